"""PCD v0.7 (PCL) reader and writer: ``DATA ascii``, ``binary`` and ``binary_compressed``.

Header lines (PCL's "The PCD file format"): VERSION, FIELDS, SIZE, TYPE (F float, U unsigned,
I signed), COUNT (optional, default 1), WIDTH, HEIGHT, VIEWPOINT, POINTS, DATA. Binary data
are little-endian packed records (row-wise). ``binary_compressed`` data are two uint32 (the
compressed and the uncompressed size) followed by an LZF block that expands to the fields stored
column-wise: every point's first field, then every point's second field, and so on.
Fields may come in any order; repeated or ``_`` padding fields are skipped.
"""

from __future__ import annotations

import io
import struct
import warnings
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..types import Scan
from .files import atomic_write
from .lzf import LzfError, lzf_compress, lzf_decompress
from .scans import find_fields, make_scan, reader

__all__ = ["read_pcd", "write_pcd"]

_TYPES = {
    ("F", 4): "f4",
    ("F", 8): "f8",
    ("U", 1): "u1",
    ("U", 2): "u2",
    ("U", 4): "u4",
    ("U", 8): "u8",
    ("I", 1): "i1",
    ("I", 2): "i2",
    ("I", 4): "i4",
    ("I", 8): "i8",
}
_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")


