"""PCD files as real tools write them, read back value for value (PLY and CSV: test_io_writers_ply_csv).

Each file is written here byte for byte from the tool's documented layout: the header text the
tool prints and its record layout (PCL's ``PCLPointCloud2`` writer declares the padding of the
C++ point struct as ``_`` fields, e.g. ``_ 1 U 4``; its ``binary_compressed`` stores the fields one
after the other, each an LZF-packed array). Where Open3D is installed its real writer makes the
files, and its reader cross-checks x y z of ours.
"""

from __future__ import annotations

import struct
from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ilcc_graph.app import main
from ilcc_graph.errors import InputError
from ilcc_graph.io import PCD_STYLES, read_calibration, read_scan, write_pcd
from ilcc_graph.io.lzf import lzf_compress
from ilcc_graph.types import Scan

PCL_FIRST = "# .PCD v0.7 - Point Cloud Data file format\n"
CHI2_6_9997 = 25.0  # chi2(6) at 99.97 %: the end-to-end NEES bound of the other simulated sensors


def _padded(n: int, names: list[str], formats: list[str], offsets: list[int], step: int) -> np.ndarray:
    """n records laid out like a C++ point struct: fields at their offsets, the padding bytes 0xA5
    (what an uninitialised struct holds; the reader must not look at them)."""
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    return np.frombuffer(bytearray(b"\xa5") * (n * step), dtype=dt)


def _shape_header(width: int, height: int, data: str) -> str:
    n = width * height
    return f"WIDTH {width}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"


def _o3d_xyz(path: Path) -> np.ndarray | None:
    """x y z of the returns (finite, not at the origin) as Open3D reads the file; None without Open3D."""
    try:
        import open3d as o3d
    except ImportError:
        return None
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    # the legacy reader: Open3D 0.20's tensor reader overruns its buffers on PCL's ``_`` fields
    # with COUNT > 1 (the process aborts), the legacy one skips them
    pc = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    p = np.asarray(pc.points, dtype=np.float64)
    return p[np.isfinite(p).all(axis=1) & (p != 0).any(axis=1)]


def _cross_check(path: Path, scan: Scan) -> None:
    theirs = _o3d_xyz(path)
    if theirs is not None:
        np.testing.assert_allclose(theirs, scan.points, rtol=0, atol=1e-6)


def _rng_points(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).normal(0, 8, (n, 3)).astype(np.float32)


# --------------------------------------------------------------------------- MATLAB pcwrite
@pytest.mark.parametrize("encoding", ["utf-8", "cp1252"])
@pytest.mark.parametrize("data", ["ascii", "binary"])
def test_matlab_pcwrite_header_comment_in_any_encoding(tmp_path: Path, encoding: str, data: str) -> None:
    """MATLAB's first comment line names "MATLAB®" (UTF-8 as reported in issue 20, or the Windows
    code page); its organised clouds (velodyneFileReader: one row per laser) hold NaN where a laser
    saw nothing."""
    height, width = 2, 3
    pts = _rng_points(height * width, 1)
    pts[[1, 4]] = np.nan
    inten = np.array([3, 0, 250, 17, 99, 1], np.float32)
    header = (
        "# Point Cloud Data file written by MATLAB\u00ae pcwrite\n"
        + PCL_FIRST
        + "VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        + _shape_header(width, height, data)
    ).encode(encoding)
    assert "\u00ae".encode(encoding) in header and not header.isascii()
    if data == "ascii":
        body = "".join(
            " ".join("NaN" if np.isnan(v) else f"{v:.9g}" for v in (*p, i)) + "\n"
            for p, i in zip(pts, inten, strict=True)
        ).encode()
    else:
        body = np.column_stack([pts, inten]).astype("<f4").tobytes()
    path = tmp_path / f"matlab_{data}.pcd"
    path.write_bytes(header + body)
    s = read_scan(path)
    keep = [0, 2, 3, 5]
    np.testing.assert_array_equal(s.points, pts[keep].astype(np.float64))
    np.testing.assert_array_equal(s.intensity, inten[keep])
    np.testing.assert_array_equal(s.ring, [0, 0, 1, 1])  # organised: the row is the ring
    assert s.columns == width
    _cross_check(path, s)


