"""A folder of per-frame stage results kept between runs (``--stage-cache DIR``).

Each result is one pickle named by a key: the sha256 of the stage's inputs and of the code that
computes it (``code_tag``: this package's and ``factors``' sources, Python's and the libraries'
versions), so that a changed scan, setting or program is a miss, never a stale hit. Files are
written to a temporary name and renamed, so a reader sees a whole file or none; a file that cannot
be read back (another Python, a partial copy) is a miss and is written again. The folder holds
pickles: name one that only you write to, as you would for your own code.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import functools
import hashlib
import importlib.metadata
import os
import pickle
import platform
import tempfile
from collections.abc import Mapping
from pathlib import Path, PurePath
from typing import Any

import numpy as np

from ilcc_graph.errors import InputError

__all__ = ["MISSING", "code_tag", "load_result", "open_store", "result_key", "store_result"]

#: what ``load_result`` returns for a key that has no readable result
MISSING = object()

_PACKAGE = Path(__file__).resolve().parents[1]
_LIBRARIES = ("numpy", "scipy", "opencv-python-headless", "opencv-python", "open3d", "gtsam")


@functools.lru_cache(maxsize=1)
def code_tag() -> bytes:
    """The sha256 of the program a stage result depends on: every ``.py`` file of this package and of
    ``factors`` (paths and bytes), Python's version and the libraries' versions."""
    h = hashlib.sha256(platform.python_version().encode())
    for name in _LIBRARIES:
        try:
            h.update(f"{name}={importlib.metadata.version(name)};".encode())
        except importlib.metadata.PackageNotFoundError:
            h.update(f"{name}=-;".encode())
    for root in (_PACKAGE, _PACKAGE.parent / "factors"):
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root.parent)).encode())
            h.update(path.read_bytes())
    return h.digest()


def result_key(stage: str, inputs: object) -> str:
    """The key of ``stage``'s result on ``inputs``: hex sha256 of the code tag, the stage's name and
    the inputs' values (``_feed``: a dataclass by its compared fields, an array by its dtype, shape and
    bytes), so that equal inputs give one key whichever process built them."""
    h = hashlib.sha256(code_tag())
    h.update(stage.encode())
    _feed(h, inputs)
    return h.hexdigest()


def _feed(h: Any, obj: object) -> None:
    """Add ``obj``'s value to the hash ``h``, tagged by its type."""
    if obj is None or isinstance(obj, (bool, int, float, complex, str, bytes, enum.Enum, PurePath)):
        h.update(f"{type(obj).__qualname__}:{obj!r};".encode())
    elif isinstance(obj, (np.ndarray, np.generic)):
        a = np.ascontiguousarray(obj)
        h.update(f"nd:{a.dtype.str}:{a.shape};".encode())
        h.update(a.tobytes())
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        h.update(f"dc:{type(obj).__module__}.{type(obj).__qualname__}(".encode())
        for f in dataclasses.fields(obj):
            if f.compare:
                h.update(f"{f.name}=".encode())
                _feed(h, getattr(obj, f.name))
        h.update(b")")
    elif isinstance(obj, (tuple, list)):
        h.update(f"{type(obj).__qualname__}[{len(obj)}](".encode())
        for item in obj:
            _feed(h, item)
        h.update(b")")
    elif isinstance(obj, Mapping):
        h.update(f"map[{len(obj)}](".encode())
        for k in sorted(obj, key=repr):
            _feed(h, k)
            _feed(h, obj[k])
        h.update(b")")
    elif isinstance(obj, (set, frozenset)):
        h.update(f"set[{len(obj)}](".encode())
        for item in sorted(obj, key=repr):
            _feed(h, item)
        h.update(b")")
    else:  # any other value: by its pickle (a miss at worst, where its pickle varies)
        h.update(f"pickle:{type(obj).__qualname__};".encode())
        h.update(pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL))


def open_store(folder: str | Path, option: str = "--stage-cache") -> Path:
    """The folder for kept results, made when missing; InputError (``option`` named) when it is not a
    folder or cannot be written."""
    path = Path(folder).expanduser()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(f"{option} {folder}: not a folder") from None
    except OSError as err:
        raise InputError(f"{option} {folder}: cannot make the folder ({err.strerror})") from None
    if not path.is_dir():
        raise InputError(f"{option} {folder}: not a folder")
    if not os.access(path, os.W_OK | os.X_OK):
        raise InputError(f"{option} {folder}: the folder cannot be written")
    return path


def _file(folder: Path, key: str) -> Path:
    return folder / key[:2] / f"{key}.pickle"


def load_result(folder: Path, key: str) -> object:
    """The result kept under ``key``, or ``MISSING`` (none, or one that cannot be read back)."""
    try:
        with open(_file(folder, key), "rb") as f:
            return pickle.load(f)
    except Exception:  # noqa: BLE001 - a result that cannot be read back is computed again
        return MISSING


def store_result(folder: Path, key: str, value: object) -> None:
    """Keep ``value`` under ``key`` (a temporary file renamed into place: whole or absent). A store
    that fails (disk full, folder gone) loses only the saving: the run goes on."""
    path = _file(folder, key)
    tmp: str | None = None
    try:
        path.parent.mkdir(exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{key[:16]}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as f:
            pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
        tmp = None
    except (OSError, pickle.PicklingError):
        pass
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