def _parse_header(path: Path, raw: bytes) -> tuple[dict[str, list[str]], int]:
    """Header keys -> tokens, and the byte offset where the data start."""
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise InputError(f"{path}: PCD header has no DATA line (not a PCD file, or truncated)")
        try:
            line = raw[pos:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise InputError(
                f"{path}: PCD header line {len(header) + 1} is not text (not a PCD file?)"
            ) from None
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        key = key.upper()
        if key not in _KEYS:
            raise InputError(f"{path}: unknown PCD header line {line!r} (not a PCD file?)")
        header[key] = vals
        if key == "DATA":
            return header, pos


def _layout(path: Path, h: dict[str, list[str]]) -> tuple[list[str], np.dtype, int]:
    """(field names, little-endian record dtype, number of points) from the header."""
    for k in ("FIELDS", "SIZE", "TYPE"):
        if k not in h:
            raise InputError(f"{path}: PCD header has no {k} line")
    names, sizes, types = h["FIELDS"], h["SIZE"], h["TYPE"]
    counts = h.get("COUNT", ["1"] * len(names))
    if not (len(names) == len(sizes) == len(types) == len(counts)):
        raise InputError(
            f"{path}: PCD header lists {len(names)} FIELDS but {len(sizes)} SIZE, {len(types)} TYPE, "
            f"{len(counts)} COUNT entries"
        )
    try:
        width = int(h.get("WIDTH", ["-1"])[0])
        height = int(h.get("HEIGHT", ["1"])[0])
        points = int(h["POINTS"][0]) if "POINTS" in h else width * height
        sizes_i = [int(s) for s in sizes]
        counts_i = [int(c) for c in counts]
    except (ValueError, IndexError):
        raise InputError(f"{path}: PCD header has a non-integer WIDTH/HEIGHT/POINTS/SIZE/COUNT") from None
    if width >= 0 and width * height != points:
        raise InputError(f"{path}: PCD header says WIDTH*HEIGHT = {width}*{height} but POINTS = {points}")
    fields = []
    seen: set[str] = set()
    for i, (n, s, t, c) in enumerate(zip(names, sizes_i, types, counts_i, strict=True)):
        code = _TYPES.get((t.upper(), s))
        if code is None or c < 1:
            raise InputError(f"{path}: PCD field {n!r} has unsupported TYPE {t} SIZE {s} COUNT {c}")
        key = n if (n not in seen and n != "_") else f"_pad{i}"
        seen.add(key)
        fields.append((key, "<" + code, (c,)) if c > 1 else (key, "<" + code))
    return names, np.dtype(fields), points


def _columns(path: Path, names: list[str], rec: np.ndarray, width: int = -1, height: int = 1) -> Scan:
    """The Scan of the records; an organised cloud (HEIGHT > 1) without a ring field gets ring = row."""
    idx = find_fields(path, names)
    keys = rec.dtype.names
    assert keys is not None

    def col(k: str) -> np.ndarray:
        v = rec[keys[idx[k]]]  # type: ignore[index]
        return v[:, 0] if v.ndim > 1 else v

    xyz = np.stack([col("x"), col("y"), col("z")], axis=1)
    ring = col("ring") if idx["ring"] is not None else None
    organised = height > 1 and width > 0 and width * height == rec.shape[0]
    if ring is None and organised:
        ring = np.repeat(np.arange(height, dtype=np.int64), width)
    return make_scan(path, xyz, col("intensity"), ring, width if organised else None)


@reader(".pcd")
def read_pcd(path: Path, intensity_column: int | None = None) -> Scan:
    """Read a PCD file (ascii, binary or binary_compressed); fields x y z intensity [ring]."""
    path = Path(path)
    raw = path.read_bytes()
    h, start = _parse_header(path, raw)
    names, dtype, n = _layout(path, h)
    mode = h["DATA"][0].lower() if h["DATA"] else ""
    if n == 0:
        raise InputError(f"{path}: the file holds no points (POINTS 0)")
    if mode == "binary":
        need = n * dtype.itemsize
        if len(raw) - start < need:
            raise InputError(
                f"{path}: binary PCD truncated: header says {n} points of {dtype.itemsize} bytes "
                f"({need} bytes), file has {len(raw) - start} data bytes"
            )
        rec = np.frombuffer(raw, dtype=dtype, count=n, offset=start)
    elif mode == "binary_compressed":
        if len(raw) - start < 8:
            raise InputError(f"{path}: binary_compressed PCD truncated before the size words")
        csize, usize = struct.unpack_from("<II", raw, start)
        if usize != n * dtype.itemsize:
            raise InputError(
                f"{path}: binary_compressed PCD says {usize} uncompressed bytes, but {n} points of "
                f"{dtype.itemsize} bytes need {n * dtype.itemsize}"
            )
        if len(raw) - start - 8 < csize:
            raise InputError(
                f"{path}: binary_compressed PCD truncated: {csize} compressed bytes announced, "
                f"{len(raw) - start - 8} present"
            )
        try:
            buf = lzf_decompress(raw[start + 8 : start + 8 + csize], usize)
        except LzfError as e:
            raise InputError(f"{path}: corrupt binary_compressed data ({e})") from None
        rec = np.empty(n, dtype=dtype)
        off = 0
        for key in dtype.names or ():
            ft = dtype.fields[key][0]  # type: ignore[index]
            nbytes = n * ft.itemsize
            rec[key] = np.frombuffer(
                buf, dtype=ft.base, count=n * max(1, int(np.prod(ft.shape))), offset=off
            ).reshape((n, *ft.shape))
            off += nbytes
    elif mode == "ascii":
        rec = _read_ascii(path, raw[start:], names, dtype, n)
    else:
        raise InputError(
            f"{path}: unknown PCD DATA type {' '.join(h['DATA'])!r}; expected ascii|binary|binary_compressed"
        )
    width, height = int(h.get("WIDTH", ["-1"])[0]), int(h.get("HEIGHT", ["1"])[0])
    return _columns(path, names, rec, width, height)


def _read_ascii(path: Path, body: bytes, names: list[str], dtype: np.dtype, n: int) -> np.ndarray:
    ncol = sum(max(1, int(np.prod(dtype.fields[k][0].shape))) for k in dtype.names or ())  # type: ignore[index]
    text = body.decode("ascii", errors="replace")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data" -> handled below
            table = np.loadtxt(io.StringIO(text), dtype=np.float64, ndmin=2)
    except ValueError as e:
        raise InputError(f"{path}: bad ascii PCD data ({' '.join(str(e).split())})") from None
    if table.shape[0] != n:
        raise InputError(
            f"{path}: ascii PCD header says POINTS {n} but the file has {table.shape[0]} data rows"
        )
    if table.shape[1] != ncol:
        raise InputError(
            f"{path}: ascii PCD rows have {table.shape[1]} values, the header's fields need {ncol}"
        )
    rec = np.empty(n, dtype=dtype)  # values take the header's declared types (F4 text -> float32)
    c = 0
    for k in dtype.names or ():
        w = max(1, int(np.prod(dtype.fields[k][0].shape)))  # type: ignore[index]
        rec[k] = table[:, c : c + w].reshape(rec[k].shape).astype(rec[k].dtype)
        c += w
    return rec


def write_pcd(
    path: str | Path, scan: Scan, data: str = "binary", organised: tuple[int, int] | None = None
) -> Path:
    """Write ``scan`` as PCD v0.7: fields x y z intensity (float32) [ring (uint16)], atomically.

    data: ``"binary"`` (default), ``"ascii"`` or ``"binary_compressed"``.
    organised: (HEIGHT, WIDTH) to write an organised cloud (row-major: point k is row k // WIDTH);
        the scan must then hold HEIGHT * WIDTH points, (0, 0, 0) where a pixel has no return.
    """
    if data not in ("binary", "ascii", "binary_compressed"):
        raise ValueError(f"data must be 'binary', 'ascii' or 'binary_compressed', got {data!r}")
    n = len(scan)
    height, width = (1, n) if organised is None else (int(organised[0]), int(organised[1]))
    if height * width != n:
        raise ValueError(f"organised {organised} needs {height * width} points, the scan has {n}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")]
    if scan.ring is not None:
        fields.append(("ring", "<u2"))
    rec = np.empty(n, dtype=fields)
    pts = np.asarray(scan.points, dtype=np.float64).reshape(-1, 3)
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    rec["intensity"] = np.asarray(scan.intensity, dtype=np.float64)
    if scan.ring is not None:
        rec["ring"] = np.asarray(scan.ring)
    names = [f[0] for f in fields]
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(names)}\n"
        f"SIZE {' '.join(str(np.dtype(t).itemsize) for _, t in fields)}\n"
        f"TYPE {' '.join('F' if np.dtype(t).kind == 'f' else 'U' for _, t in fields)}\n"
        f"COUNT {' '.join('1' for _ in fields)}\n"
        f"WIDTH {width}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    )
    if data == "binary":
        payload = rec.tobytes()
    elif data == "binary_compressed":
        cols = b"".join(np.ascontiguousarray(rec[k]).tobytes() for k in names)
        comp = lzf_compress(cols)
        payload = struct.pack("<II", len(comp), len(cols)) + comp
    else:
        # one %-format over all values: ~10x faster than np.savetxt's per-row loop
        row = " ".join("%.9g" if rec[k].dtype.kind == "f" else "%d" for k in names) + "\n"
        values = np.stack([rec[k].astype(np.float64) for k in names], axis=1).ravel().tolist()
        payload = ((row * n) % tuple(values)).encode("ascii")
    return atomic_write(path, header.encode("ascii") + payload)