# --------------------------------------------------------------------------- PCL's PCLPointCloud2 writer
def test_pcl_ros_velodyne_cloud_with_padding_fields(tmp_path: Path) -> None:
    """``pcl_ros pointcloud_to_pcd`` on a Velodyne driver's cloud (x y z at 0, intensity 16, ring 20,
    time 24, 32 bytes a point): the gaps are declared as ``_`` fields of 4, 2 and 4 bytes."""
    n = 9
    rec = _padded(n, ["x", "y", "z", "intensity", "ring", "time"], ["<f4"] * 4 + ["<u2", "<f4"],
                  [0, 4, 8, 16, 20, 24], 32)  # fmt: skip
    pts = _rng_points(n, 2)
    rec["x"], rec["y"], rec["z"] = pts.T
    rec["intensity"] = np.arange(n) * 11.5
    rec["ring"] = [0, 15, 3, 7, 7, 1, 14, 2, 9]
    rec["time"] = np.linspace(0, 0.099, n)
    header = (
        PCL_FIRST + "VERSION 0.7\nFIELDS x y z _ intensity ring _ time _\nSIZE 4 4 4 1 4 2 1 4 1\n"
        "TYPE F F F U F U U F U\nCOUNT 1 1 1 4 1 1 2 1 4\n" + _shape_header(n, 1, "binary")
    )
    path = tmp_path / "velodyne.pcd"
    path.write_bytes(header.encode() + rec.tobytes())
    s = read_scan(path)
    np.testing.assert_array_equal(s.points, pts.astype(np.float64))
    np.testing.assert_array_equal(s.intensity, np.arange(n) * 11.5)
    np.testing.assert_array_equal(s.ring, [0, 15, 3, 7, 7, 1, 14, 2, 9])
    assert s.ring.dtype == np.int32 and s.columns is None
    _cross_check(path, s)


@pytest.mark.parametrize("ring_type", ["U1", "U2"])
def test_ouster_ros_organised_cloud(tmp_path: Path, ring_type: str) -> None:
    """ouster_ros' point: x y z, intensity (the signal) 16, t (ns, U4) 20, reflectivity 24, ring 26
    (uint8 in older drivers, uint16 now), ambient 28, range 32; 48 bytes. (0, 0, 0) is no return;
    intensity is taken over reflectivity, and the ring (0 = top beam) as the driver numbers it."""
    height, width = 4, 5
    n = height * width
    u1 = ring_type == "U1"
    rec = _padded(n, ["x", "y", "z", "intensity", "t", "reflectivity", "ring", "ambient", "range"],
                  ["<f4"] * 4 + ["<u4", "<u2", "<u1" if u1 else "<u2", "<u2", "<u4"],
                  [0, 4, 8, 16, 20, 24, 26, 28, 32], 48)  # fmt: skip
    pts = _rng_points(n, 3)
    pts[[2, 11, 12]] = 0.0
    rec["x"], rec["y"], rec["z"] = pts.T
    rec["intensity"] = np.arange(n) * 3.0 + 1
    rec["t"] = np.arange(n) * 48_828
    rec["reflectivity"] = 7
    rec["ring"] = np.repeat(np.arange(height), width)
    rec["ambient"], rec["range"] = 300, 4000
    fields = "x y z _ intensity t reflectivity ring " + ("_ ambient _ range _" if u1 else "ambient _ range _")
    sizes = "4 4 4 1 4 4 2 " + ("1 1 2 1 4 1" if u1 else "2 2 1 4 1")
    types = "F F F U F U U U " + ("U U U U U" if u1 else "U U U U")
    counts = "1 1 1 4 1 1 1 1 " + ("1 1 2 1 12" if u1 else "1 2 1 12")
    header = (
        f"{PCL_FIRST}VERSION 0.7\nFIELDS {fields}\nSIZE {sizes}\nTYPE {types}\nCOUNT {counts}\n"
        + _shape_header(width, height, "binary")
    )
    assert sum(int(a) * int(b) for a, b in zip(sizes.split(), counts.split(), strict=True)) == 48
    path = tmp_path / "os1.pcd"
    path.write_bytes(header.encode() + rec.tobytes())
    s = read_scan(path)
    keep = np.setdiff1d(np.arange(n), [2, 11, 12])
    np.testing.assert_array_equal(s.points, pts[keep].astype(np.float64))
    np.testing.assert_array_equal(s.intensity, (np.arange(n) * 3.0 + 1)[keep])
    np.testing.assert_array_equal(s.ring, np.repeat(np.arange(height), width)[keep])
    assert s.columns == width
    _cross_check(path, s)


