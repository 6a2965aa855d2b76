"""``ilcc-graph export`` through the command line, every format x every registered camera kind.

Each camera kind is simulated and calibrated by the command line; each export is written by the
command line to a file, parsed back and compared with what that ecosystem expects, computed here
from calibration.yaml and the conventions (interface.md, OpenCV, REP 103 / 105, Kalibr's camchain
reader), never by the exporter:

- KITTI ``calib_velo_to_cam.txt`` maps LiDAR points into an *optical* frame (z along the ray through
  the principal point, x towards growing u, y towards growing v), whatever our camera frame is;
- Kalibr: camera and distortion model by Kalibr's names, its intrinsics vector, what Kalibr's
  reader checks (model names, vector lengths, floats, integer resolution); no Kalibr file for a
  camera Kalibr has no model of;
- ROS tf: ``lidar`` parent, ``camera_optical`` child for a frame with optical axes (``camera``
  otherwise), the pose of the child in the parent, quaternion (x, y, z, w);
- JSON: the calibration's numbers and camera, the inverse and its covariance.
"""

from __future__ import annotations

import json
import re
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml
from test_export import quat_to_matrix, rigid  # Hamilton (x, y, z, w) read as ROS reads it

from ilcc_graph.app import main
from ilcc_graph.cameras import camera_kinds, make_camera

KINDS = camera_kinds()

#: Kalibr's model of each of our camera kinds: (camera_model, distortion_model, intrinsics from our
#: camera section, distortion coefficients from it); None: Kalibr has no such model. A new camera
#: kind must be added here (the test below fails for a kind it does not know).
KALIBR = {
    "pinhole": ("pinhole", "radtan", lambda c: _fxfycxcy(c), lambda c: c["dist"][:4]),
    "fisheye": ("pinhole", "equidistant", lambda c: _fxfycxcy(c), lambda c: c["dist"]),
    "unified": ("omni", "radtan", lambda c: [c["xi"], *_fxfycxcy(c)], lambda c: c["dist"]),
    "double_sphere": ("ds", "none", lambda c: [c["xi"], c["alpha"], *_fxfycxcy(c)], lambda c: []),
    "equirectangular": None,
}
#: what Kalibr's reader (kalibr_common.ConfigReader) wants: intrinsics per camera model,
#: coefficients per distortion model
KALIBR_INTRINSICS = {"pinhole": 4, "omni": 5, "ds": 6, "eucm": 6}
KALIBR_COEFFS = {"radtan": 4, "equidistant": 4, "fov": 1, "none": 0}


def _fxfycxcy(c: dict) -> list[float]:
    K = c["K"]
    return [K[0][0], K[1][1], K[0][2], K[1][2]]


@pytest.fixture(scope="module")
def runs(simulated, calibrated) -> dict[str, Path]:
    """calibration.yaml of a small simulated set per camera kind, as ``calibrate`` wrote it."""
    return {kind: calibrated(simulated(kind)) / "calibration.yaml" for kind in KINDS}


def _export(cal: Path, fmt: str, out: Path, *flags: str) -> Path:
    assert main(["export", str(cal), "--format", fmt, "--out", str(out), *flags]) == 0
    return out


def optical_from_camera(section: dict) -> np.ndarray:
    """(3, 3) R_opt_cam: the rows are the optical frame's axes in the camera frame, found by what the
    camera does: z is the ray through the principal point (the image centre of a panorama), x the way
    that ray turns as u grows, y as v grows (OpenCV's optical frame, REP 103's ``_optical``)."""
    cam = make_camera(section)
    if "K" in section:
        c = np.array([section["K"][0][2], section["K"][1][2]])
    else:
        c = np.array([(cam.width - 1) / 2, (cam.height - 1) / 2])
    z = cam.bearing(c)
    x = cam.bearing(c + [1.0, 0.0]) - z
    y = cam.bearing(c + [0.0, 1.0]) - z
    x -= (x @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])
    assert np.allclose(R, np.round(R), atol=1e-3), "the camera frame's axes are not the image's"
    return np.round(R)


def test_the_panorama_axes_are_those_of_the_interface():
    """interface.md: a panorama's frame is x forward (the image's centre column), y left, z up; the
    optical frame looks forward with x to the right and y down."""
    forward, left, up = np.eye(3)
    R_opt_pano = np.vstack([-left, -up, forward])
    section = {"model": "equirectangular", "width": 1200, "height": 600}
    np.testing.assert_array_equal(optical_from_camera(section), R_opt_pano)
    np.testing.assert_array_equal(R_opt_pano, [[0, -1, 0], [0, 0, -1], [1, 0, 0]])


