"""Atomic file writes and YAML reading/writing (numpy-aware, matrices as readable rows)."""

from __future__ import annotations

import math
import os
import stat
import tempfile
from pathlib import Path
from typing import Any

import yaml

from .. import signals
from ..errors import InputError, quote
from ..types import to_plain

__all__ = [
    "atomic_write", "broken_link", "new_mode", "write_yaml", "read_yaml", "dump_yaml", "to_plain",
    "not_a_file", "read_bounded", "load_yaml_text", "check_yaml_keys", "SMALL_FILE",
]  # fmt: skip


def _umask() -> int:
    """The process's umask: read from /proc on Linux (no change to it), else set and put back."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def new_mode(folder: bool = False) -> int:
    """The permission bits a new file (0666) or folder (0777) gets under the umask, as ``open`` and
    ``mkdir`` give them (``tempfile`` makes 0600 / 0700, which is why writers set these)."""
    return (0o777 if folder else 0o666) & ~_umask()


def broken_link(path: str | Path) -> str | None:
    """'PATH: a broken link (to TARGET, which does not exist)' when ``path`` is one, else None."""
    p = Path(path)
    if not p.is_symlink() or p.exists():
        return None
    try:
        target = os.readlink(p)
    except OSError:
        target = "?"
    return f"{p}: a broken link (to {target}, which does not exist)"


def atomic_write(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` so that readers see the old file or the whole new one.

    Writes a temporary file in the same folder, fsyncs it and renames it over ``path``
    (``os.replace``). Creates missing parent folders. The file gets the mode of the file it replaces,
    or the umask's (``new_mode``). On any error the temporary file is removed and ``path`` is left as
    it was. Returns ``path``.
    """
    p = Path(path)
    payload = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    p.parent.mkdir(parents=True, exist_ok=True)
    try:
        old = os.stat(p)
        mode = stat.S_IMODE(old.st_mode) if stat.S_ISREG(old.st_mode) else new_mode()
    except OSError:
        mode = new_mode()
    tmp: str | None = None
    try:
        # made with a stop held (raised once ``tmp`` is known, so the except below removes it)
        with signals.held():
            fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
            f = os.fdopen(fd, "wb")
        with f:
            os.fchmod(f.fileno(), mode)
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        if tmp is not None:
            with signals.held():  # a stop during the removal waits for it
                try:
                    os.unlink(tmp)
                except FileNotFoundError:
                    pass
        raise
    return p