def _hesai(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(4)
    return _rng_points(n, 4), rng.integers(0, 256, n).astype(np.float32), \
        1.7e9 + np.arange(n) * 1e-5, rng.integers(0, 64, n).astype(np.uint16)  # fmt: skip


def test_hesai_timestamp_f8_binary_and_pcl_binary_compressed(tmp_path: Path) -> None:
    """Hesai's point (x y z, intensity 16, timestamp F8 24, ring U2 32; 48 bytes) through PCL's
    binary writer, and the same cloud through PCL's binary_compressed writer: no padding fields,
    two uint32 (compressed, uncompressed size), then LZF of the fields one after the other."""
    n = 40
    pts, inten, stamp, ring = _hesai(n)
    rec = _padded(n, ["x", "y", "z", "intensity", "timestamp", "ring"], ["<f4"] * 4 + ["<f8", "<u2"],
                  [0, 4, 8, 16, 24, 32], 48)  # fmt: skip
    rec["x"], rec["y"], rec["z"] = pts.T
    rec["intensity"], rec["timestamp"], rec["ring"] = inten, stamp, ring
    binary = tmp_path / "hesai.pcd"
    binary.write_bytes(
        (
            f"{PCL_FIRST}VERSION 0.7\nFIELDS x y z _ intensity _ timestamp ring _\n"
            "SIZE 4 4 4 1 4 1 8 2 1\nTYPE F F F U F U F U U\nCOUNT 1 1 1 4 1 4 1 1 14\n"
            + _shape_header(n, 1, "binary")
        ).encode()
        + rec.tobytes()
    )
    arrays = [pts[:, 0], pts[:, 1], pts[:, 2], inten, stamp, ring]
    plain = b"".join(np.ascontiguousarray(a).astype(a.dtype.newbyteorder("<")).tobytes() for a in arrays)
    assert len(plain) == n * (4 * 4 + 8 + 2)
    comp = lzf_compress(plain)
    compressed = tmp_path / "hesai_c.pcd"
    compressed.write_bytes(
        (
            f"{PCL_FIRST}VERSION 0.7\nFIELDS x y z intensity timestamp ring\nSIZE 4 4 4 4 8 2\n"
            "TYPE F F F F F U\nCOUNT 1 1 1 1 1 1\n" + _shape_header(n, 1, "binary_compressed")
        ).encode()
        + struct.pack("<II", len(comp), len(plain))
        + comp
    )
    for path in (binary, compressed):
        s = read_scan(path)
        np.testing.assert_array_equal(s.points, pts.astype(np.float64))
        np.testing.assert_array_equal(s.intensity, inten)
        np.testing.assert_array_equal(s.ring, ring)
        _cross_check(path, s)


def _literal_lzf(data: bytes) -> bytes:
    """An LZF stream of literal runs only (control byte = run length - 1, at most 32 bytes a run):
    valid for every LZF decoder, and made without our compressor."""
    return b"".join(bytes([len(data[k : k + 32]) - 1]) + data[k : k + 32] for k in range(0, len(data), 32))


def test_binary_compressed_layout_with_count_and_padding_fields(tmp_path: Path) -> None:
    """The byte layout rule of binary_compressed: field after field (padding ``_`` fields too), and
    within a COUNT > 1 field the point's elements together (point 0's three normals, point 1's...)."""
    n = 6
    pts = _rng_points(n, 5)
    normal = np.arange(3 * n, dtype="<f4").reshape(n, 3) / 10
    pad = np.full((n, 4), 0xA5, np.uint8)
    inten = np.array([1, 2, 300, 4, 5, 65535], "<u2")
    ring = np.array([5, 4, 3, 2, 1, 0], "<u1")
    parts = [pts[:, 0], pts[:, 1], pts[:, 2], normal, pad, inten, ring]
    plain = b"".join(np.ascontiguousarray(a).tobytes() for a in parts)
    header = (
        f"{PCL_FIRST}VERSION 0.7\nFIELDS x y z normal _ intensity ring\nSIZE 4 4 4 4 1 2 1\n"
        "TYPE F F F F U U U\nCOUNT 1 1 1 3 4 1 1\n" + _shape_header(n, 1, "binary_compressed")
    )
    comp = _literal_lzf(plain)
    path = tmp_path / "layout.pcd"
    path.write_bytes(header.encode() + struct.pack("<II", len(comp), len(plain)) + comp)
    s = read_scan(path)
    np.testing.assert_array_equal(s.points, pts.astype(np.float64))
    np.testing.assert_array_equal(s.intensity, inten)
    np.testing.assert_array_equal(s.ring, ring)


def test_pcl_ascii_organised_with_nan(tmp_path: Path) -> None:
    """PCL's ascii writer (PointXYZINormal, organised 2 x 3): "nan" where there is no point, and
    glibc's "-nan" for a NaN with its sign bit set."""
    text = (
        f"{PCL_FIRST}VERSION 0.7\nFIELDS x y z intensity normal_x normal_y normal_z curvature\n"
        "SIZE 4 4 4 4 4 4 4 4\nTYPE F F F F F F F F\nCOUNT 1 1 1 1 1 1 1 1\n"
        + _shape_header(3, 2, "ascii")
        + "1.5 -2.25 0.125 40 0 0 1 0.001\n"
        "nan nan nan 0 nan nan nan nan\n"
        "3 4 5 41 0 1 0 0\n"
        "-nan -nan -nan 0 -nan -nan -nan -nan\n"
        "6 7 8 42 1 0 0 0.5\n"
        "9 10 11 43 0 0 -1 0\n"
    )
    path = tmp_path / "pcl_ascii.pcd"
    path.write_text(text)
    s = read_scan(path)
    np.testing.assert_array_equal(s.points, [[1.5, -2.25, 0.125], [3, 4, 5], [6, 7, 8], [9, 10, 11]])
    np.testing.assert_array_equal(s.intensity, [40, 41, 42, 43])
    np.testing.assert_array_equal(s.ring, [0, 0, 1, 1])
    _cross_check(path, s)


@pytest.mark.parametrize("code", ["U 1", "U 2", "U 4", "I 2", "I 4", "F 4", "F 8"])
def test_ring_and_time_fields_of_any_type(tmp_path: Path, code: str) -> None:
    """ring as any integer or float type next to time fields of the drivers (Ouster ``t`` U4,
    Velodyne ``time`` F4, Hesai ``timestamp`` F8, Livox ``offset_time`` U4), packed as PCL's
    templated writer stores them."""
    t, size = code.split()
    n = 8
    ring = np.array([0, 1, 2, 3, 31, 30, 7, 7])
    fmt = {"U": "<u", "I": "<i", "F": "<f"}[t] + size
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("ring", fmt), ("t", "<u4"), ("time", "<f4"),
                   ("timestamp", "<f8"), ("offset_time", "<u4"), ("intensity", "<f4")])  # fmt: skip
    rec = np.zeros(n, dt)
    pts = _rng_points(n, 6)
    rec["x"], rec["y"], rec["z"] = pts.T
    rec["ring"], rec["intensity"] = ring, np.arange(n)
    rec["t"], rec["time"], rec["timestamp"], rec["offset_time"] = 5, 0.05, 1.7e9, 9
    header = (
        f"{PCL_FIRST}VERSION 0.7\nFIELDS x y z ring t time timestamp offset_time intensity\n"
        f"SIZE 4 4 4 {size} 4 4 8 4 4\nTYPE F F F {t} U F F U F\nCOUNT 1 1 1 1 1 1 1 1 1\n"
        + _shape_header(n, 1, "binary")
    )
    path = tmp_path / "ring.pcd"
    path.write_bytes(header.encode() + rec.tobytes())
    s = read_scan(path)
    np.testing.assert_array_equal(s.ring, ring)
    np.testing.assert_array_equal(s.points, pts.astype(np.float64))
    np.testing.assert_array_equal(s.intensity, np.arange(n))


