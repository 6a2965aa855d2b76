"""Issue 36: the files a user names, tried as a careless or hostile user would, through the command
line: a key written twice (config.yaml, rig.yaml, a camera file), a path that exists but is no file
(a folder, a FIFO, /dev/zero), YAML alias bombs, a huge camera file, a huge value quoted in a
message. Each is one line naming the file and the problem, exit 2, quickly and in little memory."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.io.scans import read_scan, write_csv
from ilcc_graph.types import Scan

OST = """image_width: 640
image_height: 400
camera_name: cam
camera_matrix: {rows: 3, cols: 3, data: [320.0, 0.0, 319.5, 0.0, 320.0, 199.5, 0.0, 0.0, 1.0]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [-0.05, 0.01, 0.0, 0.0, 0.0]}
"""


@pytest.fixture(scope="module")
def pair(simulated) -> Path:  # noqa: ANN001 - conftest's factory
    """A small simulated pinhole pair (5 frames, 640 px), the session's ``simulated`` set."""
    return simulated("pinhole", frames=5, seed=3)


def _data(pair: Path, dst: Path, config: str, files: dict[str, str] | None = None) -> Path:
    """The simulated set's scans and images under ``dst`` with ``config`` as its config.yaml."""
    shutil.copytree(pair / "pcd", dst / "pcd")
    shutil.copytree(pair / "img", dst / "img")
    (dst / "config.yaml").write_text(config)
    for name, text in (files or {}).items():
        (dst / name).write_text(text)
    return dst


def _without_camera(pair: Path) -> str:
    return (pair / "config.yaml").read_text().split("camera:")[0]


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run the command; it must end with exit 2 and one line on stderr, which is returned."""
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2, err[:500]
    assert len(err.splitlines()) == 1 and len(err) < 400, err[:500]
    return err


def test_a_section_pasted_twice_into_config_yaml_is_refused(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A second camera section pasted into config.yaml (before: it silently replaced the first, and the
    run ended POOR): refused naming the key and both lines."""
    text = (pair / "config.yaml").read_text()
    n = len(text.splitlines())
    second = "camera:\n  model: pinhole\n  width: 640\n  height: 400\n"
    second += "  K: [[300, 0, 320], [0, 300, 200], [0, 0, 1]]\n"
    d = _data(pair, tmp_path / "config", text + second)
    err = _refused(["calibrate", str(d), "--out", str(tmp_path / "o1"), "--jobs", "1"], capsys)
    assert "config.yaml" in err and "'camera' appears twice" in err and f"lines 8 and {n + 1}" in err