@pytest.mark.parametrize("kind", KINDS)
def test_kitti(kind, runs, tmp_path):
    doc = yaml.safe_load(runs[kind].read_text())
    T = np.array(doc["T_cam_lidar"])
    R_opt = optical_from_camera(doc["camera"])
    path = _export(runs[kind], "kitti", tmp_path / "calib_velo_to_cam.txt")
    lines = dict(line.split(":", 1) for line in path.read_text().splitlines())
    assert list(lines)[:5] == ["calib_time", "R", "T", "delta_f", "delta_c"]
    R = np.array(lines["R"].split(), float).reshape(3, 3)
    t = np.array(lines["T"].split(), float)
    np.testing.assert_allclose(R, R_opt @ T[:3, :3], atol=1e-11)
    np.testing.assert_allclose(t, R_opt @ T[:3, 3], atol=1e-11)
    # what KITTI's devkit does with it: a LiDAR point 5 m along the camera's view lands on the optical z axis
    view = np.linalg.inv(T) @ np.r_[5.0 * R_opt[2], 1.0]
    np.testing.assert_allclose(R @ view[:3] + t, [0.0, 0.0, 5.0], atol=1e-9)
    assert "OpenCV" in lines["camera_frame"] and kind in lines["camera_frame"]


@pytest.mark.parametrize("kind", KINDS)
def test_kalibr(kind, runs, tmp_path, capsys):
    assert kind in KALIBR, f"say here which Kalibr model a {kind} camera is (or None)"
    doc = yaml.safe_load(runs[kind].read_text())
    out = tmp_path / "camchain.yaml"
    if KALIBR[kind] is None:  # no Kalibr model: refused with the reason, nothing written
        assert main(["export", str(runs[kind]), "--format", "kalibr", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert str(runs[kind]) in err and f"Kalibr has no {kind}" in err
        assert not out.exists()
        return
    model, distortion, intrinsics, coeffs = KALIBR[kind]
    cam0 = yaml.safe_load(_export(runs[kind], "kalibr", out).read_text())["cam0"]
    section = doc["camera"]
    assert (cam0["camera_model"], cam0["distortion_model"]) == (model, distortion)
    assert cam0["intrinsics"] == pytest.approx(intrinsics(section), rel=1e-15)
    assert cam0["distortion_coeffs"] == pytest.approx(coeffs(section), rel=1e-15, abs=0)
    assert cam0["resolution"] == [section["width"], section["height"]]
    np.testing.assert_allclose(cam0["T_cam_lidar"], doc["T_cam_lidar"], rtol=0, atol=1e-15)
    np.testing.assert_allclose(cam0["T_cam_lidar_covariance"], doc["covariance"], rtol=1e-15)
    # what Kalibr's reader checks
    assert len(cam0["intrinsics"]) == KALIBR_INTRINSICS[cam0["camera_model"]]
    assert len(cam0["distortion_coeffs"]) == KALIBR_COEFFS[cam0["distortion_model"]]
    assert all(isinstance(v, float) for v in cam0["intrinsics"] + cam0["distortion_coeffs"])
    assert all(isinstance(v, int) for v in cam0["resolution"]) and isinstance(cam0["rostopic"], str)
    if model == "ds":
        assert 0 <= cam0["intrinsics"][1] < 1
    if model == "omni":
        assert cam0["intrinsics"][0] >= 0


def _ros2(text: str) -> tuple[np.ndarray, str, str]:
    line = next(
        ln for ln in text.splitlines() if ln.startswith("ros2 run tf2_ros static_transform_publisher")
    )
    names = re.findall(r"--([a-z-]+) ", line)
    assert names == ["x", "y", "z", "qx", "qy", "qz", "qw", "frame-id", "child-frame-id"]
    a = dict(re.findall(r"--([a-z-]+) (\S+)", line))
    q = [float(a[k]) for k in ("qx", "qy", "qz", "qw")]
    assert abs(np.linalg.norm(q) - 1) < 1e-12 and q[3] >= 0
    return (
        rigid(quat_to_matrix(*q), np.array([float(a[k]) for k in "xyz"])),
        a["frame-id"],
        a["child-frame-id"],
    )


def _ros1(text: str) -> tuple[np.ndarray, str, str]:
    node = ET.fromstring(text[text.index("<launch>") :]).find("node")
    assert node is not None and (node.get("pkg"), node.get("type")) == (
        "tf2_ros",
        "static_transform_publisher",
    )
    a = node.get("args").split()  # x y z qx qy qz qw frame_id child_frame_id
    assert len(a) == 9
    return rigid(quat_to_matrix(*map(float, a[3:7])), np.array(a[:3], float)), a[7], a[8]


@pytest.mark.parametrize("kind", KINDS)
def test_ros_tf(kind, runs, tmp_path):
    doc = yaml.safe_load(runs[kind].read_text())
    T = np.array(doc["T_cam_lidar"])
    optical = bool(np.array_equal(optical_from_camera(doc["camera"]), np.eye(3)))
    child = "camera_optical" if optical else "camera"  # REP 103: optical axes are <name>_optical
    text = _export(runs[kind], "ros-tf", tmp_path / "tf.launch").read_text()
    for parse in (_ros2, _ros1):
        T_pc, parent, got_child = parse(text)
        assert (parent, got_child) == ("lidar", child)
        np.testing.assert_allclose(T_pc, np.linalg.inv(T), atol=1e-12)  # the camera's pose in the LiDAR frame
    # the other way round, other names, one ROS at a time
    flags = ("--parent", "camera", "--lidar-frame", "velodyne", "--camera-frame", "cam0", "--ros", "ros1")
    text = _export(runs[kind], "ros-tf", tmp_path / "tf1.launch", *flags).read_text()
    assert "ros2 run" not in text
    T_pc, parent, got_child = _ros1(text)
    assert (parent, got_child) == ("cam0", "velodyne")
    np.testing.assert_allclose(T_pc, T, atol=1e-12)
    assert _ros2(_export(runs[kind], "ros-tf", tmp_path / "tf2", "--ros", "ros2").read_text())[2] == child


@pytest.mark.parametrize("kind", KINDS)
def test_json(kind, runs, tmp_path):
    doc = yaml.safe_load(runs[kind].read_text())
    T, C = np.array(doc["T_cam_lidar"]), np.array(doc["covariance"])
    got = json.loads(_export(runs[kind], "json", tmp_path / "c.json").read_text())
    np.testing.assert_allclose(got["T_cam_lidar"], T, rtol=0, atol=1e-15)  # read as a rotation: 1 ulp
    np.testing.assert_allclose(got["covariance"], C, rtol=1e-15, atol=0)
    assert got["camera"] == doc["camera"]
    np.testing.assert_allclose(np.array(got["T_lidar_cam"]) @ T, np.eye(4), atol=1e-12)
    Ad = gtsam.Pose3(T).AdjointMap()  # T_lidar_cam = T^-1: its tangent is -Ad(T) xi
    np.testing.assert_allclose(got["covariance_T_lidar_cam"], Ad @ C @ Ad.T, rtol=1e-9, atol=1e-20)
    assert got["sigma"]["tx_mm"] == pytest.approx(doc["sigma"]["tx_mm"])


def test_a_calibration_without_its_camera_is_refused_by_name(runs, tmp_path, capsys):
    """A calibration.yaml without ``camera:`` (and no config.resolved.yaml beside it): formats that
    depend on the camera are refused, naming the file; with config.resolved.yaml beside it they are
    written from its camera."""
    doc = yaml.safe_load(runs["equirectangular"].read_text())
    del doc["camera"]
    bare = tmp_path / "bare" / "calibration.yaml"
    bare.parent.mkdir()
    bare.write_text(yaml.safe_dump(doc))
    for fmt in ("kitti", "ros-tf", "kalibr"):
        assert main(["export", str(bare), "--format", fmt]) == 2
        err = capsys.readouterr().err
        assert str(bare) in err and f"the {fmt} export needs the camera model" in err
    assert main(["export", str(bare), "--format", "json"]) == 0
    assert json.loads(capsys.readouterr().out)["camera"] is None
    shutil.copy(runs["equirectangular"].parent / "config.resolved.yaml", bare.parent)
    kitti = _export(bare, "kitti", tmp_path / "k.txt").read_text()
    assert "rotated from ilcc_graph's equirectangular camera frame" in kitti
