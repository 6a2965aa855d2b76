"""A rig's calibration in other tools' formats (docs/rig.md, "Exports of a rig"), as text.

From a rig's calibration (``io.rig_results.RigCalibration``: every ``T_ref_sensor``, the joint
covariance, the rig's cameras):

- ``ros-tf``: a ROS 1 launch file, one ``tf2_ros/static_transform_publisher`` per frame;
- ``urdf``: a URDF snippet, a link per frame and a fixed joint per transform;
- ``kalibr``: a Kalibr camchain (``cam0``...: intrinsics, ``T_cn_cnm1`` the chained camera-camera
  transforms, ``T_cam_lidar`` to the reference LiDAR as Kalibr's ``T_cam_imu``);
- ``json``: every pose, the joint covariance, every pair's relative pose with its covariance.

Frames (REP 103): every sensor has a body frame named after it, forward-left-up (a LiDAR's own
frame; a camera's axes turned by its model's ``R_flu_cam``); a camera whose own axes are OpenCV's
(z forward, x right, y down) has a child ``<name>_optical`` in those axes. The tree's root is the
reference sensor's body frame, every other body frame its child.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ilcc_graph.cameras import CameraModel, make_camera
from ilcc_graph.exports import CONVENTION, _num, _quat_xyzw, _yaml_row, refined_camera
from ilcc_graph.io.rig_results import RigCalibration
from ilcc_graph.types import sigma_dict

__all__ = ["RIG_FORMATS", "export_rig", "rig_cameras", "tf_frames"]

RIG_FORMATS = ("ros-tf", "urdf", "kalibr", "json")


def rig_cameras(cal: RigCalibration) -> dict[str, CameraModel]:
    """{camera: model} from the calibration's rig section (in its sensors' order), with the intrinsics
    the run refined where it did (``camera_intrinsics``). ValueError when those are not the camera's."""
    sensors = (cal.rig or {}).get("sensors", {})
    refined = cal.refined_intrinsics()
    out = {}
    for s in (s for s in cal.sensors if "camera" in sensors.get(s, {})):
        cam = make_camera(sensors[s]["camera"])
        out[s] = refined_camera(cam, refined[s], f"camera_intrinsics.{s}: ") if s in refined else cam
    return out


def tf_frames(cal: RigCalibration) -> list[tuple[str, str, np.ndarray]]:
    """The transform tree as ``(parent, child, T_parent_child)``: root -> every other body frame,
    then body -> ``_optical`` for cameras whose axes are not forward-left-up."""
    cams = rig_cameras(cal)

    def body(s: str) -> np.ndarray:  # T_ref_body = T_ref_sensor @ R_flu_sensor^T
        T = np.array(cal.T_ref_sensor[s], dtype=np.float64)
        if s in cams:
            T[:3, :3] = T[:3, :3] @ np.asarray(cams[s].R_flu_cam).T
        return T

    root = cal.reference
    T_root = body(root)
    out = [(root, s, np.linalg.solve(T_root, body(s))) for s in cal.sensors if s != root]
    for s, cam in cams.items():
        R = np.asarray(cam.R_flu_cam)
        if not np.allclose(R, np.eye(3)):
            T = np.eye(4)
            T[:3, :3] = R
            out.append((s, f"{s}_optical", T))
    return out


def _ros_tf(cal: RigCalibration) -> str:
    lines = [
        "<launch>",
        "  <!-- ilcc_graph rig calibration: static transforms parent -> child (p_parent = R p_child + t);",
        "       REP 103 frames: <sensor> forward-left-up, <sensor>_optical OpenCV axes -->",
    ]
    for parent, child, T in tf_frames(cal):
        x, y, z = (_num(v) for v in T[:3, 3])
        q = " ".join(_num(v) for v in _quat_xyzw(T[:3, :3]))
        lines += [
            f'  <node pkg="tf2_ros" type="static_transform_publisher" name="{parent}_to_{child}"',
            f'        args="{x} {y} {z} {q} {parent} {child}" />',
        ]
    return "\n".join([*lines, "</launch>"]) + "\n"


