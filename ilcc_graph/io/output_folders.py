"""Output folders: claimed before a run, staged, committed in one step under a lock.

A run writes only into a folder that is new, empty, or an earlier result of ours: one holding our
marker file ``.ilcc-graph-run`` (the version, the command, what kind of folder it is and the paths
written, in subfolders too) and nothing but those paths. Anything else is refused before any work,
and nothing in it is touched (docs/faults.md, "Output folders"). A link to a folder stands for its
target: the run writes the target, the link stays.

``claim_output(out)`` says before a long run whether ``out`` may be written (``OutputError`` naming
the path and the reason); ``staged(out)`` gives a staging folder beside it that replaces it only when
everything is written, so ``out`` is always one run's complete result or as it was;
``add_file(folder, name, data)`` writes one file into a folder we may write (``evaluate --out``);
``write_file(path, data)`` one file the user named (``export --out``, replaced as ``cp`` does);
``write_beside(path, data)`` a failure file or log beside an output folder, never over a file that is
not ours; ``staged_files(targets)`` new files (or folders) that belong together, e.g. a simulated bag
and the YAML files beside it, moved in together at the end and never over anything that exists;
``link_latest`` points ``<parent>/latest`` at a run folder. Which folder a command writes
is decided in ``app.folders``; the simulator stages its data sets here too (``simulate.write_set``).
"""

from __future__ import annotations

import errno
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import yaml

from ilcc_graph import signals
from ilcc_graph.errors import OutputError
from ilcc_graph.io import atomic_write, dump_yaml
from ilcc_graph.io.files import new_mode

__all__ = [
    "DATA_SET",
    "MARKER",
    "RESULT",
    "add_file",
    "claim_output",
    "link_latest",
    "staged",
    "staged_files",
    "write_beside",
    "write_file",
]

#: the marker file of a folder we wrote (hidden; YAML: tool, version, kind, command, names: every
#: path written, relative, subfolders' too)
MARKER = ".ilcc-graph-run"
#: kinds of folder: a command's results (calibrate, check, the stage commands, evaluate) and a
#: simulated data set; a run replaces only a folder of its own kind
RESULT, DATA_SET = "result", "data set"
#: the first line of a file written beside an output folder (failure file, error log)
OURS = "# written by ilcc-graph"
_MARKER_HEAD = f"{OURS} into this folder; a later run may replace it whole (it holds only the paths listed)\n"


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("ilcc_graph")
    except Exception:  # noqa: BLE001 - not installed: a source checkout
        return "unknown"


def _marker(stage: Path, kind: str, command: str) -> str:
    """The marker's text for the folder ``stage`` (its names as they are now); ``command``: the
    command line's arguments that wrote it ("" from Python)."""
    doc = {
        "tool": "ilcc-graph",
        "version": _version(),
        "kind": kind,
        "command": f"ilcc-graph {command}" if command else "(from Python)",
        "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "names": [n for n in _entries(stage) if n != MARKER],
    }
    return _MARKER_HEAD + dump_yaml(doc)


def _read_marker(folder: Path) -> dict | None:
    try:
        doc = yaml.safe_load((folder / MARKER).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None
    if not isinstance(doc, dict) or doc.get("tool") != "ilcc-graph" or not isinstance(doc.get("names"), list):
        return None
    return doc


def _entries(folder: Path) -> list[str]:
    """Every path under ``folder`` (files and folders, relative, with ``/``), sorted; links not followed."""
    got = []
    for top, dirs, files in os.walk(folder):
        rel = Path(top).relative_to(folder)
        got += [(rel / n).as_posix() for n in dirs + files]
    return sorted(got)


def _foreign(folder: Path, kind: str) -> str | None:
    """Why the existing folder ``folder`` may not be replaced by a run of ``kind``, or None."""
    names = sorted(p.name + ("/" if p.is_dir() else "") for p in folder.iterdir())
    if not names:
        return None
    listed = ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")
    doc = _read_marker(folder)
    if doc is None:
        return (
            f"holds files ilcc-graph did not write ({listed}); a run writes only into a new or empty "
            "folder or over an earlier result of its own, and would lose them: give a new folder"
        )
    if doc.get("kind") != kind:
        return (
            f"is a {doc.get('kind')} written by {doc.get('command', 'ilcc-graph')}, not a {kind}: "
            "a run never replaces it; give a new folder"
        )
    ours = set(doc["names"]) | {MARKER}
    extra = [n for n in _entries(folder) if n not in ours]
    if extra:
        return (
            f"an earlier result of ilcc-graph, but it now also holds {', '.join(extra[:6])}, which the "
            "run did not write and replacing it would lose: move them or give a new folder"
        )
    return None


def _existing_parent(path: Path, say: str, what: str) -> Path:
    """The nearest existing folder above ``path``; ``OutputError`` when it is a file."""
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"{say}: {parent} is a file, so {what} under it")
    return parent


