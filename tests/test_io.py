"""File I/O: scans (PCD/PLY/CSV/BIN), LZF, images, frames, YAML, calibration, ground truth."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sensor_examples import lidar_errors_example

from ilcc_graph.errors import InputError
from ilcc_graph.io import (
    FramePaths,
    atomic_write,
    list_frames,
    lzf_compress,
    lzf_decompress,
    read_calibration,
    read_ground_truth,
    read_image,
    read_scan,
    read_yaml,
    write_calibration,
    write_ground_truth,
    write_image,
    write_pcd,
    write_ply,
    write_yaml,
)
from ilcc_graph.io.lzf import LzfError
from ilcc_graph.types import BoardFit, Calibration, FrameResult, ImageCorners, Scan

HYP = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


# --------------------------------------------------------------------------- helpers
def _scan(n: int, seed: int, ring: bool = True) -> Scan:
    rng = np.random.default_rng(seed)
    pts = rng.normal(0, 20, (n, 3)).astype(np.float32).astype(np.float64)
    inten = rng.integers(0, 256, n).astype(np.float64)
    r = rng.integers(0, 64, n).astype(np.int32) if ring else None
    return Scan(pts, inten, r, "mem")


def _assert_same(a: Scan, b: Scan) -> None:
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.intensity, b.intensity)
    if b.ring is None:
        assert a.ring is None
    else:
        assert a.ring is not None and a.ring.dtype == np.int32
        np.testing.assert_array_equal(a.ring, b.ring)


scans = st.builds(_scan, n=st.integers(1, 60), seed=st.integers(0, 2**31 - 1), ring=st.booleans())


def _pcd_header(fields, sizes, types, counts, n, data, width=None, points=None) -> bytes:
    return (
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS {' '.join(fields)}\nSIZE {' '.join(map(str, sizes))}\n"
        f"TYPE {' '.join(types)}\nCOUNT {' '.join(map(str, counts))}\nWIDTH {n if width is None else width}\n"
        f"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n if points is None else points}\nDATA {data}\n"
    ).encode()


# --------------------------------------------------------------------------- round trips
@HYP
@given(scan=scans, mode=st.sampled_from(["binary", "ascii", "binary_compressed"]))
def test_pcd_round_trip(tmp_path: Path, scan: Scan, mode: str) -> None:
    p = tmp_path / f"s_{mode}.pcd"
    write_pcd(p, scan, data=mode)
    got = read_scan(p)
    _assert_same(got, scan)
    assert got.source == str(p)


@HYP
@given(scan=scans, colour=st.booleans())
def test_ply_round_trip(tmp_path: Path, scan: Scan, colour: bool) -> None:
    rgb = (
        np.random.default_rng(len(scan)).integers(0, 256, (len(scan), 3)).astype(np.uint8) if colour else None
    )
    p = tmp_path / "s.ply"
    write_ply(p, scan, rgb=rgb)
    _assert_same(read_scan(p), scan)


@HYP
@given(scan=scans, order=st.permutations(["x", "y", "z", "intensity", "laser_id", "azimuth"]))
def test_csv_round_trip_any_column_order(tmp_path: Path, scan: Scan, order: list[str]) -> None:
    cols = {
        "x": scan.points[:, 0],
        "y": scan.points[:, 1],
        "z": scan.points[:, 2],
        "intensity": scan.intensity,
        "laser_id": scan.ring if scan.ring is not None else np.zeros(len(scan)),
        "azimuth": np.arange(len(scan)),
    }
    lines = [",".join(order)] + [",".join(repr(float(cols[c][i])) for c in order) for i in range(len(scan))]
    p = tmp_path / "s.csv"
    p.write_text("\n".join(lines) + "\n")
    got = read_scan(p)
    expect = (
        scan if scan.ring is not None else Scan(scan.points, scan.intensity, np.zeros(len(scan), np.int32))
    )
    _assert_same(got, expect)


@HYP
@given(scan=scans)
def test_kitti_bin_round_trip(tmp_path: Path, scan: Scan) -> None:
    p = tmp_path / "s.bin"
    np.column_stack([scan.points, scan.intensity]).astype("<f4").tofile(p)
    _assert_same(read_scan(p), Scan(scan.points, scan.intensity, None))


def test_csv_without_header_uses_intensity_column(tmp_path: Path) -> None:
    scan = _scan(20, 3, ring=False)
    table = np.column_stack([scan.points, np.full(len(scan), 7.0), scan.intensity])
    p = tmp_path / "h.csv"
    np.savetxt(p, table, delimiter=",", fmt="%.17g")
    _assert_same(read_scan(p, intensity_column=4), scan)
    with pytest.raises(InputError, match=r"h\.csv.*intensity_column"):
        read_scan(p)
    q = tmp_path / "four.csv"
    np.savetxt(q, np.column_stack([scan.points, scan.intensity]), delimiter=",", fmt="%.17g")
    _assert_same(read_scan(q), scan)


def test_csv_header_without_intensity_name_uses_column(tmp_path: Path) -> None:
    """The configured column when the header names none; without one the scan has no intensity
    (its boards are then placed by their shape), as a three-column file without a header."""
    p = tmp_path / "named.csv"
    p.write_text("x,y,z,a,b\n1,2,3,40,50\n")
    s = read_scan(p, intensity_column=4)
    np.testing.assert_array_equal(s.intensity, [50])
    assert s.has_intensity
    s = read_scan(p)
    assert not s.has_intensity and s.ring is None
    np.testing.assert_array_equal(s.intensity, [0])
    q = tmp_path / "xyz.csv"
    q.write_text("1 2 3\n4 5 6\n")
    s = read_scan(q)
    np.testing.assert_array_equal(s.points, [[1, 2, 3], [4, 5, 6]])
    assert not s.has_intensity
    r = tmp_path / "ring.csv"  # a ring column, no intensity
    r.write_text("x,y,z,ring\n1,2,3,7\n4,5,6,9\n")
    s = read_scan(r)
    assert not s.has_intensity
    np.testing.assert_array_equal(s.ring, [7, 9])


def test_veloview_csv_header_names(tmp_path: Path) -> None:
    p = tmp_path / "0001.csv"
    p.write_text('"Points:0","Points:1","Points:2","intensity","laser_id"\n1,2,3,40,5\n4,5,6,50,6\n')
    s = read_scan(p)
    np.testing.assert_array_equal(s.points, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(s.ring, [5, 6])


def test_pcd_any_field_order_types_and_padding(tmp_path: Path) -> None:
    """Fields in another order, F8/U1/I2 types, a COUNT 3 padding field '_'."""
    n = 7
    rng = np.random.default_rng(5)
    dt = np.dtype(
        [("intensity", "<u1"), ("_", "<f4", (3,)), ("z", "<f8"), ("ring", "<i2"), ("x", "<f8"), ("y", "<f8")]
    )
    rec = np.zeros(n, dt)
    rec["intensity"] = rng.integers(0, 255, n)
    rec["x"], rec["y"], rec["z"] = rng.normal(size=(3, n))
    rec["ring"] = rng.integers(0, 32, n)
    hdr = _pcd_header(
        ["intensity", "_", "z", "ring", "x", "y"],
        [1, 4, 8, 2, 8, 8],
        list("UFFIFF"),
        [1, 3, 1, 1, 1, 1],
        n,
        "binary",
    )
    p = tmp_path / "odd.pcd"
    p.write_bytes(hdr + rec.tobytes())
    s = read_scan(p)
    np.testing.assert_array_equal(s.points, np.column_stack([rec["x"], rec["y"], rec["z"]]))
    np.testing.assert_array_equal(s.intensity, rec["intensity"])
    np.testing.assert_array_equal(s.ring, rec["ring"])
    # the same content as ascii
    rows = [
        f"{r['intensity']} 0 0 0 {float(r['z'])!r} {r['ring']} {float(r['x'])!r} {float(r['y'])!r}"
        for r in rec
    ]
    hdr_a = hdr.replace(b"DATA binary", b"DATA ascii")
    pa = tmp_path / "odd_ascii.pcd"
    pa.write_bytes(hdr_a + ("\n".join(rows) + "\n").encode())
    _assert_same(read_scan(pa), s)
    # cut in the middle of a row: said in our words (not numpy's advice to its caller)
    cut = tmp_path / "cut_ascii.pcd"
    cut.write_bytes(hdr_a + ("\n".join(rows[:-1]) + "\n" + rows[-1][:5]).encode())
    with pytest.raises(InputError, match=r"cut_ascii\.pcd: bad ascii PCD data \(.*a truncated") as e:
        read_scan(cut)
    assert "usecols" not in str(e.value)


def test_open3d_interoperates_with_binary_compressed(tmp_path: Path) -> None:
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(11)
    pts = rng.normal(size=(500, 3)).astype(np.float32)
    pts[:250] = np.round(pts[:250], 1)  # something for LZF to compress
    inten = rng.uniform(0, 100, (500, 1)).astype(np.float32)
    pc = o3d.t.geometry.PointCloud()
    pc.point.positions = o3d.core.Tensor(pts)
    pc.point.intensity = o3d.core.Tensor(inten)
    theirs = tmp_path / "o3d.pcd"
    assert o3d.t.io.write_point_cloud(str(theirs), pc, write_ascii=False, compressed=True)
    assert b"binary_compressed" in theirs.read_bytes()[:400]
    s = read_scan(theirs)
    np.testing.assert_array_equal(s.points, pts)
    np.testing.assert_array_equal(s.intensity, inten[:, 0])
    ours = tmp_path / "ours.pcd"
    write_pcd(ours, s, data="binary_compressed")
    back = o3d.t.io.read_point_cloud(str(ours))
    np.testing.assert_array_equal(back.point.positions.numpy(), pts)
    np.testing.assert_array_equal(back.point.intensity.numpy()[:, 0], inten[:, 0])


@HYP
@given(
    data=st.one_of(
        st.binary(max_size=3000),
        st.lists(st.sampled_from([b"ab", b"abc", b"\x00\x00\x00\x00", b"xyzw" * 40]), max_size=200).map(
            b"".join
        ),
    )
)
def test_lzf_round_trip(data: bytes) -> None:
    comp = lzf_compress(data)
    assert lzf_decompress(comp, len(data)) == data
    if len(data) > 100 and len(set(data)) <= 4:
        assert len(comp) < len(data)


def test_lzf_known_stream() -> None:
    # literal "ab" (ctrl 1), then a back reference of length 6 at distance 2 (ctrl (4<<5)|0, lo 1)
    assert lzf_decompress(bytes([1, ord("a"), ord("b"), 4 << 5, 1]), 8) == b"abababab"
    with pytest.raises(LzfError):
        lzf_decompress(bytes([1, ord("a"), ord("b"), 4 << 5, 5]), 8)  # reaches before the start


# --------------------------------------------------------------------------- bad files
def _bad_files(d: Path) -> list[tuple[Path, str]]:
    good = _scan(10, 1)
    write_pcd(d / "good.pcd", good)
    raw = (d / "good.pcd").read_bytes()
    cases = []

    def add(name: str, content: bytes, words: str) -> None:
        (d / name).write_bytes(content)
        cases.append((d / name, words))

    add("truncated.pcd", raw[:-7], "truncated")
    add("count.pcd", raw.replace(b"POINTS 10", b"POINTS 12"), "WIDTH")
    add(
        "rows.pcd",
        _pcd_header(["x", "y", "z", "intensity"], [4] * 4, "FFFF", [1] * 4, 3, "ascii")
        + b"1 2 3 4\n5 6 7 8\n",
        "POINTS 3",
    )
    add(
        "cols.pcd",
        _pcd_header(["x", "y", "z", "intensity"], [4] * 4, "FFFF", [1] * 4, 2, "ascii") + b"1 2 3 4\n5 6 7\n",
        "ascii PCD",
    )
    add(
        "nox.pcd",
        _pcd_header(["y", "z", "rgb", "intensity"], [4] * 4, "FFFF", [1] * 4, 1, "ascii") + b"1 2 3 4\n",
        "no 'x' field; fields present: ['y', 'z', 'rgb', 'intensity']",
    )
    add(
        "nan.pcd",
        _pcd_header(["x", "y", "z", "intensity"], [4] * 4, "FFFF", [1] * 4, 2, "ascii")
        + b"nan nan nan 1\nnan 0 0 1\n",
        "non-finite",
    )
    add(
        "zero.pcd",
        _pcd_header(["x", "y", "z", "intensity"], [4] * 4, "FFFF", [1] * 4, 0, "binary"),
        "no points",
    )
    add("empty.pcd", b"", "empty")
    add("garbage.pcd", b"\x89PNG\r\n\x1a\n" + bytes(200), "PCD")
    add(
        "type.pcd",
        _pcd_header(["x", "y", "z", "intensity"], [4, 4, 4, 3], "FFFF", [1] * 4, 1, "binary") + bytes(15),
        "unsupported TYPE",
    )
    add(
        "lzf.pcd",
        _pcd_header(["x", "y", "z", "intensity"], [4] * 4, "FFFF", [1] * 4, 2, "binary_compressed")
        + struct.pack("<II", 3, 32)
        + bytes([0xFF, 0xFF, 0xFF]),
        "corrupt",
    )
    add("short.bin", bytes(30), "multiple of 16")
    add(
        "bad.ply",
        b"ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
        b"property float z\nproperty float intensity\nend_header\n" + bytes(40),
        "truncated",
    )
    add(  # (x y z without intensity is a scan: its board is placed by its shape)
        "noz.ply",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
        b"property float intensity\nend_header\n1 2 3\n",
        "no 'z' field; fields present: ['x', 'y', 'intensity']",
    )
    add("noy.csv", b"x,z,azimuth,intensity\n1,2,3,4\n", "fields present")
    add("five.csv", b"1,2,3,4,5\n", "set lidar.intensity_column")
    add("text.csv", b"x,y,z,intensity\n1,2,3,four\n", "bad CSV")
    add("data.xyz", b"1 2 3\n", "no reader")
    return cases


def test_bad_scan_files_raise_input_error_naming_the_file(tmp_path: Path) -> None:
    for path, words in _bad_files(tmp_path):
        with pytest.raises(InputError) as e:
            read_scan(path)
        msg = str(e.value)
        assert path.name in msg, msg
        assert words in msg, (path.name, msg)
    with pytest.raises(InputError, match=r"missing\.pcd: file not found"):
        read_scan(tmp_path / "missing.pcd")


def test_non_finite_rows_are_dropped(tmp_path: Path) -> None:
    p = tmp_path / "some_nan.pcd"
    p.write_bytes(
        _pcd_header(["x", "y", "z", "intensity"], [4] * 4, "FFFF", [1] * 4, 3, "ascii")
        + b"1 2 3 4\nnan nan nan 0\n5 6 7 inf\n"
    )
    s = read_scan(p)
    np.testing.assert_array_equal(s.points, [[1, 2, 3]])
    np.testing.assert_array_equal(s.intensity, [4])


def test_recorded_scan(acfr_data: Path) -> None:
    s = read_scan(acfr_data / "pcd" / "pose01.pcd")
    assert len(s) == 23969
    assert s.points.dtype == np.float64 and s.ring is not None
    assert s.ring.min() == 0 and s.ring.max() == 15
    assert s.intensity.min() >= 0 and s.intensity.max() <= 255
    np.testing.assert_allclose(s.points[0], [1.373171, -2.6457233, -0.79871565], rtol=1e-6)


# --------------------------------------------------------------------------- images
def test_images(tmp_path: Path) -> None:
    import cv2

    rng = np.random.default_rng(2)
    bgr = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    write_image(tmp_path / "c.png", bgr)
    np.testing.assert_array_equal(read_image(tmp_path / "c.png"), bgr)
    gray = rng.integers(0, 256, (20, 30), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "g.png"), gray)
    np.testing.assert_array_equal(read_image(tmp_path / "g.png"), np.repeat(gray[:, :, None], 3, axis=2))
    g16 = gray.astype(np.uint16) * 257
    cv2.imwrite(str(tmp_path / "g16.png"), g16)
    np.testing.assert_array_equal(read_image(tmp_path / "g16.png")[:, :, 1], gray)
    for bits in (10, 12):  # a machine-vision camera's 10 or 12 bits in a 16-bit PNG fill 0..255 too
        g = np.round(gray / 255.0 * (2**bits - 1)).astype(np.uint16)
        g[0, 0] = 2**bits - 1  # saturated somewhere
        cv2.imwrite(str(tmp_path / f"g{bits}.png"), g)
        got = read_image(tmp_path / f"g{bits}.png")[:, :, 1].astype(int)
        want = gray.astype(int)
        want[0, 0] = 255
        assert np.abs(got - want).max() <= 1, bits
    bgra = np.dstack([bgr, np.full((20, 30), 9, np.uint8)])
    cv2.imwrite(str(tmp_path / "a.png"), bgra)
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), bgr)
    (tmp_path / "bad.jpg").write_bytes(b"\xff\xd8not really a jpeg")
    for name, words in (("bad.jpg", "cannot decode"), ("none.png", "not found")):
        with pytest.raises(InputError, match=words) as e:
            read_image(tmp_path / name)
        assert name in str(e.value)
    with pytest.raises(ValueError):
        write_image(tmp_path / "x.unknownext", bgr)
    assert not (tmp_path / "x.unknownext").exists()


# --------------------------------------------------------------------------- frames
def test_list_frames(tmp_path: Path) -> None:
    (tmp_path / "pcd").mkdir()
    (tmp_path / "img").mkdir()
    for stem in ("pose10", "pose2", "pose1", "lonely"):
        (tmp_path / "pcd" / f"{stem}.pcd").write_bytes(b"x")
    for stem in ("pose10", "pose2", "pose1", "orphan"):
        (tmp_path / "img" / f"{stem}.png").write_bytes(b"x")
    (tmp_path / "pcd" / "notes.txt").write_text("hi")
    frames, skipped = list_frames(tmp_path)
    assert [f.name for f in frames] == ["pose1", "pose2", "pose10"]
    assert frames[0] == FramePaths("pose1", tmp_path / "pcd" / "pose1.pcd", tmp_path / "img" / "pose1.png")
    reasons = dict(skipped)
    assert (
        "no image" in reasons["lonely"]
        and "no scan" in reasons["orphan"]
        and "unsupported" in reasons["notes"]
    )
    with pytest.raises(InputError, match="no 'img' folder"):
        (tmp_path / "other" / "pcd").mkdir(parents=True)
        list_frames(tmp_path / "other")
    (tmp_path / "other" / "img").mkdir()
    with pytest.raises(InputError, match="no frame"):
        list_frames(tmp_path / "other")


def test_list_frames_recorded(acfr_data: Path) -> None:
    frames, skipped = list_frames(acfr_data)
    assert len(frames) == 20 and not skipped
    assert frames[0].name == "pose01"


# --------------------------------------------------------------------------- YAML
def test_yaml_round_trip_and_layout(tmp_path: Path) -> None:
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 1e-7]
    obj = {
        "T": T,
        "s": np.float32(0.5),
        "n": np.int64(3),
        "v": (1, 2),
        "nan": float("nan"),
        "flag": np.bool_(True),
    }
    p = write_yaml(tmp_path / "a.yaml", obj)
    text = p.read_text()
    assert "- [1.0, 0.0, 0.0, 0.1]" in text  # matrix rows on one line each
    back = read_yaml(p)
    np.testing.assert_array_equal(np.array(back["T"]), T)
    assert (
        back["s"] == 0.5 and back["n"] == 3 and back["v"] == [1, 2] and np.isnan(back["nan"]) and back["flag"]
    )
    (tmp_path / "bad.yaml").write_text("a: [1, 2\n")
    with pytest.raises(InputError, match=r"bad\.yaml: not valid YAML"):
        read_yaml(tmp_path / "bad.yaml")
    # the two slips of an editor that a parser's words do not name: a tab, a file not in UTF-8
    (tmp_path / "tab.yaml").write_text("board:\n\tsquares: [6, 8]\n")
    with pytest.raises(InputError, match=r"tab\.yaml: not valid YAML .*line 2 holds a tab"):
        read_yaml(tmp_path / "tab.yaml")
    (tmp_path / "latin1.yaml").write_bytes("# board\n# caf\u00e9\na: 1\n".encode("latin-1"))
    with pytest.raises(InputError, match=r"latin1\.yaml: cannot read file: line 2 is not UTF-8 .*as UTF-8"):
        read_yaml(tmp_path / "latin1.yaml")


def test_yaml_write_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    p = tmp_path / "keep.yaml"
    write_yaml(p, {"a": 1})
    before = p.read_bytes()
    with pytest.raises(TypeError):
        write_yaml(p, {"a": object()})  # fails while serialising: file untouched
    assert p.read_bytes() == before

    def boom(src, dst):  # fails after the temporary file is written
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        write_yaml(p, {"a": 2, "b": list(range(1000))})
    with pytest.raises(OSError):
        atomic_write(tmp_path / "new.bin", b"123")
    monkeypatch.undo()
    assert p.read_bytes() == before
    assert sorted(f.name for f in tmp_path.iterdir()) == ["keep.yaml"]  # no partial or temporary file


# --------------------------------------------------------------------------- results
def _calibration() -> Calibration:
    rng = np.random.default_rng(4)
    T = np.eye(4)
    T[:3, :3] = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], float)
    T[:3, 3] = [0.05, -0.1, 0.2]
    A = rng.normal(size=(6, 6)) * 1e-3
    cov = A @ A.T
    Tb = np.eye(4)
    Tb[:3, 3] = [3.0, 0.5, 0.1]
    board = BoardFit(Tb, np.eye(6), rng.normal(size=(35, 3)), np.zeros((5, 3)), np.zeros(5), True)
    corners = ImageCorners(rng.uniform(0, 1000, (35, 2)), np.zeros((35, 3)), np.zeros((35, 2, 2)), False)
    frames = (
        FrameResult("0001", True, None, board, corners, 0.42),
        FrameResult("0002", False, "no board found in the scan"),
    )
    return Calibration(T, cov, frames, method="graph", diagnostics={"iterations": 7.0})


def test_calibration_round_trip(tmp_path: Path) -> None:
    cal = _calibration()
    p = write_calibration(tmp_path / "calibration.yaml", cal)
    d = yaml.safe_load(p.read_text())
    assert list(d)[:4] == ["T_cam_lidar", "covariance", "sigma", "frames"]
    assert list(d["frames"][0])[:6] == [
        "name",
        "used",
        "lidar_corners",
        "image_corners",
        "rms_bearing_error_mrad",
        "T_lidar_board",
    ]
    assert d["frames"][1] == {
        "name": "0002",
        "used": False,
        "reason": "no board found in the scan",
        "rms_bearing_error_mrad": None,
    }
    sd = np.sqrt(np.diag(cal.covariance))
    assert d["sigma"]["rx_deg"] == pytest.approx(np.degrees(sd[0]))
    assert d["sigma"]["tz_mm"] == pytest.approx(1000 * sd[5])
    back = read_calibration(p)
    np.testing.assert_array_equal(back.T_cam_lidar, cal.T_cam_lidar)
    np.testing.assert_array_equal(back.covariance, cal.covariance)
    assert back.method == "graph" and back.diagnostics == {"iterations": 7.0}
    f0, f1 = back.frames
    assert (f0.name, f0.used, f0.reason, f0.rms_bearing_error_mrad) == ("0001", True, None, 0.42)
    np.testing.assert_array_equal(f0.board.corners_lidar, cal.frames[0].board.corners_lidar)
    np.testing.assert_array_equal(f0.board.T_lidar_board, cal.frames[0].board.T_lidar_board)
    np.testing.assert_array_equal(f0.corners.uv, cal.frames[0].corners.uv)
    assert (f1.used, f1.reason, f1.board, f1.corners) == (False, "no board found in the scan", None, None)


def _with_lidar_errors() -> Calibration:
    """_calibration() with the LiDAR's errors estimated and the first board refined by the core."""
    import dataclasses

    cal = _calibration()
    T_ref = cal.frames[0].board.T_lidar_board.copy()
    T_ref[:3, 3] += [0.002, -0.001, 0.003]
    f0 = dataclasses.replace(cal.frames[0], T_lidar_board_refined=T_ref)
    sensors = {
        "lidar_errors": lidar_errors_example(),
        "camera_intrinsics": {
            "names": ["fx", "fy"], "stated": np.array([900.0, 901.0]),
            "values": np.array([903.0, 899.5]), "sigmas": np.array([1.5, 1.4]),
        },
        "effects": {"lidar_errors": {"rotation_deg": 0.01, "translation_mm": 1.2, "mahalanobis": 2.5}},
    }  # fmt: skip
    return dataclasses.replace(cal, frames=(f0, cal.frames[1]), sensors=sensors)