def test_a_key_twice_in_a_camera_file_is_refused(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    d = _data(pair, tmp_path / "camfile", _without_camera(pair) + "camera: {file: ost.yaml}\n",
              {"ost.yaml": OST + "image_width: 1280\n"})  # fmt: skip
    err = _refused(["calibrate", str(d), "--out", str(tmp_path / "o2"), "--jobs", "1"], capsys)
    assert "ost.yaml" in err and "'image_width' appears twice" in err and "lines 1 and 7" in err


def test_a_sensor_named_twice_in_rig_yaml_is_refused(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before: the second ``cam`` silently replaced the first."""
    rig = tmp_path / "rig"
    rig.mkdir()
    for s in ("lidar", "cam"):
        shutil.copytree(pair / ("pcd" if s == "lidar" else "img"), rig / s)
    doc = yaml.safe_load((pair / "config.yaml").read_text())
    camera = yaml.safe_dump(doc["camera"], default_flow_style=True).strip()
    other = "{model: pinhole, width: 640, height: 400, K: [[300, 0, 320], [0, 300, 200], [0, 0, 1]]}"
    sensors = (
        f"  lidar:\n    lidar: {{model: hdl32}}\n  cam:\n    camera: {camera}\n  cam:\n    camera: {other}\n"
    )
    board = yaml.safe_dump({"board": doc["board"]}, default_flow_style=None)
    (rig / "rig.yaml").write_text(f"reference: lidar\n{board}sensors:\n{sensors}")
    lines = (rig / "rig.yaml").read_text().splitlines()
    first, last = (i + 1 for i, line in enumerate(lines) if line == "  cam:")
    err = _refused(["calibrate", str(rig), "--out", str(tmp_path / "o3"), "--jobs", "1"], capsys)
    assert "rig.yaml" in err and "'cam' appears twice" in err and f"lines {first} and {last}" in err


@pytest.mark.parametrize("kind", ["folder", "fifo", "device"])
@pytest.mark.parametrize("which", ["camera", "lidar"])
def test_a_path_that_is_no_file_is_named_for_what_it_is(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], kind: str, which: str
) -> None:
    """A folder, a FIFO or /dev/zero named as the camera's or the LiDAR's calibration file (before: "not
    found"; a FIFO must not block the run)."""
    path = tmp_path / "calib.yaml"
    if kind == "folder":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    else:
        path = Path("/dev/zero")
    config = (pair / "config.yaml").read_text()
    if which == "camera":
        config = _without_camera(pair) + f"camera: {{file: {path}}}\n"
    else:
        config = config.replace("  model: hdl32\n", f"  calibration_file: {path}\n")
    d = _data(pair, tmp_path / "data", config)
    err = _refused(["calibrate", str(d), "--out", str(tmp_path / "o"), "--jobs", "1"], capsys)
    what = {"folder": "is a folder", "fifo": "is a FIFO (named pipe)", "device": "is a character device"}[
        kind
    ]
    assert f"{path} {what}" in err and "not found" not in err


def _bomb(levels: int, name: str = "a") -> str:
    """YAML anchors, each level 10 aliases of the one below: 10**levels values when expanded."""
    lines = [f"  {name}0: &{name}0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"  {name}{i}: &{name}{i} [{', '.join([f'*{name}{i - 1}'] * 10)}]" for i in range(1, levels)]
    return "\n".join(lines) + "\n"


def test_alias_bombs_and_huge_files_are_refused_at_once(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An alias bomb in a camera file (before: the message held all 10**6 values, megabytes) and in
    board.squares; a camera file of 2 MB (before: read whole, 60 MB of memory per MB); each refused
    with a short line."""
    cam = (
        "bomb:\n"
        + _bomb(6)
        + OST.replace("data: [320.0, 0.0, 319.5, 0.0, 320.0, 199.5, 0.0, 0.0, 1.0]", "data: *a5")
    )
    d = _data(pair, tmp_path / "cam", _without_camera(pair) + "camera: {file: ost.yaml}\n", {"ost.yaml": cam})
    err = _refused(["calibrate", str(d), "--out", str(tmp_path / "o1"), "--jobs", "1"], capsys)
    assert "ost.yaml" in err and "alias" in err

    config = (
        "x-anchors:\n"
        + _bomb(6)
        + (pair / "config.yaml").read_text().replace("squares: [6, 8]", "squares: *a5")
    )
    d = _data(pair, tmp_path / "squares", config)
    err = _refused(["calibrate", str(d), "--out", str(tmp_path / "o2"), "--jobs", "1"], capsys)
    assert "config.yaml" in err and "alias" in err

    big = OST + "notes: [" + ", ".join(["1.0"] * 420_000) + "]\n"
    d = _data(pair, tmp_path / "big", _without_camera(pair) + "camera: {file: ost.yaml}\n", {"ost.yaml": big})
    err = _refused(["calibrate", str(d), "--out", str(tmp_path / "o3"), "--jobs", "1"], capsys)
    assert "ost.yaml: camera file is larger than 1 MiB" in err


def test_a_huge_value_is_quoted_by_a_short_prefix(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A value within the alias bound but long (20,000 numbers in board.squares; 10**4 through aliases
    in a camera file's camera_matrix): the message quotes a short prefix (before: the whole value)."""
    squares = "[" + ", ".join(["6"] * 20_000) + "]"
    d = _data(pair, tmp_path / "sq", (pair / "config.yaml").read_text().replace("[6, 8]", squares))
    err = _refused(["calibrate", str(d), "--out", str(tmp_path / "o1"), "--jobs", "1"], capsys)
    assert "board.squares = [6, 6, 6" in err and "..." in err
    cam = (
        "bomb:\n"
        + _bomb(4)
        + OST.replace("data: [320.0, 0.0, 319.5, 0.0, 320.0, 199.5, 0.0, 0.0, 1.0]", "data: *a3")
    )
    d = _data(pair, tmp_path / "cam", _without_camera(pair) + "camera: {file: ost.yaml}\n", {"ost.yaml": cam})
    err = _refused(["calibrate", str(d), "--out", str(tmp_path / "o2"), "--jobs", "1"], capsys)
    assert "camera_matrix = [[[[" in err and "..." in err


def test_a_scan_with_impossible_coordinates_is_a_damaged_file(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A KITTI .bin written as float64 records (read as float32: points at 1e19 m; before: skipped as
    "no object of board size in the scan") and a CSV with a point at infinity: each frame skipped as a
    damaged file, named, its values called impossible; the other frames calibrate."""
    d = _data(pair, tmp_path / "data", (pair / "config.yaml").read_text())
    scan = read_scan(d / "pcd" / "0002.pcd")
    (d / "pcd" / "0002.pcd").unlink()
    np.c_[scan.points, scan.intensity].astype("<f8").tofile(d / "pcd" / "0002.bin")
    scan = read_scan(d / "pcd" / "0004.pcd")
    (d / "pcd" / "0004.pcd").unlink()
    xyz = scan.points.copy()
    xyz[7] = [np.inf, 0.0, 1.0]
    write_csv(d / "pcd" / "0004.csv", Scan(xyz, scan.intensity, scan.ring))
    out = tmp_path / "out"
    assert main(["calibrate", str(d), "--out", str(out), "--jobs", "1", "--no-report"]) == 0
    frames = {f["name"]: f for f in yaml.safe_load((out / "calibration.yaml").read_text())["frames"]}
    for name, file in (("0002", "0002.bin"), ("0004", "0004.csv")):
        f = frames[name]
        assert not f["used"] and f.get("damaged"), f
        assert file in f["reason"] and "farther than any LiDAR reaches" in f["reason"], f["reason"]
    assert "KITTI's .bin is float32" in frames["0002"]["reason"]
    assert sum(f["used"] for f in frames.values()) == 3
    capsys.readouterr()


def test_a_key_twice_in_an_opencv_camera_file_is_refused(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """OpenCV's FileStorage YAML (read by OpenCV, which keeps the last of two keys silently)."""
    import cv2

    p = tmp_path / "out_camera_data.yml"
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 400)
    fs.write("camera_matrix", np.array([[320, 0, 319.5], [0, 320, 199.5], [0, 0, 1.0]]))
    fs.write("distortion_coefficients", np.zeros((5, 1)))
    fs.release()
    text = p.read_text() + "image_width: 1280\n"
    d = _data(pair, tmp_path / "cv", _without_camera(pair) + "camera: {file: cam.yml}\n", {"cam.yml": text})
    last = len(text.splitlines())
    err = _refused(["calibrate", str(d), "--out", str(tmp_path / "o"), "--jobs", "1"], capsys)
    assert "cam.yml: the key 'image_width' appears twice" in err and f"lines 3 and {last}" in err


@pytest.mark.parametrize("case", ["config-folder", "rig-fifo", "data-device"])
def test_a_data_set_file_that_is_no_file_is_named(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], case: str
) -> None:
    """config.yaml a folder, rig.yaml a FIFO (never opened), the data set /dev/zero (before: "no
    config.yaml in this folder", "not a data set")."""
    d = tmp_path / "data"
    shutil.copytree(pair / "pcd", d / "pcd")
    shutil.copytree(pair / "img", d / "img")
    if case == "config-folder":
        (d / "config.yaml").mkdir()
        want = f"{d / 'config.yaml'} is a folder: a data set's config.yaml is a file"
    elif case == "rig-fifo":
        os.mkfifo(d / "rig.yaml")
        want = f"{d / 'rig.yaml'} is a FIFO (named pipe): a data set's rig.yaml is a file"
    else:
        d, want = Path("/dev/zero"), "/dev/zero is a character device: expected a data set"
    err = _refused(["calibrate", str(d), "--out", str(tmp_path / "o"), "--jobs", "1"], capsys)
    assert want in err