def _under(a: Path, b: Path) -> bool:
    """``a`` is ``b`` or inside it (both resolved)."""
    return a == b or b in a.parents


def claim_output(
    out: Path | str, flag: str = "--out", kind: str = RESULT, reads: Sequence[Path | str] = ()
) -> Path:
    """The folder a run may write as ``out``, checked now (before a long run); ``OutputError``
    naming ``flag``, the path and the reason otherwise.

    ``out`` may be absent (made), an empty folder, or an earlier folder of ours of the same ``kind``
    (replaced whole); a link stands for its target (the target is returned and written, the link
    stays). Refused: a file, a path under a file, a folder holding anything else, a data set the
    run ``reads``, the current folder or one holding it (the run replaces its output folder, which
    would leave the shell in a deleted one), a mount point, a place that cannot be written (tried
    with a probe folder: permission bits do not stop root, a read-only file system does).
    """
    given = Path(out)
    out = Path(os.path.realpath(given)) if given.is_symlink() else given
    say = f"{flag} {given}" + (f" (a link to {out})" if out != given else "")
    if out.is_symlink():
        raise OutputError(f"{say}: a link that leads to no folder (a loop of links)")
    if out.exists() and not out.is_dir():
        raise OutputError(f"{say}: is an existing file, not a folder; give a folder for the results")
    parent = _existing_parent(out, say, "no folder can be made")
    if out.is_dir():
        real = out.resolve()
        for data in reads:
            if _under(Path(data).resolve(), real):
                raise OutputError(f"{say}: holds the data set this run reads ({data}); give a new folder")
        if _under(Path.cwd().resolve(), real):
            raise OutputError(
                f"{say}: is the current folder or holds it; a run replaces its output folder whole, "
                "so give a folder inside it (e.g. out/run1) or run from elsewhere"
            )
        if os.path.ismount(real):
            raise OutputError(f"{say}: is a mount point, which cannot be replaced; give a folder inside it")
        if why := _foreign(out, kind):
            raise OutputError(f"{say}: {why}")
    try:
        probe = tempfile.mkdtemp(prefix=".ilcc-graph-probe-", dir=parent)
        os.rmdir(probe)
    except OSError as err:
        raise OutputError(f"{say}: cannot write in {parent} ({err.strerror or err})") from None
    return out


def link_latest(path: Path) -> None:
    """Point ``<parent>/latest`` at the run folder ``path`` (best effort: a link is a convenience;
    a ``latest`` that is not a link is left alone)."""
    latest = Path(path).parent / "latest"
    if latest.exists() and not latest.is_symlink():
        return
    tmp = latest.with_name(f".latest.{os.getpid()}")
    try:
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(Path(path).name)
        os.replace(tmp, latest)
    except OSError:
        tmp.unlink(missing_ok=True)


def write_file(path: Path | str, data: str | bytes, flag: str = "--out") -> Path:
    """One file the user named, written atomically (an existing file is replaced as ``cp`` does,
    keeping its mode; a new one has the umask's; a link is written through); ``OutputError`` naming
    ``flag`` and the path when it cannot be (a folder, a path under a file, no permission)."""
    path = Path(path)
    if path.is_symlink():
        path = Path(os.path.realpath(path))
    if path.is_dir():
        raise OutputError(f"{flag} {path}: is a folder; give a file name")
    _existing_parent(path, f"{flag} {path}", "nothing can be written")
    try:
        return atomic_write(path, data)
    except OSError as err:
        raise OutputError(f"{flag} {path}: cannot write ({err.strerror or err})") from None


