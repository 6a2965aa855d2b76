"""Point-cloud readers picked by file extension, and the checks every reader shares.

``read_scan(path)`` dispatches on the suffix through a small registry (``@reader(".pcd")``).
Formats are described in interface.md; field names are matched case-insensitively, without a
trailing unit in parentheses (ouster-cli's ``X1 (m)``), with a few common aliases (``laser_id``
for ``ring``, VeloView's ``Points:0`` for ``x``, CloudCompare's ``scalar_Intensity`` for
``intensity``).

Rows whose x, y, z or intensity is not finite are dropped (Velodyne drivers write NaN for "no
return"), and so are points exactly at the origin (Ouster's organised clouds write (0, 0, 0) for
"no return"); a file whose rows are all unusable, or that has no rows, raises ``InputError``.
"""

from __future__ import annotations

import io
import re
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..types import Scan

__all__ = ["read_scan", "reader", "supported_scan_suffixes", "FIELD_ALIASES", "write_csv"]

ReadFn = Callable[[Path, "int | None"], Scan]
#: farther than any LiDAR reaches (automotive ones 200-1000 m, survey scanners some 6 km): a point
#: beyond is not a measurement but a damaged or misread file
MAX_RANGE_M = 10_000.0
_READERS: dict[str, ReadFn] = {}

#: canonical field -> accepted names (lower case)
FIELD_ALIASES: dict[str, tuple[str, ...]] = {
    "x": ("x", "points:0", "points_m_xyz:0", "point:0", "x1"),
    "y": ("y", "points:1", "points_m_xyz:1", "point:1", "y1"),
    "z": ("z", "points:2", "points_m_xyz:2", "point:2", "z1"),
    "intensity": (
        "intensity",
        "scalar_intensity",
        "reflectance",
        "scalar_reflectance",
        "reflectivity",
        "scalar_reflectivity",
        "signal",
        "i",
    ),
    "ring": ("ring", "laser_id", "scalar_ring", "scalar_laser_id", "ring_id", "row"),
}
_UNIT = re.compile(r"\s*\([^()]*\)$")  # a trailing unit, as in ouster-cli's "X1 (m)"


def reader(*suffixes: str) -> Callable[[ReadFn], ReadFn]:
    """Register a reader ``fn(path, intensity_column) -> Scan`` for the given suffixes."""

    def register(fn: ReadFn) -> ReadFn:
        for s in suffixes:
            _READERS[s.lower()] = fn
        return fn

    return register


def supported_scan_suffixes() -> list[str]:
    """Suffixes with a registered reader, e.g. ``['.bin', '.csv', '.pcd', '.ply']``."""
    return sorted(_READERS)


def read_scan(path: str | Path, intensity_column: int | None = None) -> Scan:
    """Read one LiDAR scan; the reader is chosen by the file's suffix.

    intensity_column: column of intensity in a CSV file without header (ignored otherwise).
    Returns a ``Scan`` (points (N,3) float64 LiDAR frame metres, intensity (N,), ring (N,) int32
    or None). Raises ``InputError`` naming the file and the problem.
    """
    p = Path(path)
    read = _READERS.get(p.suffix.lower())
    if read is None:
        raise InputError(f"{p}: no reader for {p.suffix!r}; supported: {supported_scan_suffixes()}")
    if not p.is_file():
        raise InputError(f"{p}: file not found")
    if p.stat().st_size == 0:
        raise InputError(f"{p}: empty file")
    try:
        return read(p, intensity_column)
    except InputError:
        raise
    except (ValueError, UnicodeDecodeError, OSError, IndexError) as e:
        raise InputError(f"{p}: cannot read as a {p.suffix} point cloud ({e})") from None


def find_fields(path: Path, names: Sequence[str]) -> dict[str, int | None]:
    """Indices of x, y, z, intensity and ring among ``names`` (intensity and ring None when absent);
    InputError when x, y or z is missing."""
    low = [_UNIT.sub("", str(n).strip().strip('"').strip("'")).lower() for n in names]
    found: dict[str, int | None] = {}
    for key, aliases in FIELD_ALIASES.items():
        idx = next((low.index(a) for a in aliases if a in low), None)
        if idx is None and key in ("x", "y", "z"):
            raise InputError(f"{path}: no {key!r} field; fields present: {list(names)}")
        found[key] = idx
    return found


