"""PCD (PCL's format, v0.5-0.7) reader and writer: ``DATA ascii``, ``binary``, ``binary_compressed``.

Header lines (PCL's "The PCD file format"): VERSION, FIELDS (v0.5: COLUMNS), SIZE, TYPE (F float,
U unsigned, I signed), COUNT (optional, default 1), WIDTH, HEIGHT, VIEWPOINT, POINTS, DATA, with
``#`` comments in any encoding (read as bytes, never decoded). Binary data are little-endian
packed records (row-wise). ``binary_compressed`` data are two uint32 (the compressed and the
uncompressed size) followed by an LZF block that expands to the fields stored column-wise: every
point's first field (all COUNT elements of a point together), then every point's second field,
and so on. Fields may come in any order; repeated or ``_`` padding fields are skipped. The writer
can mimic the headers and layouts of PCL, Open3D and MATLAB (``PCD_STYLES``).
"""

from __future__ import annotations

import io
import re
import struct
import warnings
from pathlib import Path

import numpy as np

from ..errors import InputError, quote
from ..types import Scan
from .files import atomic_write
from .lzf import LzfError, lzf_compress, lzf_decompress
from .scans import find_fields, make_scan, reader

__all__ = ["PCD_STYLES", "read_pcd", "write_pcd"]

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
_KEY_ALIASES = {"COLUMNS": "FIELDS"}  # PCD v0.5 named the field line COLUMNS
_BOM = b"\xef\xbb\xbf"


def _parse_header(path: Path, raw: bytes) -> tuple[dict[str, list[str]], int]:
    """Header keys -> tokens, and the byte offset where the data start.

    Byte-safe: a line is stripped of spaces, tabs and CR first; blank lines and comments (``#``,
    in any encoding: MATLAB writes "MATLAB®" in UTF-8) are skipped before anything is decoded.
    Keys are case-insensitive. Any other line must be ASCII text with a known key.
    """
    header: dict[str, list[str]] = {}
    pos = len(_BOM) if raw.startswith(_BOM) else 0
    lineno = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise InputError(f"{path}: PCD header has no DATA line (not a PCD file, or truncated)")
        lineno += 1
        line = raw[pos:end].strip()
        pos = end + 1
        if not line or line.startswith(b"#"):
            continue
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            raise InputError(
                f"{path}: PCD header line {lineno} is neither a comment nor text (not a PCD file?)"
            ) from None
        key, *vals = text.split()
        key = _KEY_ALIASES.get(key.upper(), key.upper())
        if key not in _KEYS:
            raise InputError(f"{path}: unknown PCD header line {lineno} {text[:60]!r} (not a PCD file?)")
        if key in header:
            raise InputError(f"{path}: PCD header has a second {key} line (line {lineno})")
        header[key] = vals
        if key == "DATA":
            return header, pos


def _ints(path: Path, h: dict[str, list[str]], key: str) -> list[int] | None:
    """The integer tokens of header line ``key`` (None when absent); InputError if not integers."""
    if key not in h:
        return None
    try:
        return [int(v) for v in h[key]]
    except ValueError:
        raise InputError(f"{path}: PCD header line {key} {quote(' '.join(h[key]))} is not integers") from None


def _shape(path: Path, h: dict[str, list[str]]) -> tuple[int, int, int]:
    """(width, height, points): POINTS defaults to WIDTH*HEIGHT, WIDTH to POINTS (HEIGHT 1), as in PCL."""
    width, height, points = (_ints(path, h, k) for k in ("WIDTH", "HEIGHT", "POINTS"))
    for key, v in (("WIDTH", width), ("HEIGHT", height), ("POINTS", points)):
        if v is not None and (len(v) != 1 or v[0] < 0):
            raise InputError(f"{path}: PCD header line {key} {quote(' '.join(h[key]))} is not one count")
    if points is None and width is None:
        raise InputError(f"{path}: PCD header has neither WIDTH nor POINTS")
    h_ = 1 if height is None else height[0]
    w_ = points[0] // max(h_, 1) if width is None else width[0]  # type: ignore[index]
    n = w_ * h_ if points is None else points[0]
    if w_ * h_ != n:
        raise InputError(f"{path}: PCD header says WIDTH*HEIGHT = {w_}*{h_} but POINTS = {n}")
    return w_, h_, n