#: libyaml's emitter and parser when PyYAML was built with them (its wheels are): the same text and
#: documents as the pure-Python ones, about 3x faster to write and 20x faster to read (a calibration.yaml
#: of 80 frames, 0.75 MB: 2.5 -> 0.8 s and 4.8 -> 0.25 s)
_SAFE_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _Dumper(_SAFE_DUMPER):  # type: ignore[misc, valid-type]
    """Lists of scalars in flow style (matrix rows on one line); everything else block style."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(not isinstance(v, (list, dict)) for v in data) and len(data) <= 64
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


def _represent_float(dumper: yaml.SafeDumper, data: float) -> yaml.Node:
    if math.isnan(data):
        return dumper.represent_scalar("tag:yaml.org,2002:float", ".nan")
    if math.isinf(data):
        return dumper.represent_scalar("tag:yaml.org,2002:float", ".inf" if data > 0 else "-.inf")
    text = repr(float(data))  # shortest string that reads back to the same double
    if "." not in text and "e" not in text:
        text += ".0"
    elif "e" in text and "." not in text:  # YAML 1.1 needs a dot in 1e-05
        mant, exp = text.split("e")
        text = f"{mant}.0e{exp}"
    return dumper.represent_scalar("tag:yaml.org,2002:float", text)


_Dumper.add_representer(list, _represent_list)
_Dumper.add_representer(float, _represent_float)


def dump_yaml(obj: Any) -> str:
    """YAML text of ``obj`` (numpy-aware; key order kept)."""
    return yaml.dump(to_plain(obj), Dumper=_Dumper, sort_keys=False, allow_unicode=True, width=200)


def write_yaml(path: str | Path, obj: Any) -> Path:
    """Write ``obj`` as YAML, atomically. The text is made in full before the file is touched."""
    return atomic_write(path, dump_yaml(obj))


#: the largest YAML file read (calibration.yaml of a long run is a few MB); config.yaml, rig.yaml and a
#: camera's calibration file are read with the smaller ``SMALL_FILE``
YAML_MAX_BYTES = 64 << 20
SMALL_FILE = 1 << 20
#: how many values YAML's aliases (``*name``) may add to a document when expanded (an alias bomb adds
#: billions); a hand-written file has none or a few
ALIAS_MAX_VALUES = 100_000

_KINDS = (
    (stat.S_ISDIR, "is a folder"),
    (stat.S_ISFIFO, "is a FIFO (named pipe)"),
    (stat.S_ISCHR, "is a character device"),
    (stat.S_ISBLK, "is a block device"),
    (stat.S_ISSOCK, "is a socket"),
)


def not_a_file(path: str | Path) -> str | None:
    """Why ``path`` cannot be read as a file, or None when it is a regular one: ``not found``, ``is a
    broken link (to ...)``, ``is a folder``, ``is a FIFO (named pipe)``, ``is a character device``
    (/dev/zero), ... (issue 36: these were all "not found"). Never opens it (a FIFO would block)."""
    p = Path(path)
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError:
        link = broken_link(p)
        return "is " + link[len(str(p)) + 2 :] if link else "not found"
    except OSError as e:
        return f"cannot be read ({e.strerror})"
    if stat.S_ISREG(mode):
        return None
    return next((what for test, what in _KINDS if test(mode)), "is not a regular file")


def read_bounded(path: str | Path, what: str = "file", max_bytes: int = YAML_MAX_BYTES) -> bytes:
    """The bytes of the regular file ``path``; InputError naming it when it is something else (a
    folder, a FIFO, a device), cannot be read or is larger than ``max_bytes`` (read no further)."""
    p = Path(path)
    problem = not_a_file(p)
    if problem is not None:
        raise InputError(f"{p}: {what} {problem}")
    try:
        with open(p, "rb") as f:
            raw = f.read(max_bytes + 1)
    except OSError as e:
        raise InputError(f"{p}: cannot read {what} ({e.strerror or e})") from None
    if len(raw) > max_bytes:
        raise InputError(
            f"{p}: {what} is larger than {max_bytes / 2**20:g} MiB, far more than such a file holds; not read"
        )
    return raw


def _check_nodes(root: yaml.Node, src: str) -> None:
    """Refuse a mapping that names a key twice (YAML keeps the last silently; a section pasted twice
    replaced the first) and aliases that expand to more than ``ALIAS_MAX_VALUES`` values; each node
    is visited once however often it is referred to."""
    size: dict[int, int] = {}
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        if id(node) in size and not done:
            continue
        children = _children(node)
        if not done:
            size[id(node)] = -1  # on the way: an alias back to it makes a cycle
            stack.append((node, True))
            stack.extend((c, False) for c in children if size.get(id(c)) is None)
            if isinstance(node, yaml.MappingNode):
                _duplicates(node, src)
            continue
        if any(size.get(id(c), 0) < 0 for c in children):
            raise InputError(
                f"{src}: line {node.start_mark.line + 1}: an alias refers to the value that holds it"
            )
        size[id(node)] = 1 + sum(size[id(c)] for c in children)
    expanded = size[id(root)]
    if expanded > len(size) + ALIAS_MAX_VALUES:
        raise InputError(
            f"{src}: its aliases (*name) would add more than {ALIAS_MAX_VALUES:,} values to its "
            f"{len(size):,} (an alias bomb?); not read"
        )


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for kv in node.value for n in kv]
    return []


def _duplicates(node: yaml.MappingNode, src: str) -> None:
    seen: dict[tuple[str, str], int] = {}
    for k, _ in node.value:
        if not isinstance(k, yaml.ScalarNode) or k.tag == "tag:yaml.org,2002:merge":
            continue
        line = k.start_mark.line + 1
        first = seen.setdefault((k.tag, k.value), line)
        if first != line:
            raise InputError(
                f"{src}: the key {quote(k.value, 60)} appears twice in one mapping (lines {first} and "
                f"{line}); YAML would keep only the last: remove one"
            )


def load_yaml_text(text: str, src: str) -> Any:
    """The document in ``text`` (safe loader), refusing duplicate keys and alias bombs
    (``_check_nodes``); InputError naming ``src`` when it is not valid YAML."""
    loader: Any = None
    try:
        loader = _SAFE_LOADER(text)  # its reader refuses characters YAML does not allow
        node = loader.get_single_node()
        if node is None:
            return None
        _check_nodes(node, src)
        return loader.construct_document(node)
    except yaml.YAMLError as e:
        line = getattr(getattr(e, "problem_mark", None), "line", None)
        lines = text.splitlines()
        hint = ""
        if isinstance(line, int) and 0 <= line < len(lines) and "\t" in lines[line]:
            hint = f"; line {line + 1} holds a tab: YAML indents with spaces only"
        raise InputError(f"{src}: not valid YAML ({' '.join(str(e).split())}){hint}") from None
    finally:
        if loader is not None:
            loader.dispose()


def check_yaml_keys(text: str, src: str) -> None:
    """The checks of ``load_yaml_text`` (a key twice, alias bombs) on YAML another parser will read
    (OpenCV's FileStorage: its tags are only composed here, never built); text that is not YAML to
    PyYAML is left to that parser."""
    loader: Any = None
    try:
        loader = _SAFE_LOADER(text)
        node = loader.get_single_node()
    except yaml.YAMLError:
        return
    finally:
        if loader is not None:
            loader.dispose()
    if node is not None:
        _check_nodes(node, src)


def read_yaml(path: str | Path, what: str = "file", max_bytes: int = YAML_MAX_BYTES) -> Any:
    """Load a YAML file (safe loader). Missing file, something else than a file, more than
    ``max_bytes``, bad YAML, a key twice in a mapping or an alias bomb -> ``InputError`` naming the file
    (``what`` it is, e.g. ``config file``)."""
    p = Path(path)
    raw = read_bounded(p, what, max_bytes)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise InputError(
            f"{p}: cannot read {what}: line {line} is not UTF-8 ({e}); save it as UTF-8"
        ) from None
    return load_yaml_text(text, str(p))
