"""Output folders: checked before a run, staged, committed in one step under a lock.

``staged(out)`` gives a staging folder beside ``out`` that becomes ``out`` only when everything in it
is written, so ``out`` is always one run's complete result or untouched (issue 14, docs/faults.md);
``check_output`` says before a long run that ``out`` cannot be written; ``write_file`` writes one
file atomically; ``link_latest`` points ``<parent>/latest`` at a run folder.
"""

from __future__ import annotations

import errno
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ilcc_graph import signals
from ilcc_graph.errors import OutputError
from ilcc_graph.io import atomic_write

__all__ = ["check_output", "link_latest", "staged", "write_file"]


def link_latest(path: Path) -> None:
    """Point ``<parent>/latest`` at the run folder ``path`` (best effort: a link is a convenience)."""
    latest = Path(path).parent / "latest"
    try:
        if latest.is_symlink() or latest.exists():
            latest.unlink()
        latest.symlink_to(Path(path).name)
    except OSError:
        pass


def write_file(path: Path, data: str | bytes, flag: str = "--out") -> Path:
    """One file written atomically; ``OutputError`` naming ``flag`` and the path when it cannot be."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{flag} {path}: is a folder; give a file name")
    if path.parent.exists() and not path.parent.is_dir():
        raise OutputError(f"{flag} {path}: {path.parent} is a file, so nothing can be written under it")
    check_output(path.parent, flag)
    try:
        return atomic_write(path, data)
    except OSError as err:
        raise OutputError(f"{flag} {path}: cannot write ({err.strerror or err})") from None


def check_output(out: Path, flag: str = "--out") -> None:
    """Raise ``OutputError`` now when ``out`` cannot become an output folder (before a long run).

    ``out`` may be absent or a folder; it must not be a file or lie under a file, and its nearest
    existing parent must be writable (tried with a probe folder, removed again: permission bits do
    not stop root, a read-only file system does).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{flag} {out}: is an existing file, not a folder; give a folder for the results")
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"{flag} {out}: {parent} is a file, so no folder can be made under it")
    try:
        probe = tempfile.mkdtemp(prefix=".ilcc-graph-probe-", dir=parent)
        os.rmdir(probe)
    except OSError as err:
        raise OutputError(f"{flag} {out}: cannot write in {parent} ({err.strerror or err})") from None


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


def _commit(stage: Path, out: Path) -> None:
    """Put the complete ``stage`` at ``out`` (replacing an old ``out``); signals held, runs serialised.

    Two runs writing to one folder at once each stage their own folder; the commits take turns
    under a lock on the parent, so ``out`` is always one run's complete result (the last to commit).
    """
    with signals.held(), _locked(out.parent):
        if out.exists() and not out.is_dir():
            raise OutputError(f"{out}: is a file now (it was not when the run started); nothing written")
        if not out.exists():
            os.replace(stage, out)
            return
        if _exchange(stage, out):
            shutil.rmtree(stage, ignore_errors=True)  # the old result, swapped out
            return
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
        os.replace(out, old / "x")
        os.replace(stage, out)
        shutil.rmtree(old, ignore_errors=True)


@contextmanager
def staged(out: Path) -> Iterator[Path]:
    """A staging folder beside ``out`` that becomes ``out`` when the block ends without an error.

    An existing ``out`` is replaced only then, in one step where the system allows; on an error or a
    signal the staging folder is removed and ``out`` is untouched. A write that fails (disk full,
    read-only, permissions) raises ``OutputError`` naming the file.
    """
    out = Path(out)
    check_output(out, "output folder")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    except OSError as err:
        raise OutputError(f"{out}: cannot create the output folder ({err.strerror or err})") from None
    with signals.on_stop(lambda: shutil.rmtree(stage, ignore_errors=True)):
        try:
            yield stage
            _commit(stage, out)
        except OSError as err:
            shutil.rmtree(stage, ignore_errors=True)
            where = f" ({err.filename})" if err.filename else ""
            raise OutputError(f"{out}: cannot write the results: {err.strerror or err}{where}") from None
        except BaseException:
            shutil.rmtree(stage, ignore_errors=True)
            raise