def _urdf(cal: RigCalibration, robot: str = "rig") -> str:
    frames = tf_frames(cal)
    links = [cal.reference, *(c for _, c, _ in frames)]
    lines = [f'<robot name="{robot}">', "  <!-- ilcc_graph rig calibration; REP 103 frames (docs/rig.md) -->"]
    lines += [f'  <link name="{n}"/>' for n in links]
    for parent, child, T in frames:
        rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")  # fixed axes: R = Rz(y) Ry(p) Rx(r)
        xyz, angles = (" ".join(_num(v) for v in x) for x in (T[:3, 3], rpy))
        lines += [
            f'  <joint name="{parent}_to_{child}" type="fixed">',
            f'    <parent link="{parent}"/>',
            f'    <child link="{child}"/>',
            f'    <origin xyz="{xyz}" rpy="{angles}"/>',
            "  </joint>",
        ]
    return "\n".join([*lines, "</robot>"]) + "\n"


def _kalibr(cal: RigCalibration, topics: Mapping[str, str] | None = None) -> str:
    cams = rig_cameras(cal)
    if not cams:
        raise ValueError("kalibr: the rig has no camera")
    lidar = cal.reference
    out = [
        "# Kalibr camchain written by ilcc_graph from a rig calibration.",
        "# T_cn_cnm1: p_cam_n = T_cn_cnm1 @ p_cam_(n-1) (chained camera-camera transforms, metres);",
        f"# T_cam_lidar: p_cam = T_cam_lidar @ p_{lidar} (the reference sensor, as Kalibr's T_cam_imu).",
    ]
    body: list[str] = []
    names = list(cams)
    for n, s in enumerate(names):
        cam = cams[s]
        fields, notes = cam.kalibr()  # ValueError when Kalibr has no model for the camera
        out += [f"# cam{n} ({s}): {x}" for x in notes]
        body.append(f"cam{n}:")
        body.append(f"  # {s}")
        T_cl = np.linalg.solve(cal.T_ref_sensor[s], cal.T_ref_sensor[lidar])
        body += ["  T_cam_lidar:"] + [f"  - {_yaml_row(r)}" for r in T_cl]
        if n > 0:
            T = np.linalg.solve(cal.T_ref_sensor[s], cal.T_ref_sensor[names[n - 1]])
            body += ["  T_cn_cnm1:"] + [f"  - {_yaml_row(r)}" for r in T]
        for key, value in fields.items():
            body.append(f"  {key}: {value if isinstance(value, str) else _yaml_row(value)}")
        body.append(f"  resolution: [{int(cam.width)}, {int(cam.height)}]")
        body += ["  cam_overlaps: []", f"  rostopic: {(topics or {}).get(s, f'/{s}/image_raw')}"]
    return "\n".join(out + body) + "\n"


def _json(cal: RigCalibration) -> str:
    doc: dict[str, Any] = {
        "reference": cal.reference,
        "sensors": list(cal.sensors),
        "T_ref_sensor": {s: np.asarray(cal.T_ref_sensor[s]).tolist() for s in cal.sensors},
        "covariance": np.asarray(cal.covariance).tolist(),
        "covariance_order": [f"{s}.{x}" for s in cal.sensors for x in ("rx", "ry", "rz", "tx", "ty", "tz")],
        "sigma": {s: sigma_dict(cal.block(s)) for s in cal.sensors if s != cal.reference},
        "pairs": {
            f"{a}/{b}": {
                "T_a_b": np.asarray(T).tolist(),
                "covariance": np.asarray(C).tolist(),
                "sigma": sigma_dict(C),
            }
            for (a, b), (T, C) in cal.pairs.items()
        },
        "cameras": {s: c.to_dict() for s, c in rig_cameras(cal).items()},
        "convention": "T_ref_sensor: p_ref = T_ref_sensor @ p_sensor; T_a_b: p_a = T_a_b @ p_b. "
        + CONVENTION,
    }
    return json.dumps(doc, indent=2) + "\n"


def export_rig(cal: RigCalibration, fmt: str, **options: Any) -> str:
    """``cal`` as text in format ``fmt`` (``RIG_FORMATS``); options: ``robot`` (urdf), ``topics``
    {camera: image topic} (kalibr). ValueError for an unknown format or a camera Kalibr cannot hold."""
    if fmt == "ros-tf":
        return _ros_tf(cal)
    if fmt == "urdf":
        return _urdf(cal, **options)
    if fmt == "kalibr":
        return _kalibr(cal, **options)
    if fmt == "json":
        return _json(cal)
    raise ValueError(f"unknown rig export format {fmt!r}; expected one of {', '.join(RIG_FORMATS)}")