def _layout(path: Path, h: dict[str, list[str]]) -> tuple[list[str], np.dtype, int]:
    """(field names, little-endian record dtype, number of points) from the header.

    ``_`` fields (PCL's padding, e.g. ``_ 1 U 4``) and repeated names get private keys; a field with
    COUNT > 1 is a sub-array (its first element is what a Scan uses).
    """
    for k in ("FIELDS", "SIZE", "TYPE"):
        if k not in h:
            raise InputError(f"{path}: PCD header has no {k} line")
    names, types = h["FIELDS"], h["TYPE"]
    sizes = _ints(path, h, "SIZE") or []
    counts = _ints(path, h, "COUNT") or [1] * len(names)
    if not (len(names) == len(sizes) == len(types) == len(counts)):
        raise InputError(
            f"{path}: PCD header lists {len(names)} FIELDS but {len(sizes)} SIZE, {len(types)} TYPE, "
            f"{len(counts)} COUNT entries"
        )
    n = _shape(path, h)[2]
    fields = []
    seen: set[str] = set()
    for i, (name, s, t, c) in enumerate(zip(names, sizes, types, counts, strict=True)):
        code = _TYPES.get((t.upper(), s))
        if code is None or c < 1:
            raise InputError(f"{path}: PCD field {name!r} has unsupported TYPE {t} SIZE {s} COUNT {c}")
        key = name if (name not in seen and name != "_") else f"_pad{i}"
        seen.add(key)
        fields.append((key, "<" + code, (c,)) if c > 1 else (key, "<" + code))
    return names, np.dtype(fields), n


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
    inten = col("intensity") if idx["intensity"] is not None else None
    return make_scan(path, xyz, inten, ring, width if organised else None)


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
    width, height, _ = _shape(path, h)
    return _columns(path, names, rec, width, height)


def _read_ascii(path: Path, body: bytes, names: list[str], dtype: np.dtype, n: int) -> np.ndarray:
    fields = dtype.fields  # None only for an unstructured dtype, which has no names either
    ncol = 0 if fields is None else sum(max(1, int(np.prod(fields[k][0].shape))) for k in dtype.names or ())
    text = body.decode("ascii", errors="replace")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data" -> handled below
            table = np.loadtxt(io.StringIO(text), dtype=np.float64, ndmin=2)
    except ValueError as e:
        why = re.sub(r"; use `usecols`.*", "", " ".join(str(e).split()))  # numpy's advice to its caller
        raise InputError(f"{path}: bad ascii PCD data ({why}; a truncated or edited file?)") from None
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


#: header comment of each writer style; MATLAB's names "MATLAB®" in UTF-8 (issue 20's report)
_FIRST_LINE = {
    "plain": b"# .PCD v0.7 - Point Cloud Data file format\n",
    "pcl": b"# .PCD v0.7 - Point Cloud Data file format\n",
    "open3d": b"# .PCD v0.7 - Point Cloud Data file format\n",
    "matlab": "# Point Cloud Data file written by MATLAB\u00ae pcwrite\n".encode("utf-8"),
}
PCD_STYLES = tuple(_FIRST_LINE)
_PCL_STEP = 32  # bytes per point of PCL's aligned point types (EIGEN_ALIGN16)


def _style_fields(scan: Scan, style: str) -> tuple[list[tuple[str, str, np.ndarray]], list[int] | None]:
    """(name, little-endian type, values) of each field in the style's order, and the byte offsets
    of PCL's in-memory record (32 bytes, padding between) or None for packed records."""
    pts = np.asarray(scan.points, dtype=np.float64).reshape(-1, 3)
    xyz = [("x", "<f4", pts[:, 0]), ("y", "<f4", pts[:, 1]), ("z", "<f4", pts[:, 2])]
    inten = [("intensity", "<f4", np.asarray(scan.intensity, dtype=np.float64))] if scan.has_intensity else []
    ring = [] if scan.ring is None else [("ring", "<u2", np.asarray(scan.ring))]
    if style == "open3d":  # Open3D's tensor writer: the other attributes after x y z, last added first
        return xyz + ring + inten, None
    if style == "matlab":  # MATLAB's pointCloud has Location and Intensity, no ring
        return xyz + inten, None
    if style == "pcl":  # the Velodyne driver's point (x y z _ intensity ring _ time _), or PointXYZI
        if not ring:
            return xyz + inten, [0, 4, 8, 16]
        az = np.arctan2(pts[:, 1], pts[:, 0])  # seconds since the sweep started, 10 Hz clockwise
        sweep = [("time", "<f4", np.mod(np.pi - az, 2 * np.pi) / (2 * np.pi) * 0.1)]
        return xyz + inten + ring + sweep, [0, 4, 8, 16, 20, 24]
    return xyz + inten + ring, None


