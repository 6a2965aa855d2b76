"""Tests of ilcc_graph.exports: every format reads back to the same transform."""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml

from ilcc_graph.exports import FORMATS, export_calibration
from ilcc_graph.handoff import invert_with_covariance
from ilcc_graph.types import Calibration, sigma_dict

PINHOLE = {
    "model": "pinhole",
    "width": 1280,
    "height": 720,
    "K": [[900.0, 0.0, 640.5], [0.0, 905.0, 360.25], [0.0, 0.0, 1.0]],
    "dist": [-0.2, 0.05, 0.001, -0.002, 0.0],
}
FISHEYE = {
    "model": "fisheye",
    "width": 1024,
    "height": 768,
    "K": [[350.0, 0.0, 512.0], [0.0, 351.0, 384.0], [0.0, 0.0, 1.0]],
    "dist": [0.01, -0.002, 0.0003, -0.00004],
}
EQUIRECT = {"model": "equirectangular", "width": 8000, "height": 4000}


def sample(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    T = gtsam.Pose3.Expmap(np.concatenate([rng.normal(0, 1.5, 3), rng.normal(0, 0.3, 3)])).matrix()
    A = rng.normal(size=(6, 6)) * np.array([1e-3] * 3 + [5e-3] * 3)
    return T, A @ A.T + 1e-8 * np.eye(6)


def quat_to_matrix(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """Rotation matrix of a unit quaternion (Hamilton, as ROS and Eigen)."""
    n = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    x, y, z, w = qx / n, qy / n, qz / n, qw / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def rigid(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def test_formats_listed():
    assert FORMATS == ("json", "ros-tf", "kitti", "kalibr", "lidar-offsets")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_json_round_trip(seed):
    T, cov = sample(seed)
    doc = json.loads(export_calibration((T, cov), "json", camera=PINHOLE))
    np.testing.assert_allclose(doc["T_cam_lidar"], T, atol=1e-15)
    np.testing.assert_allclose(np.array(doc["T_lidar_cam"]) @ T, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(doc["covariance"], cov, rtol=1e-15)
    _, cov_inv = invert_with_covariance(T, cov)
    np.testing.assert_allclose(doc["covariance_T_lidar_cam"], cov_inv, rtol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(*doc["quaternion_xyzw_cam_lidar"]), T[:3, :3], atol=1e-12)
    assert doc["sigma"]["tx_mm"] == pytest.approx(1e3 * np.sqrt(cov[3, 3]))
    assert doc["sigma"]["rz_deg"] == pytest.approx(np.degrees(np.sqrt(cov[2, 2])))
    assert doc["camera"]["K"] == PINHOLE["K"]
    assert "p_cam = R @ p_lidar + t" in doc["convention"]


def parse_ros2(text: str) -> tuple[np.ndarray, str, str]:
    line = next(
        ln for ln in text.splitlines() if ln.startswith("ros2 run tf2_ros static_transform_publisher")
    )
    args = dict(re.findall(r"--([a-z-]+) (\S+)", line))
    R = quat_to_matrix(*(float(args[k]) for k in ("qx", "qy", "qz", "qw")))
    t = np.array([float(args[k]) for k in ("x", "y", "z")])
    return rigid(R, t), args["frame-id"], args["child-frame-id"]


def parse_ros1(text: str) -> tuple[np.ndarray, str, str]:
    launch = ET.fromstring(text[text.index("<launch>") :])
    node = launch.find("node")
    assert (
        node is not None and node.get("pkg") == "tf2_ros" and node.get("type") == "static_transform_publisher"
    )
    a = node.get("args").split()
    assert len(a) == 9
    R = quat_to_matrix(*(float(v) for v in a[3:7]))
    return rigid(R, np.array([float(v) for v in a[:3]])), a[7], a[8]


@pytest.mark.parametrize("seed", [0, 3])
def test_ros_tf_frame_order(seed):
    T, cov = sample(seed)
    # default: LiDAR is the parent, so the published transform is the camera's pose in the LiDAR frame
    text = export_calibration((T, cov), "ros-tf", camera=EQUIRECT)
    for parse in (parse_ros2, parse_ros1):
        T_pc, parent, child = parse(text)
        assert (parent, child) == ("lidar", "camera")
        np.testing.assert_allclose(T_pc, np.linalg.inv(T), atol=1e-12)
    # camera as parent, custom names, pinhole: the published transform is T_cam_lidar itself
    text = export_calibration(
        (T, cov),
        "ros-tf",
        camera=PINHOLE,
        parent="camera",
        lidar_frame="velodyne",
        camera_frame="cam0_optical",
    )
    for parse in (parse_ros2, parse_ros1):
        T_pc, parent, child = parse(text)
        assert (parent, child) == ("cam0_optical", "velodyne")
        np.testing.assert_allclose(T_pc, T, atol=1e-12)
    # a pinhole camera's frame defaults to the optical frame name
    assert parse_ros2(export_calibration((T, cov), "ros-tf", camera=PINHOLE))[2] == "camera_optical"


def test_ros_tf_single_flavours():
    T, cov = sample(4)
    ros2 = export_calibration((T, cov), "ros-tf", camera=FISHEYE, ros="ros2")
    assert "<launch>" not in ros2 and parse_ros2(ros2)[1] == "lidar"
    ros1 = export_calibration((T, cov), "ros-tf", camera=FISHEYE, ros="ros1")
    assert "ros2 run" not in ros1
    ET.fromstring(ros1)  # a whole, valid launch file
    with pytest.raises(ValueError, match="parent"):
        export_calibration((T, cov), "ros-tf", camera=FISHEYE, parent="world")


def parse_kitti(text: str) -> dict[str, str]:
    out = {}
    for line in text.splitlines():
        key, value = line.split(":", 1)
        out[key] = value.strip()
    return out


def test_kitti_pinhole_round_trip():
    T, cov = sample(5)
    d = parse_kitti(export_calibration((T, cov), "kitti", camera=PINHOLE, calib_time="15-Mar-2012 11:37:16"))
    assert list(d)[:5] == ["calib_time", "R", "T", "delta_f", "delta_c"]
    assert d["calib_time"] == "15-Mar-2012 11:37:16"
    R = np.array(d["R"].split(), dtype=float).reshape(3, 3)
    t = np.array(d["T"].split(), dtype=float)
    np.testing.assert_allclose(rigid(R, t), T, atol=1e-11)
    np.testing.assert_allclose(np.array(d["delta_f"].split(), dtype=float), [0.0, 0.0])
    assert "OpenCV" in d["camera_frame"]


def test_kitti_equirectangular_uses_opencv_axes():
    T, cov = sample(6)
    d = parse_kitti(export_calibration((T, cov), "kitti", camera=EQUIRECT))
    T_k = rigid(np.array(d["R"].split(), dtype=float).reshape(3, 3), np.array(d["T"].split(), dtype=float))
    T_lidar_cam = np.linalg.inv(T)
    # points ahead of, left of and above the equirectangular camera, given in the LiDAR frame
    for p_eq, p_cv in (([5.0, 0, 0], [0, 0, 5.0]), ([0, 2.0, 0], [-2.0, 0, 0]), ([0, 0, 3.0], [0, -3.0, 0])):
        p_lidar = T_lidar_cam @ np.array([*p_eq, 1.0])
        np.testing.assert_allclose((T_k @ p_lidar)[:3], p_cv, atol=1e-10)
    assert "equirectangular" in d["camera_frame"]


def test_kalibr_round_trip():
    T, cov = sample(7)
    doc = yaml.safe_load(export_calibration((T, cov), "kalibr", camera=PINHOLE))
    cam = doc["cam0"]
    np.testing.assert_allclose(cam["T_cam_lidar"], T, atol=1e-15)
    np.testing.assert_allclose(cam["T_cam_lidar_covariance"], cov, rtol=1e-15)
    assert cam["camera_model"] == "pinhole"
    assert cam["intrinsics"] == [900.0, 905.0, 640.5, 360.25]
    assert cam["distortion_model"] == "radtan"
    assert cam["distortion_coeffs"] == PINHOLE["dist"][:4]
    assert cam["resolution"] == [1280, 720]

    cam = yaml.safe_load(export_calibration((T, cov), "kalibr", camera=FISHEYE))["cam0"]
    assert cam["distortion_model"] == "equidistant"
    assert cam["distortion_coeffs"] == FISHEYE["dist"]

    # cameras Kalibr cannot hold exactly are refused, saying why, rather than written wrong
    k3 = dict(PINHOLE, dist=[-0.2, 0.05, 0.001, -0.002, 0.01])
    with pytest.raises(ValueError, match=r"k3\.\. = \[0\.01\]"):
        export_calibration((T, cov), "kalibr", camera=k3)
    tiny = dict(PINHOLE, dist=[-0.2, 0.05, 0.001, -0.002, 1e-6])  # moves no pixel by 0.001 px: left out
    text = export_calibration((T, cov), "kalibr", camera=tiny)
    assert (
        yaml.safe_load(text)["cam0"]["distortion_coeffs"] == tiny["dist"][:4]
        and "# k3.. = [1e-06] left out" in text
    )
    skew = dict(PINHOLE, K=[[900.0, 0.5, 640.5], [0.0, 905.0, 360.25], [0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="no skew"):
        export_calibration((T, cov), "kalibr", camera=skew)
    with pytest.raises(ValueError, match="no equirectangular"):
        export_calibration((T, cov), "kalibr", camera=EQUIRECT)


@pytest.mark.parametrize("fmt", ["ros-tf", "kitti", "kalibr"])
def test_formats_that_depend_on_the_camera_need_it(fmt, tmp_path: Path):
    T, cov = sample(10)
    with pytest.raises(ValueError, match=f"the {fmt} export needs the camera model"):
        export_calibration((T, cov), fmt)
    # a calibration (or its file) carries its camera: nothing to pass
    cal = Calibration(T_cam_lidar=T, covariance=cov, frames=(), camera=FISHEYE)
    assert export_calibration(
        cal, fmt, **({"calib_time": "x"} if fmt == "kitti" else {})
    ) == export_calibration((T, cov), fmt, camera=FISHEYE, **({"calib_time": "x"} if fmt == "kitti" else {}))
    json.loads(export_calibration((T, cov), "json"))  # the JSON says "camera": null instead


def test_refined_intrinsics_are_exported_with_the_extrinsic():
    T, cov = sample(11)
    refined = [351.0, 352.5, 511.0, 385.0, 0.011, -0.0021, 0.00031, -0.00005]
    sensors = {"camera_intrinsics": {"names": ["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"],
                                     "stated": np.zeros(8), "values": np.array(refined),
                                     "sigmas": np.ones(8)}}  # fmt: skip
    cal = Calibration(T_cam_lidar=T, covariance=cov, frames=(), camera=FISHEYE, sensors=sensors)
    cam = yaml.safe_load(export_calibration(cal, "kalibr"))["cam0"]
    assert cam["intrinsics"] == refined[:4] and cam["distortion_coeffs"] == refined[4:]
    assert json.loads(export_calibration(cal, "json"))["camera"]["K"][0] == [351.0, 0.0, 511.0]
    # given explicitly, the camera is taken as it is
    cam = yaml.safe_load(export_calibration(cal, "kalibr", camera=FISHEYE))["cam0"]
    assert cam["intrinsics"] == [350.0, 351.0, 512.0, 384.0]


def test_inputs_calibration_pose_and_file(tmp_path: Path):
    T, cov = sample(8)
    from_pair = export_calibration((gtsam.Pose3(T), cov), "json")
    from_cal = export_calibration(Calibration(T_cam_lidar=T, covariance=cov, frames=()), "json")
    assert from_pair == from_cal
    path = tmp_path / "calibration.yaml"
    doc = {"T_cam_lidar": T.tolist(), "covariance": cov.tolist(), "sigma": sigma_dict(cov)}
    path.write_text(yaml.safe_dump({**doc, "frames": []}))
    np.testing.assert_allclose(json.loads(export_calibration(path, "json"))["T_cam_lidar"], T, atol=1e-15)


def test_errors():
    T, cov = sample(9)
    with pytest.raises(ValueError, match="unknown export format"):
        export_calibration((T, cov), "csv")
    with pytest.raises(ValueError, match="no option 'parent'"):
        export_calibration((T, cov), "json", parent="camera")
    with pytest.raises(ValueError, match="rigid"):
        export_calibration((np.diag([1.0, 2.0, 1.0, 1.0]), cov), "json")
    with pytest.raises(ValueError, match="unknown model"):
        export_calibration((T, cov), "json", camera={"model": "orthographic"})


def test_lidar_offsets_yaml_and_csv(tmp_path: Path) -> None:
    import csv
    import io

    from ilcc_graph.io import write_calibration

    T, cov = sample(7)
    lid = {
        "names": ["offset[0]", "offset[5]", "dark"],
        "values": np.array([0.0012, -0.0031, 0.0123]),
        "sigmas": np.array([0.0004, 0.0006, 0.0002]),
        "left_out": [["beam 2", "3 returns on 1 board(s): too few to estimate its terms"]],
        "elevation_deg": {"offset[0]": -15.0, "offset[5]": 1.0},
    }
    cal = Calibration(T_cam_lidar=T, covariance=cov, frames=(), sensors={"lidar_errors": lid})
    doc = yaml.safe_load(export_calibration(cal, "lidar-offsets"))
    assert [b["beam"] for b in doc["beams"]] == [0, 5]
    assert doc["beams"][1]["offset_mm"] == pytest.approx(-3.1) and doc["beams"][1][
        "sigma_mm"
    ] == pytest.approx(0.6)
    assert doc["beams"][0]["elevation_deg"] == -15.0
    assert doc["dark_mm"] == {"value": pytest.approx(12.3), "sigma": pytest.approx(0.2)}
    assert doc["left_out"][0]["term"] == "beam 2"
    rows = list(csv.DictReader(io.StringIO(export_calibration(cal, "lidar-offsets", table="csv"))))
    rows = [r for r in rows if not r["term"].startswith("#")]
    assert [r["term"] for r in rows] == lid["names"]
    assert float(rows[2]["value"]) == pytest.approx(12.3) and rows[2]["unit"] == "mm"
    # from the file calibrate writes, and a clear error when the terms were not estimated
    path = write_calibration(tmp_path / "calibration.yaml", cal)
    again = yaml.safe_load(export_calibration(path, "lidar-offsets"))
    assert [(b["beam"], b["elevation_deg"]) for b in again["beams"]] == [(0, -15.0), (5, 1.0)]
    assert [b["offset_mm"] for b in again["beams"]] == pytest.approx([1.2, -3.1])
    assert again["left_out"] == doc["left_out"]
    with pytest.raises(ValueError, match="--sensor-model beams"):
        export_calibration(Calibration(T_cam_lidar=T, covariance=cov, frames=()), "lidar-offsets")