# --------------------------------------------------------------------------- Open3D's own writers
def o3d_cloud(o3d, n: int, seed: int):  # noqa: ANN001, ANN201 - the open3d module, its PointCloud
    """An Open3D tensor cloud with float32 positions, colours, intensity and a uint16 ring; and the
    (n, 3) points, (n, 1) intensity and (n, 1) ring it holds."""
    rng = np.random.default_rng(seed)
    pts = _rng_points(n, seed)
    inten = rng.uniform(0, 255, (n, 1)).astype(np.float32)
    ring = rng.integers(0, 128, (n, 1)).astype(np.uint16)
    pc = o3d.t.geometry.PointCloud()
    pc.point.positions = o3d.core.Tensor(pts)
    pc.point.colors = o3d.core.Tensor(rng.uniform(0, 1, (n, 3)).astype(np.float32))
    pc.point.intensity = o3d.core.Tensor(inten)
    pc.point.ring = o3d.core.Tensor(ring)
    return pc, pts, inten, ring


@pytest.mark.parametrize("kind", ["ascii", "binary", "binary_compressed"])
def test_open3d_tensor_writer(tmp_path: Path, kind: str) -> None:
    """Open3D's tensor writer: packed ``rgb`` (U4), ``t`` (U4), ``ring`` (U2), ``intensity`` (F4)."""
    o3d = pytest.importorskip("open3d")
    pc, pts, inten, ring = o3d_cloud(o3d, 30, 7)
    pc.point.t = o3d.core.Tensor(np.arange(30, dtype=np.uint32)[:, None])
    path = tmp_path / f"o3d_{kind}.pcd"
    assert o3d.t.io.write_point_cloud(
        str(path), pc, write_ascii=kind == "ascii", compressed=kind == "binary_compressed"
    )
    assert f"DATA {kind}\n".encode() in path.read_bytes()[:600]
    s = read_scan(path)
    np.testing.assert_array_equal(s.points, pts.astype(np.float64))
    np.testing.assert_array_equal(s.intensity, inten[:, 0])
    np.testing.assert_array_equal(s.ring, ring[:, 0])