def test_sensor_errors_round_trip_and_refined_corners(tmp_path: Path) -> None:
    cal = _with_lidar_errors()
    p = write_calibration(tmp_path / "calibration.yaml", cal)
    d = yaml.safe_load(p.read_text())
    terms = d["sensor_errors"]["lidar"]["terms"]
    assert terms["dark"] == {"value_mm": pytest.approx(12.3), "sigma_mm": pytest.approx(0.2)}
    assert terms["offset[3]"]["elevation_deg"] == -9.0
    assert d["sensor_errors"]["effect_on_extrinsic"]["lidar_errors"]["translation_mm"] == 1.2
    # the reported corners are the refined board's, the stage's kept beside them
    f = cal.frames[0]
    np.testing.assert_allclose(
        d["frames"][0]["lidar_corners"], f.board.corners_lidar + [0.002, -0.001, 0.003]
    )
    np.testing.assert_allclose(d["frames"][0]["lidar_corners_stage"], f.board.corners_lidar)
    back = read_calibration(p)
    np.testing.assert_array_equal(back.frames[0].board.corners_lidar, f.board.corners_lidar)
    for k in ("values", "sigmas"):
        np.testing.assert_allclose(back.sensors["lidar_errors"][k], cal.sensors["lidar_errors"][k])
        np.testing.assert_allclose(back.sensors["camera_intrinsics"][k], cal.sensors["camera_intrinsics"][k])
    assert back.sensors["lidar_errors"]["names"] == cal.sensors["lidar_errors"]["names"]
    assert back.sensors["lidar_errors"]["left_out"] == cal.sensors["lidar_errors"]["left_out"]
    assert back.sensors["effects"] == cal.sensors["effects"]
    assert d["sensor_errors"]["lidar"]["board_plane"]["beam_mm"] == pytest.approx(2.4)
    bp_in, bp_back = cal.sensors["lidar_errors"]["board_plane"], back.sensors["lidar_errors"]["board_plane"]
    assert bp_back == {k: pytest.approx(v) if isinstance(v, float) else v for k, v in bp_in.items()}
    again = yaml.safe_load(write_calibration(tmp_path / "again.yaml", back).read_text())
    assert again["frames"] == d["frames"]  # written again: the same corners, not moved twice
    # without the LiDAR's terms the stage's corners are reported, as before
    plain = write_calibration(tmp_path / "plain.yaml", _calibration())
    assert "lidar_corners_stage" not in yaml.safe_load(plain.read_text())["frames"][0]


