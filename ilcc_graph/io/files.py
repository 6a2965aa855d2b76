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
from ..errors import InputError
from ..types import to_plain

__all__ = ["atomic_write", "broken_link", "new_mode", "write_yaml", "read_yaml", "dump_yaml", "to_plain"]


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


class _Dumper(yaml.SafeDumper):
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


def read_yaml(path: str | Path, what: str = "file") -> Any:
    """Load a YAML file (safe loader). Missing file or bad YAML -> ``InputError`` naming the file
    (``what`` it is, e.g. ``config file``)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{p}: {what} not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: cannot read {what} ({e})") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise InputError(f"{p}: not valid YAML ({' '.join(str(e).split())})") from None
