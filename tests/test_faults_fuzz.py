"""Fuzzing the readers: random bytes and mutated files never give anything but a result or our error.

Every point-cloud reader (``io.read_scan`` by suffix, the ROS PointCloud2 decoder of
``datasets.rosbag``), the image reader and the config loader, fed with random bytes, headers with
tokens swapped or numbers changed, and truncated or bit-flipped files, must return a result or raise
``InputError`` (the file and the problem): never a ``ValueError``, ``IndexError``, ``MemoryError``
or anything else a user would meet as a traceback.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ilcc_graph.config import load_config, parse_config
from ilcc_graph.datasets.rosbag import decode_cloud
from ilcc_graph.errors import InputError
from ilcc_graph.io import read_image, read_scan, write_pcd, write_ply
from ilcc_graph.io.scans import write_csv
from ilcc_graph.types import Scan

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
_FILES = ("binary.pcd", "ascii.pcd", "compressed.pcd", "cloud.ply", "cloud.csv", "cloud.bin", "ascii.ply")


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One folder for the module's files (hypothesis and function-scoped ``tmp_path`` do not mix)."""
    return tmp_path_factory.mktemp("fuzz")


def _scan(n: int = 40, ring: bool = True) -> Scan:
    rng = np.random.default_rng(0)
    return Scan(
        rng.normal(size=(n, 3)) + [3.0, 0.0, 0.0],
        rng.uniform(0, 100, n),
        rng.integers(0, 32, n).astype(np.int32) if ring else None,
    )


@pytest.fixture(scope="module")
def seeds(fuzz_dir: Path) -> dict[str, bytes]:
    """One small valid file per format and layout (the seeds of the mutations), by name."""
    out = {}
    for name, write in (
        ("binary.pcd", lambda p: write_pcd(p, _scan(), data="binary")),
        ("ascii.pcd", lambda p: write_pcd(p, _scan(), data="ascii")),
        ("compressed.pcd", lambda p: write_pcd(p, _scan(), data="binary_compressed")),
        ("cloud.ply", lambda p: write_ply(p, _scan())),
        ("cloud.csv", lambda p: write_csv(p, _scan())),
        (
            "cloud.bin",
            lambda p: p.write_bytes(np.c_[_scan().points, _scan().intensity].astype("<f4").tobytes()),
        ),
    ):
        path = fuzz_dir / f"seed-{name}"
        write(path)
        out[name] = path.read_bytes()
    out["ascii.ply"] = (
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        b"property float intensity\nend_header\n1 2 3 4\n2 3 4 5\n3 4 5 6\n"
    )
    assert sorted(out) == sorted(_FILES)
    return out


def _read(folder: Path, name: str, data: bytes) -> None:
    path = folder / name
    path.write_bytes(data)
    try:
        scan = read_scan(path)
    except InputError as err:
        assert path.name in str(err)  # the message names the file
        return
    assert scan.points.ndim == 2 and scan.points.shape[1] == 3
    assert len(scan.intensity) == len(scan.points) and np.isfinite(scan.points).all()


@pytest.mark.parametrize("suffix", [".pcd", ".ply", ".csv", ".bin"])
@FUZZ
@given(data=st.binary(max_size=600))
def test_random_bytes_into_every_scan_reader(fuzz_dir: Path, suffix: str, data: bytes) -> None:
    _read(fuzz_dir, f"random{suffix}", data)


@pytest.mark.parametrize("seed", sorted(_FILES))
@FUZZ
@given(
    cut=st.integers(0, 10**6),
    flips=st.lists(st.tuples(st.integers(0, 10**6), st.integers(1, 255)), max_size=6),
)
def test_truncated_and_bit_flipped_files(
    fuzz_dir: Path, seeds: dict[str, bytes], seed: str, cut: int, flips: list[tuple[int, int]]
) -> None:
    data = bytearray(seeds[seed])
    for pos, mask in flips:
        data[pos % len(data)] ^= mask
    _read(fuzz_dir, seed, bytes(data[: cut % (len(data) + 1)]))


_TOKENS = [b"x", b"y", b"z", b"intensity", b"ring", b"F", b"U", b"I", b"4", b"8", b"0", b"-1", b"1e9",
           b"binary", b"ascii", b"binary_compressed", b"float", b"uchar", b"vertex", b"face", b"list",
           b"99999999999", b"nan", b"", b"DATA", b"POINTS", b"WIDTH", b"end_header"]  # fmt: skip