def make_scan(
    path: Path,
    xyz: np.ndarray,
    intensity: np.ndarray | None,
    ring: np.ndarray | None,
    columns: int | None = None,
) -> Scan:
    """Check values, drop non-finite rows and (0, 0, 0) points; the ``Scan`` (float64 / int32 copies).
    intensity None: the file has no intensity field (zeros, ``Scan.has_intensity`` False)."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    has_intensity = intensity is not None
    inten = np.asarray(intensity, dtype=np.float64).reshape(-1) if has_intensity else np.zeros(len(xyz))
    n = xyz.shape[0]
    if n == 0:
        raise InputError(f"{path}: the file holds no points")
    _impossible(path, xyz)
    ok = np.isfinite(xyz).all(axis=1) & np.isfinite(inten)
    if not ok.any():
        raise InputError(f"{path}: all {n} points have non-finite x, y, z or intensity (NaN/inf)")
    ok &= (xyz != 0).any(axis=1)
    if not ok.any():
        raise InputError(f"{path}: all {n} points are at (0, 0, 0) (no return)")
    r = None
    if ring is not None:
        rf = np.asarray(ring).reshape(-1)
        if rf.dtype.kind == "f":
            bad = ok & ~(np.isfinite(rf) & (rf == np.round(rf)))
            if bad.any():
                raise InputError(f"{path}: ring values must be whole numbers; found {rf[bad][:3].tolist()}")
            rf = np.where(ok, rf, 0)
        if (rf[ok] < 0).any() or (rf[ok] > 65535).any():
            raise InputError(
                f"{path}: ring values must be in [0, 65535]; found {int(rf[ok].min())}..{int(rf[ok].max())}"
            )
        r = rf.astype(np.int32)
    if not ok.all():
        xyz, inten = xyz[ok], inten[ok]
        r = None if r is None else r[ok]
    return Scan(
        points=np.ascontiguousarray(xyz),
        intensity=np.ascontiguousarray(inten),
        ring=r,
        source=str(path),
        columns=columns,
        has_intensity=has_intensity,
    )


def _impossible(path: Path, xyz: np.ndarray) -> None:
    """InputError naming ``path`` when some point is at infinity or beyond ``MAX_RANGE_M`` (NaN is
    a driver's "no return" and is dropped by the caller)."""
    with np.errstate(invalid="ignore"):
        far = (np.abs(xyz) > MAX_RANGE_M).any(axis=1)  # NaN compares False, infinity True
    if far.any():
        k = int(np.flatnonzero(far)[0])
        x, y, z = (f"{v:.3g}" for v in xyz[k])
        raise InputError(
            f"{path}: {int(far.sum())} of {len(xyz)} points are at infinity or farther than any LiDAR "
            f"reaches ({MAX_RANGE_M / 1000:g} km; point {k}: ({x}, {y}, {z}) m): the values are impossible, "
            "the file is damaged or not in the format its name says"
        )


# --------------------------------------------------------------------------- KITTI .bin
@reader(".bin")
def read_kitti_bin(path: Path, intensity_column: int | None = None) -> Scan:
    """KITTI velodyne scan: little-endian float32 records ``x y z intensity``."""
    raw = path.read_bytes()
    if len(raw) % 16:
        raise InputError(
            f"{path}: size {len(raw)} bytes is not a multiple of 16 (float32 x y z intensity); truncated?"
        )
    a = np.frombuffer(raw, dtype="<f4").reshape(-1, 4)
    try:
        return make_scan(path, a[:, :3], a[:, 3], None)
    except InputError as err:
        if len(raw) % 32 == 0 and _as_float64(raw):
            raise InputError(
                f"{err}; read as float64 records it holds plausible points: KITTI's .bin is float32 x y z "
                "intensity (write it as float32)"
            ) from None
        raise


def _as_float64(raw: bytes) -> bool:
    """Whether ``raw`` read as float64 records x y z intensity gives points a LiDAR could measure."""
    a = np.frombuffer(raw, dtype="<f8").reshape(-1, 4)[:, :3]
    with np.errstate(invalid="ignore"):
        return bool(np.all(np.isnan(a) | (np.abs(a) <= MAX_RANGE_M)))


# --------------------------------------------------------------------------- CSV of many tools
def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def _split(line: str, sep: str | None) -> list[str]:
    return [t.strip() for t in line.split(sep)]


def _csv_layout(path: Path, lines: list[str]) -> tuple[list[str] | None, list[str], str | None]:
    """(header names or None, data lines, separator or None for spaces) of a CSV export.

    Lines before the data that start with ``#`` or ``//`` are comments; the last of them names the
    columns when the first data line is numeric and the names fit it (ouster-cli writes
    ``# TIMESTAMP (ns), ROW, ...``, CloudCompare ``//X Y Z Intensity``, then optionally a line with
    the point count). The separator is the first of ``,`` ``;`` tab found in the first data line,
    else runs of spaces.
    """
    comments: list[str] = []
    k = 0
    while k < len(lines) and (not lines[k].strip() or lines[k].lstrip().startswith(("#", "//"))):
        if lines[k].strip():
            comments.append(lines[k].lstrip().lstrip("#/").strip())
        k += 1
    body = [ln for ln in lines[k:] if ln.strip()]
    if not body:
        raise InputError(f"{path}: the file holds no points")
    sep = next((c for c in (",", ";", "\t") if c in body[min(1, len(body) - 1)]), None)
    first = _split(body[0], sep)
    if len(first) == 1 and first[0].isdigit() and len(body) > 1 and len(_split(body[1], sep)) > 1:
        body, first = body[1:], _split(body[1], sep)  # CloudCompare's optional point-count line
    if not all(_is_number(t) for t in first if t):
        return first, body[1:], sep
    if comments:
        names = _split(comments[-1], sep)
        if len(names) == len(first) and not all(_is_number(t) for t in names if t):
            return names, body, sep
    return None, body, sep


@reader(".csv")
def read_csv(path: Path, intensity_column: int | None = None) -> Scan:
    """A CSV export: a header row naming the columns (ILCC's and VeloView's ``Points:0,...``,
    LidarView's ``"Points_m_XYZ:0",...``, ouster-cli's commented ``X1 (m)``, CloudCompare's
    ``//X,Y,Z,Intensity``; intensity found by name, else at ``intensity_column``, else none), or no
    header: x y z first, intensity at ``intensity_column`` (a 4-column file needs none; 3 columns:
    no intensity)."""
    lines = path.read_bytes().decode("utf-8-sig", errors="replace").splitlines()
    head, body_lines, sep = _csv_layout(path, lines)
    ncols = len(head) if head is not None else len(_split(body_lines[0], sep))
    if head is not None:
        cols = find_fields(path, head)
        if cols["intensity"] is None and intensity_column is not None:  # the configured column
            if not 3 <= int(intensity_column) < ncols:
                raise InputError(
                    f"{path}: intensity_column {intensity_column} is outside the {ncols} columns"
                )
            cols["intensity"] = int(intensity_column)
    else:
        if intensity_column is None:
            if ncols > 4:
                raise InputError(
                    f"{path}: CSV without a header row has {ncols} columns; set lidar.intensity_column "
                    "in config.yaml to say which holds intensity"
                )
            intensity_column = 3 if ncols == 4 else None  # x y z alone: no intensity
        if intensity_column is not None and not 3 <= intensity_column < ncols:
            raise InputError(
                f"{path}: intensity_column {intensity_column} is outside the file's {ncols} columns"
            )
        cols = {"x": 0, "y": 1, "z": 2, "intensity": intensity_column, "ring": None}
    if not body_lines:
        raise InputError(f"{path}: the file holds no points")
    # x, y and z are never None (find_fields refuses a file without them)
    want = [c for c in (cols["x"], cols["y"], cols["z"], cols["intensity"], cols["ring"]) if c is not None]
    try:
        data = np.loadtxt(
            io.StringIO("\n".join(body_lines)), delimiter=sep, usecols=want, ndmin=2, dtype=np.float64
        )
    except ValueError as e:
        raise InputError(f"{path}: bad CSV data ({' '.join(str(e).split())})") from None
    widths = {len(ln.split(sep)) for ln in body_lines[:: max(1, len(body_lines) // 1000)]}
    if widths != {ncols}:
        raise InputError(f"{path}: rows have {sorted(widths)} values, the first row has {ncols}")
    inten = data[:, 3] if cols["intensity"] is not None else None
    ring = data[:, -1] if cols["ring"] is not None else None
    return make_scan(path, data[:, :3], inten, ring)


def write_csv(path: str | Path, scan: Scan, ring_name: str = "laser_id") -> Path:
    """Write ``scan`` as ILCC's / VeloView's CSV: header ``Points:0,Points:1,Points:2,intensity,laser_id``
    (ring column named ``ring_name``; omitted when the scan has no ring, and intensity when it has
    none), atomically."""
    from .files import atomic_write

    pts = np.asarray(scan.points, dtype=np.float64).reshape(-1, 3)
    cols = [pts[:, 0], pts[:, 1], pts[:, 2]]
    names = ["Points:0", "Points:1", "Points:2"]
    fmt = ["%.6f", "%.6f", "%.6f"]
    if scan.has_intensity:
        cols.append(np.asarray(scan.intensity, dtype=np.float64))
        names.append("intensity")
        fmt.append("%.6g")
    if scan.ring is not None:
        cols.append(np.asarray(scan.ring, dtype=np.float64))
        names.append(ring_name)
        fmt.append("%d")
    row = ",".join(fmt) + "\n"
    values = np.stack(cols, axis=1).ravel().tolist()
    body = (row * len(pts)) % tuple(values) if len(pts) else ""
    return atomic_write(path, (",".join(names) + "\n" + body).encode("ascii"))