def add_file(
    folder: Path | str, name: str, data: str | bytes, flag: str = "--out", command: str = ""
) -> Path:
    """``folder/name`` written atomically into a folder a run may write (``claim_output``): a new or
    empty one becomes ours with this file, an earlier result of ours keeps its other files and lists
    the name in its marker (first, so no crash leaves a file the marker does not name)."""
    folder = claim_output(folder, flag)
    if not folder.is_dir() or not any(folder.iterdir()):
        with staged(folder, command=command) as d:
            atomic_write(d / name, data)
        return folder / name
    try:
        doc = _read_marker(folder) or {"names": []}  # claimed above: an earlier result of ours
        if name not in doc["names"]:
            doc["names"] = sorted([*doc["names"], name])
            atomic_write(folder / MARKER, _MARKER_HEAD + dump_yaml(doc))
        return atomic_write(folder / name, data)
    except OSError as err:
        raise OutputError(f"{flag} {folder / name}: cannot write ({err.strerror or err})") from None


def write_beside(path: Path, data: str) -> Path | None:
    """``data`` (its first line ``OURS``) written atomically to ``path`` when that is absent or a file of
    ours (its first line says so); None when it is anything else or cannot be written (the caller
    then says so or uses another place)."""
    path = Path(path)
    if path.is_symlink() or (path.exists() and not path.is_file()):
        return None
    if path.exists():
        try:
            with open(path, encoding="utf-8", errors="replace") as f:
                if not f.readline().startswith(OURS):
                    return None
        except OSError:
            return None
    try:
        return atomic_write(path, data)
    except OSError:
        return None


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux renameat2 RENAME_EXCHANGE); False where not available."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    if ctypes.get_errno() in (errno.EINVAL, errno.ENOSYS, errno.EPERM):
        return False  # a file system without the exchange: rename in two steps
    raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()), str(b))


@contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """An exclusive lock on ``folder`` (flock on its descriptor; nothing where unsupported)."""
    try:
        import fcntl

        fd = os.open(folder, os.O_RDONLY)
    except (ImportError, OSError):
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _commit(stage: Path, out: Path, kind: str) -> None:
    """Put the complete ``stage`` at ``out`` (replacing an earlier result of ours); signals held,
    runs serialised.

    Two runs writing to one folder at once each stage their own folder; the commits take turns
    under a lock on the parent, so ``out`` is always one run's complete result (the last to commit).
    What ``out`` holds is checked again under the lock: files put there during the run are kept.
    """
    with signals.held(), _locked(out.parent):
        if out.exists() and not out.is_dir():
            raise OutputError(f"{out}: is a file now (it was not when the run started); nothing written")
        if not out.exists():
            os.replace(stage, out)
            return
        if why := _foreign(out, kind):
            raise OutputError(f"{out}: changed while the run was on and now {why}; nothing written")
        if _exchange(stage, out):
            shutil.rmtree(stage, ignore_errors=True)  # the old result, swapped out
            return
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
        os.replace(out, old / "x")
        os.replace(stage, out)
        shutil.rmtree(old, ignore_errors=True)


def _make_stage(parent: Path, name: str) -> Path:
    """A new staging folder ``.<name>.partial-*`` in ``parent`` (made), with the umask's mode;
    ``OutputError`` naming ``name`` when it cannot be made."""
    try:
        parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{name}.partial-", dir=parent))
        os.chmod(stage, new_mode(folder=True))
    except OSError as err:
        raise OutputError(
            f"{parent / name}: cannot create the output folder ({err.strerror or err})"
        ) from None
    return stage


def _remove(paths: Sequence[Path]) -> None:
    """Remove what a staging wrote (folders whole, files, links); what is gone already is skipped."""
    for q in paths:
        if q.is_dir() and not q.is_symlink():
            shutil.rmtree(q, ignore_errors=True)
        else:
            q.unlink(missing_ok=True)