@pytest.mark.parametrize("seed", ["binary.pcd", "ascii.pcd", "compressed.pcd", "cloud.ply", "ascii.ply"])
@FUZZ
@given(edits=st.lists(st.tuples(st.integers(0, 200), st.sampled_from(_TOKENS)), min_size=1, max_size=4))
def test_mutated_headers(
    fuzz_dir: Path, seeds: dict[str, bytes], seed: str, edits: list[tuple[int, bytes]]
) -> None:
    raw = seeds[seed]
    end = raw.find(b"DATA") if seed.endswith(".pcd") else raw.find(b"end_header")
    head_end = raw.find(b"\n", end) + 1
    tokens = raw[:head_end].split(b" ")
    for pos, tok in edits:
        tokens[pos % len(tokens)] = tok
    _read(fuzz_dir, seed, b" ".join(tokens) + raw[head_end:])


_PF = {"x": 7, "y": 7, "z": 7, "intensity": 7, "ring": 4}


@FUZZ
@given(
    names=st.lists(st.sampled_from(["x", "y", "z", "intensity", "ring", "t", ""]), max_size=6),
    types=st.lists(st.integers(0, 10), min_size=6, max_size=6),
    offsets=st.lists(st.integers(0, 40), min_size=6, max_size=6),
    step=st.integers(0, 40),
    width=st.integers(0, 20),
    height=st.integers(0, 3),
    row_step=st.integers(0, 800),
    data=st.binary(max_size=800),
    big=st.booleans(),
)
def test_random_pointcloud2_messages(names, types, offsets, step, width, height, row_step, data, big) -> None:  # noqa: ANN001
    fields = [
        SimpleNamespace(name=n, datatype=t, offset=o, count=1) for n, t, o in zip(names, types, offsets)
    ]
    msg = SimpleNamespace(
        fields=fields,
        point_step=step,
        width=width,
        height=height,
        row_step=row_step,
        data=np.frombuffer(data, np.uint8),  # what the bag readers give
        is_bigendian=big,
    )
    try:
        scan = decode_cloud(msg, "bag.db3 /points #0")
    except InputError as err:
        assert "bag.db3" in str(err)
        return
    assert scan.points.shape[1] == 3 and np.isfinite(scan.points).all()


@FUZZ
@given(data=st.binary(max_size=400))
def test_random_bytes_into_the_image_reader(fuzz_dir: Path, data: bytes) -> None:
    path = fuzz_dir / "random.png"
    path.write_bytes(data)
    try:
        img = read_image(path)
    except InputError as err:
        assert "random.png" in str(err)
        return
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3


_K = [[500, 0, 320], [0, 500, 240], [0, 0, 1]]
_VALID = {
    "board": {"squares": [6, 8], "square_size": 0.075, "margin": 0.0, "lower_left": "black"},
    "lidar": {"model": "hdl32"},
    "camera": {"model": "pinhole", "width": 640, "height": 480, "K": _K, "dist": [0, 0, 0, 0, 0]},
}
_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(10**12), 10**12)
    | st.floats(allow_nan=True)
    | st.text(max_size=8),
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=6), kids, max_size=3),
    max_leaves=8,
)


@FUZZ
@given(section=st.sampled_from(sorted(_VALID)), key=st.text(max_size=12) | st.sampled_from(
    ["squares", "square_size", "margin", "lower_left", "model", "width", "height", "K", "dist", "roi",
     "vertical_angles_deg", "calibration_file", "intensity_column", "xi", "alpha", "intrinsics_sigma"]),
    value=_VALUES)  # fmt: skip
def test_config_with_one_random_value(fuzz_dir: Path, section: str, key: str, value: object) -> None:
    d = yaml.safe_load(yaml.safe_dump(_VALID))
    d[section][key] = value
    try:
        cfg = parse_config(d, source="config.yaml", base_dir=fuzz_dir)
    except InputError as err:
        assert "config.yaml" in str(err)
        return
    assert cfg.camera.width > 0 and cfg.board.square_size > 0


@FUZZ
@given(data=st.binary(max_size=300) | st.text(max_size=300).map(str.encode))
def test_random_bytes_into_the_config_loader(fuzz_dir: Path, data: bytes) -> None:
    path = fuzz_dir / "config.yaml"
    path.write_bytes(data)
    try:
        load_config(path)
    except InputError as err:
        assert "config.yaml" in str(err)