def test_read_calibration_rejects_bad_content(tmp_path: Path) -> None:
    p = write_calibration(tmp_path / "c.yaml", _calibration())
    d = yaml.safe_load(p.read_text())
    d["T_cam_lidar"][0][0] = 2.0
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(d))
    with pytest.raises(InputError, match=r"bad\.yaml: T_cam_lidar is not a rigid transform"):
        read_calibration(tmp_path / "bad.yaml")
    del d["covariance"]
    (tmp_path / "bad2.yaml").write_text(yaml.safe_dump(d))
    with pytest.raises(InputError, match=r"bad2\.yaml: missing key 'covariance'"):
        read_calibration(tmp_path / "bad2.yaml")


def test_ground_truth_round_trip(tmp_path: Path) -> None:
    T = _calibration().T_cam_lidar
    boards = {"0001": np.eye(4), "0002": _calibration().frames[0].board.T_lidar_board}
    write_ground_truth(tmp_path, T, boards, {"noise": {"range_sigma_m": 0.02}, "seed": 3})
    text = (tmp_path / "ground_truth.yaml").read_text()
    assert text.index("T_cam_lidar") < text.index("T_lidar_board") < text.index("noise")
    gt = read_ground_truth(tmp_path)
    np.testing.assert_array_equal(gt.T_cam_lidar, T)
    assert set(gt.T_lidar_board) == {"0001", "0002"}
    np.testing.assert_array_equal(gt.T_lidar_board["0002"], boards["0002"])
    assert gt.extra == {"noise": {"range_sigma_m": 0.02}, "seed": 3}
    with pytest.raises(InputError, match="not found"):
        read_ground_truth(tmp_path / "elsewhere")