def test_open3d_legacy_cloud_without_intensity_reads_without_it(tmp_path: Path) -> None:
    """Open3D's legacy cloud keeps x y z (and rgb), no intensity: read as a scan without intensity
    (its board placed by its shape); our writers then leave the field out too."""
    o3d = pytest.importorskip("open3d")
    pts = _rng_points(10, 8).astype(np.float64)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.colors = o3d.utility.Vector3dVector(np.full((10, 3), 0.5))
    path = tmp_path / "legacy.pcd"
    assert o3d.io.write_point_cloud(str(path), pc)
    s = read_scan(path)
    np.testing.assert_allclose(s.points, pts, rtol=1e-6)
    assert not s.has_intensity
    back = write_pcd(tmp_path / "back.pcd", s)
    assert b"FIELDS x y z\n" in back.read_bytes()[:300]
    again = read_scan(back)
    assert not again.has_intensity
    np.testing.assert_array_equal(again.points, s.points)


@pytest.mark.parametrize("style", PCD_STYLES)
@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_our_writer_styles_read_back_and_by_open3d(tmp_path: Path, style: str, data: str) -> None:
    n = 25
    rng = np.random.default_rng(9)
    scan = Scan(_rng_points(n, 9).astype(np.float64), rng.integers(0, 256, n).astype(np.float64),
                rng.integers(0, 32, n).astype(np.int32))  # fmt: skip
    path = write_pcd(tmp_path / f"{style}.pcd", scan, data=data, style=style)
    raw = path.read_bytes()
    if style == "matlab":
        assert "MATLAB\u00ae".encode() in raw.split(b"\n", 1)[0]
    if style == "pcl" and data == "binary":
        assert b"FIELDS x y z _ intensity ring _ time _\n" in raw and b"COUNT 1 1 1 4 1 1 2 1 4\n" in raw
    s = read_scan(path)
    np.testing.assert_array_equal(s.points, scan.points)
    np.testing.assert_array_equal(s.intensity, scan.intensity)
    if style == "matlab":
        assert s.ring is None  # MATLAB's pointCloud has no ring
    else:
        np.testing.assert_array_equal(s.ring, scan.ring)
    _cross_check(path, s)