def _header_fields(fields: list[tuple[str, str, np.ndarray]], offsets: list[int] | None) -> list[str]:
    """FIELDS, SIZE, TYPE, COUNT lines; with offsets, each gap is a ``_`` field of that many bytes
    (``_ 1 U <bytes>``), as PCL's writer declares the padding of a binary record."""
    cols: list[tuple[str, int, str, int]] = []
    at = 0
    for k, (name, t, _) in enumerate(fields):
        dt = np.dtype(t)
        if offsets is not None and offsets[k] > at:
            cols.append(("_", 1, "U", offsets[k] - at))
        cols.append((name, dt.itemsize, {"f": "F", "u": "U", "i": "I"}[dt.kind], 1))
        at = (offsets[k] if offsets is not None else at) + dt.itemsize
    if offsets is not None and at < _PCL_STEP:
        cols.append(("_", 1, "U", _PCL_STEP - at))
    return [
        f"{key} {' '.join(str(c[j]) for c in cols)}\n"
        for j, key in enumerate(("FIELDS", "SIZE", "TYPE", "COUNT"))
    ]


def write_pcd(
    path: str | Path,
    scan: Scan,
    data: str = "binary",
    organised: tuple[int, int] | None = None,
    style: str = "plain",
) -> Path:
    """Write ``scan`` as PCD v0.7, atomically, the way one of several tools writes it.

    data: ``"binary"`` (default), ``"ascii"`` or ``"binary_compressed"``.
    organised: (HEIGHT, WIDTH) to write an organised cloud (row-major: point k is row k // WIDTH);
        the scan must then hold HEIGHT * WIDTH points, (0, 0, 0) where a pixel has no return.
    style: ``"plain"`` (default): x y z intensity (float32) [ring (uint16)]. ``"pcl"``: PCL's
        PCLPointCloud2 writer on a Velodyne driver's cloud (ROS ``pointcloud_to_pcd``): binary
        records of 32 bytes declared with ``_`` padding fields, x y z intensity ring and ``time``
        (float32 s into the sweep); ascii and binary_compressed without the padding, as PCL writes
        them. ``"open3d"``: Open3D's tensor writer (x y z ring intensity). ``"matlab"``: MATLAB
        ``pcwrite``: a first comment line naming "MATLAB®" in UTF-8, x y z intensity, no ring.
    """
    if data not in ("binary", "ascii", "binary_compressed"):
        raise ValueError(f"data must be 'binary', 'ascii' or 'binary_compressed', got {data!r}")
    if style not in _FIRST_LINE:
        raise ValueError(f"style must be one of {PCD_STYLES}, got {style!r}")
    n = len(scan)
    height, width = (1, n) if organised is None else (int(organised[0]), int(organised[1]))
    if height * width != n:
        raise ValueError(f"organised {organised} needs {height * width} points, the scan has {n}")
    fields, offsets = _style_fields(scan, style)
    if data != "binary":
        offsets = None  # PCL writes padding fields only in binary records
    names = [f[0] for f in fields]
    if offsets is None:
        rec = np.empty(n, dtype=[(f, t) for f, t, _ in fields])
    else:
        formats = [t for _, t, _ in fields]
        layout = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": _PCL_STEP})
        rec = np.zeros(n, dtype=layout)
    for name, _, values in fields:
        rec[name] = values
    header = _FIRST_LINE[style] + (
        "VERSION 0.7\n"
        + "".join(_header_fields(fields, offsets))
        + f"WIDTH {width}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    ).encode("ascii")
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
    return atomic_write(path, header + payload)