def test_list_frames_one_sensor_only(tmp_path: Path) -> None:
    (tmp_path / "pcd").mkdir()
    for stem in ("0002", "0001"):
        (tmp_path / "pcd" / f"{stem}.bin").write_bytes(bytes(16))
    with pytest.raises(InputError, match="no 'img' folder"):
        list_frames(tmp_path)
    frames, skipped = list_frames(tmp_path, require_image=False)
    assert [(f.name, f.scan.name, f.image) for f in frames] == [
        ("0001", "0001.bin", None),
        ("0002", "0002.bin", None),
    ]
    assert skipped == []
    (tmp_path / "img").mkdir()
    (tmp_path / "img" / "0003.jpg").write_bytes(b"x")
    frames, skipped = list_frames(tmp_path, require_scan=False)
    assert [(f.name, f.scan, f.image.name) for f in frames] == [("0003", None, "0003.jpg")]
    assert [s for s, _ in skipped] == ["0001", "0002"]


def test_ply_ascii_and_big_endian(tmp_path: Path) -> None:
    p = tmp_path / "a.ply"
    p.write_text(
        "ply\nformat ascii 1.0\ncomment by hand\nelement vertex 2\nproperty uchar ring\nproperty double z\n"
        "property float scalar_Intensity\nproperty float x\nproperty float y\nelement face 1\n"
        "property list uchar int vertex_indices\nend_header\n3 1.5 20 0.25 -2\n4 -1 30 1 2\n3 0 1 1\n"
    )
    s = read_scan(p)
    np.testing.assert_array_equal(s.points, [[0.25, -2, 1.5], [1, 2, -1]])
    np.testing.assert_array_equal(s.intensity, [20, 30])
    np.testing.assert_array_equal(s.ring, [3, 4])
    rec = np.array(
        [(1.0, 2.0, 3.0, 9.0)], dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("intensity", ">f8")]
    )
    q = tmp_path / "b.ply"
    q.write_bytes(
        b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
        b"property float z\nproperty double intensity\nend_header\n" + rec.tobytes()
    )
    s = read_scan(q)
    np.testing.assert_array_equal(s.points, [[1, 2, 3]])
    assert s.intensity[0] == 9.0 and s.ring is None