# --------------------------------------------------------------------------- header robustness
_COMMENT = st.binary(max_size=60).map(lambda b: b"#" + b.replace(b"\n", b" "))
_SPACE = st.sampled_from([b" ", b"  ", b"\t", b" \t "])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    comments=st.lists(st.tuples(st.integers(0, 12), _COMMENT), max_size=5),
    blank=st.lists(st.integers(0, 12), max_size=3),
    crlf=st.booleans(),
    space=_SPACE,
    lower=st.booleans(),
    drop=st.sets(st.sampled_from(["VERSION", "VIEWPOINT", "COUNT", "POINTS"])),
    bom=st.booleans(),
    data=st.sampled_from(["ascii", "binary"]),
)
def test_header_decorations_do_not_change_the_values(
    tmp_path: Path, comments, blank, crlf, space, lower, drop, bom, data
) -> None:
    """Comments anywhere in any bytes, blank lines, CR LF line ends, tabs and runs of spaces,
    lowercase keys, a UTF-8 byte order mark, and the keys PCL can do without."""
    n = 5
    pts = _rng_points(n, 10)
    inten = np.arange(n, dtype=np.float32) * 2
    lines = [
        [b"VERSION", b"0.7"], [b"FIELDS", b"x", b"y", b"z", b"intensity"], [b"SIZE"] + [b"4"] * 4,
        [b"TYPE"] + [b"F"] * 4, [b"COUNT"] + [b"1"] * 4, [b"WIDTH", str(n).encode()], [b"HEIGHT", b"1"],
        [b"VIEWPOINT", b"0", b"0", b"0", b"1", b"0", b"0", b"0"], [b"POINTS", str(n).encode()],
    ]  # fmt: skip
    out = [space.join([t[0].lower() if lower else t[0], *t[1:]]) for t in lines if t[0].decode() not in drop]
    for at, c in sorted(comments, reverse=True):
        out.insert(min(at, len(out)), c)
    for at in blank:
        out.insert(min(at, len(out)), space)
    out.append(space.join([b"data" if lower else b"DATA", data.encode()]))
    eol = b"\r\n" if crlf else b"\n"
    header = (b"\xef\xbb\xbf" if bom else b"") + eol.join(out) + eol
    if data == "ascii":
        body = b"".join(
            b" ".join(f"{v:.9g}".encode() for v in (*p, i)) + eol for p, i in zip(pts, inten, strict=True)
        )
    else:
        body = np.column_stack([pts, inten]).astype("<f4").tobytes()
    path = tmp_path / "h.pcd"
    path.write_bytes(header + body)
    s = read_scan(path)
    np.testing.assert_array_equal(s.points, pts.astype(np.float64))
    np.testing.assert_array_equal(s.intensity, inten)