@contextmanager
def _staging(parent: Path, name: str) -> Iterator[list[Path]]:
    """``[stage]``: a staging folder (``_make_stage``) that is removed, with whatever the caller adds to
    the list, when the block raises or a stop ends the process (the caller takes out what it has
    committed).

    No stop can leave the folder behind: it is made with signals held inside the block that removes
    it (a stop between ``mkdtemp`` and that block used to leave it), it is in the stop's clean-up
    (``signals.on_stop``) before it exists, and the removal after an error runs with signals held (a
    first stop inside it used to cut it short). The stop is raised once the folder is gone.
    """
    made: list[Path] = []
    with signals.on_stop(lambda: _remove(made)):
        try:
            with signals.held():
                made.append(_make_stage(parent, name))
            yield made
        except BaseException:
            with signals.held():
                _remove(made)
            raise


@contextmanager
def staged(
    out: Path | str, kind: str = RESULT, flag: str = "output folder", command: str = ""
) -> Iterator[Path]:
    """A staging folder beside ``out`` that becomes ``out`` when the block ends without an error.

    ``out`` must be one a run may write (``claim_output``; a link stands for its target). The marker
    (``MARKER``) is added last, naming what the block wrote and the ``command`` that wrote it. An
    earlier result is replaced only at the end, in one step where the system allows; on an error or
    a signal the staging folder is removed and ``out`` is untouched (``_staging``). A write that
    fails (disk full, read-only, permissions) raises ``OutputError`` naming the file. Folders follow
    the umask.
    """
    out = claim_output(out, flag, kind)
    with _staging(out.parent, out.name) as made:
        stage = made[0]
        try:
            yield stage
            atomic_write(stage / MARKER, _marker(stage, kind, command))
            _commit(stage, out, kind)
        except OSError as err:
            where = f" ({err.filename})" if err.filename else ""
            raise OutputError(f"{out}: cannot write the results: {err.strerror or err}{where}") from None
        # committed: the stage's path is gone (renamed to ``out``) or holds the old result (removed)


def _in_the_way(targets: Sequence[Path], flag: str) -> None:
    """``OutputError`` naming ``flag``, the main target (the last) and the first target that exists:
    new files are never written over anything (a run never writes over a file it did not write)."""
    main = targets[-1]
    for t in (main, *targets[:-1]):
        if t.exists() or t.is_symlink():
            where = "exists" if t == main else f"{t.name} exists beside it (written with it)"
            raise OutputError(
                f"{flag} {main}: {where}; a run never writes over a file it did not write: "
                f"give another name or move {t.name}"
            )


@contextmanager
def staged_files(targets: Sequence[Path | str], flag: str = "output") -> Iterator[Path]:
    """A staging folder for new files or folders that belong together (``targets``, all in one folder,
    the main one last): the block writes each under its name in the staging folder; when it ends
    without an error they are moved to their targets, the main one last, with signals held (so the
    main one present means all are). None of them may exist: ``OutputError`` naming ``flag`` and the
    one in the way, before the block and again under the commit's lock. On an error or a stop the
    staging folder and whatever was moved are removed: nothing is left, nothing else is touched."""
    paths = [Path(t) for t in targets]
    parent = paths[-1].parent
    if any(t.parent != parent for t in paths):
        raise ValueError(f"staged_files: the targets must share one folder, got {paths}")
    _in_the_way(paths, flag)
    _existing_parent(paths[-1], f"{flag} {paths[-1]}", "nothing can be written")
    with _staging(parent, paths[-1].name) as made:  # the staging folder, then each target moved in
        stage = made[0]
        try:
            yield stage
            with signals.held(), _locked(parent):
                _in_the_way(paths, flag)
                for t in paths:
                    os.rename(stage / t.name, t)
                    made.append(t)
                del made[1:]  # committed: the targets stay
                shutil.rmtree(stage, ignore_errors=True)  # empty, unless the block wrote more
        except OSError as err:
            where = f" ({err.filename})" if err.filename else ""
            raise OutputError(f"{flag} {paths[-1]}: cannot write: {err.strerror or err}{where}") from None
