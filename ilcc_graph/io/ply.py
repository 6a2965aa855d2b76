"""A small PLY reader/writer for point clouds: ``ascii``, ``binary_little_endian`` and
``binary_big_endian``; the ``vertex`` element's scalar properties x y z intensity [ring] (any
order, any PLY type, extra properties ignored; names through ``io.scans``' aliases, e.g.
CloudCompare's ``scalar_Intensity``). Elements before ``vertex`` must have no list properties;
elements after it (faces, PCL's ``camera`` and ``range_grid``) are not read. Header comments may
be in any encoding.
The writer produces binary little-endian PLY with float x y z intensity, [ushort ring],
[uchar red green blue].
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError, quote
from ..types import Scan
from .files import atomic_write
from .scans import find_fields, make_scan, reader

__all__ = ["read_ply", "write_ply"]

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


_MAX_LINE = 1 << 16  # bytes: no header line of a PLY file is longer


def _header_lines(path: Path, raw: bytes) -> tuple[list[tuple[int, str]], int]:
    """(line number, text) of the header lines between ``ply`` and ``end_header`` that are not
    comments, and the data offset. Byte-safe: ``comment`` and ``obj_info`` lines (free text in any
    encoding: CloudCompare, MATLAB, file names) are skipped before anything is decoded; CR line
    ends, blank lines and runs of spaces or tabs are accepted."""
    lines: list[tuple[int, str]] = []
    pos, lineno = 0, 0
    while True:
        end = raw.find(b"\n", pos, pos + _MAX_LINE)
        if end < 0:
            raise InputError(f"{path}: PLY header has no end_header line (truncated?)")
        lineno += 1
        line = raw[pos:end].strip()
        pos = end + 1
        if lineno == 1:
            if line != b"ply":
                raise InputError(f"{path}: not a PLY file (does not start with 'ply')")
            continue
        if line == b"end_header":
            return lines, pos
        if not line or line.split(None, 1)[0] in (b"comment", b"obj_info"):
            continue
        try:
            lines.append((lineno, line.decode("ascii")))
        except UnicodeDecodeError:
            raise InputError(f"{path}: PLY header line {lineno} is neither a comment nor text") from None


def _header(path: Path, raw: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, str]], bool]], int]:
    """(format, elements [(name, count, [(prop, type)], has_list)], data offset)."""
    lines, start = _header_lines(path, raw)
    fmt = ""
    elements: list[tuple[str, int, list[tuple[str, str]], bool]] = []
    for lineno, ln in lines:
        tok = ln.split()
        if tok[0] == "format" and len(tok) >= 2:
            fmt = tok[1]
        elif tok[0] == "element" and len(tok) == 3:
            try:
                elements.append((tok[1], int(tok[2]), [], False))
            except ValueError:
                raise InputError(f"{path}: bad PLY element line {lineno} {quote(ln)}") from None
        elif tok[0] == "property" and elements and len(tok) >= 3:
            name, count, props, has_list = elements[-1]
            if tok[1] == "list":
                elements[-1] = (name, count, props, True)
                props.append((tok[-1], "list"))
            elif len(tok) == 3 and tok[1] in _PLY_TYPES:
                props.append((tok[2], _PLY_TYPES[tok[1]]))
            else:
                raise InputError(f"{path}: unsupported PLY property line {lineno} {quote(ln)}")
        else:
            raise InputError(f"{path}: unexpected PLY header line {lineno} {quote(ln)}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(
            f"{path}: unsupported PLY format {fmt!r}; expected ascii or binary_little/big_endian"
        )
    return fmt, elements, start


@reader(".ply")
def read_ply(path: Path, intensity_column: int | None = None) -> Scan:
    """Read the ``vertex`` element of a PLY file: x y z intensity [ring]."""
    path = Path(path)
    raw = path.read_bytes()
    fmt, elements, start = _header(path, raw)
    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise InputError(f"{path}: PLY file has no 'vertex' element (elements: {names})")
    vi = names.index("vertex")
    for name, _, _, has_list in elements[:vi]:
        if has_list:
            raise InputError(
                f"{path}: PLY element {name!r} with list properties before 'vertex' is not supported"
            )
    _, n, props, has_list = elements[vi]
    if has_list:
        raise InputError(f"{path}: PLY 'vertex' element has list properties; expected scalar x y z intensity")
    if n == 0:
        raise InputError(f"{path}: the file holds no points (element vertex 0)")
    prop_names = [p for p, _ in props]
    idx = find_fields(path, prop_names)
    if fmt == "ascii":
        text = raw[start:].decode("ascii", errors="replace").split()
        skip = sum(c * len(p) for _, c, p, _ in elements[:vi])
        need = n * len(props)
        if len(text) - skip < need:
            raise InputError(
                f"{path}: ascii PLY truncated: {n} vertices need {need} values, found {len(text) - skip}"
            )
        try:
            table = np.array(text[skip : skip + need], dtype=np.float64).reshape(n, len(props))
        except ValueError as e:
            raise InputError(f"{path}: non-numeric value in ascii PLY data ({e})") from None

        def col(k: str) -> np.ndarray:  # the value as its declared type holds it (float text -> float32)
            return table[:, idx[k]].astype(props[idx[k]][1])  # type: ignore[index]
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        offset = start
        for _, c, p, _ in elements[:vi]:
            offset += c * np.dtype([(f"p{i}", order + t) for i, (_, t) in enumerate(p)]).itemsize
        dt = np.dtype([(f"p{i}", order + t) for i, (_, t) in enumerate(props)])
        if len(raw) - offset < n * dt.itemsize:
            raise InputError(
                f"{path}: binary PLY truncated: {n} vertices of {dt.itemsize} bytes need {n * dt.itemsize} "
                f"bytes, {max(0, len(raw) - offset)} present"
            )
        rec = np.frombuffer(raw, dtype=dt, count=n, offset=offset)

        def col(k: str) -> np.ndarray:
            return rec[f"p{idx[k]}"]

    xyz = np.stack([col("x"), col("y"), col("z")], axis=1)
    ring = col("ring") if idx["ring"] is not None else None
    return make_scan(path, xyz, col("intensity") if idx["intensity"] is not None else None, ring)


def write_ply(path: str | Path, scan: Scan, rgb: np.ndarray | None = None) -> Path:
    """Write ``scan`` as binary little-endian PLY, atomically.

    rgb: optional (N, 3) uint8 colours (red, green, blue) per point.
    """
    n = len(scan)
    fields = [
        ("x", "<f4", "float"),
        ("y", "<f4", "float"),
        ("z", "<f4", "float"),
    ] + ([("intensity", "<f4", "float")] if scan.has_intensity else [])
    if scan.ring is not None:
        fields.append(("ring", "<u2", "ushort"))
    if rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.shape != (n, 3):
            raise ValueError(f"rgb must have shape ({n}, 3), got {rgb.shape}")
        fields += [("red", "u1", "uchar"), ("green", "u1", "uchar"), ("blue", "u1", "uchar")]
    rec = np.empty(n, dtype=[(f, t) for f, t, _ in fields])
    pts = np.asarray(scan.points, dtype=np.float64).reshape(-1, 3)
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if scan.has_intensity:
        rec["intensity"] = scan.intensity
    if scan.ring is not None:
        rec["ring"] = scan.ring
    if rgb is not None:
        rec["red"], rec["green"], rec["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    header = f"ply\nformat binary_little_endian 1.0\ncomment written by ilcc_graph\nelement vertex {n}\n"
    header += "".join(f"property {pt} {f}\n" for f, _, pt in fields) + "end_header\n"
    return atomic_write(path, header.encode("ascii") + rec.tobytes())