# --------------------------------------------------------------------------- damaged stays damaged
def test_damaged_headers_are_refused_naming_the_file_and_the_line(tmp_path: Path, capsys) -> None:
    good = (
        f"{PCL_FIRST}VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        + _shape_header(1, 1, "ascii")
        + "1 2 3 4\n"
    ).encode()
    latin = good.replace(b"FIELDS x", "FIELDS x\u00e9".encode("latin-1"))
    cases = {
        "latin.pcd": (latin, "line 3 is neither a comment nor text"),
        "twice.pcd": (good.replace(b"SIZE", b"FIELDS a b c d\nSIZE"), "second FIELDS line (line 4)"),
        "nowidth.pcd": (good.replace(b"WIDTH 1\n", b"").replace(b"POINTS 1\n", b""), "neither WIDTH nor"),
        "badwidth.pcd": (good.replace(b"WIDTH 1", b"WIDTH one"), "WIDTH 'one' is not integers"),
    }
    for name, (content, words) in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(InputError) as e:
            read_scan(tmp_path / name)
        assert name in str(e.value) and words in str(e.value), str(e.value)
    # through the command line: exit 2, the file named
    data = tmp_path / "data"
    (data / "pcd").mkdir(parents=True)
    (data / "img").mkdir()
    (data / "config.yaml").write_text(
        "board: {squares: [6, 8], square_size: 0.075}\nlidar: {model: vlp16}\n"
        "camera: {model: pinhole, width: 64, height: 48, K: [[50, 0, 32], [0, 50, 24], [0, 0, 1]]}\n"
    )
    (data / "pcd" / "0001.pcd").write_bytes(cases["latin.pcd"][0])
    import cv2

    cv2.imwrite(str(data / "img" / "0001.png"), np.zeros((48, 64, 3), np.uint8))
    assert main(["calibrate", str(data), "--out", str(tmp_path / "out"), "--jobs", "1"]) == 2
    err = capsys.readouterr().err
    assert "0001.pcd" in err and "neither a comment nor text" in err


# --------------------------------------------------------------------------- the simulator writes MATLAB's
def test_simulated_matlab_style_set_calibrates_through_the_cli(tmp_path: Path, capsys) -> None:
    """``simulate --pcd-style matlab`` (MATLAB's header comment, no ring field), then ``calibrate``:
    the written extrinsic is within the run's own covariance of the truth (NEES, chi2(6))."""
    data = tmp_path / "matlab"
    argv = ["simulate", str(data), "--lidar", "vlp16", "--camera", "pinhole", "--width", "640",
            "--frames", "8", "--seed", "5", "--pcd-style", "matlab"]  # fmt: skip
    assert main(argv) == 0
    scans = sorted((data / "pcd").glob("*.pcd"))
    assert len(scans) == 8
    head = scans[0].read_bytes()[:400]
    assert head.startswith("# Point Cloud Data file written by MATLAB\u00ae".encode()) and b"ring" not in head
    out = tmp_path / "out"
    assert main(["calibrate", str(data), "--out", str(out), "--jobs", "1"]) == 0
    cal = read_calibration(out / "calibration.yaml")
    truth = np.array(yaml.safe_load((data / "ground_truth.yaml").read_text())["T_cam_lidar"])
    xi = gtsam.Pose3(cal.T_cam_lidar).localCoordinates(gtsam.Pose3(truth))
    nees = float(xi @ np.linalg.solve(cal.covariance, xi))
    used = sum(f.used for f in cal.frames)
    assert used >= 6, capsys.readouterr().out
    assert nees < CHI2_6_9997, (nees, xi)


def test_pcd_style_with_csv_output_is_a_usage_error(tmp_path: Path, capsys) -> None:
    argv = ["simulate", str(tmp_path / "x"), "--format", "velodyne-csv", "--pcd-style", "matlab"]
    assert main(argv) == 2
    assert "--pcd-style matlab needs PCD files" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
