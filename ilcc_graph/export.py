"""Write the extrinsic in other tools' formats (JSON, ROS static tf, KITTI, Kalibr).

Every format starts from ``T_cam_lidar`` (``p_cam = R @ p_lidar + t``) and its 6x6 covariance in
GTSAM's Pose3 tangent convention (``shared/interface.md``). ``docs/exports.md`` gives each
format's frame convention. The functions return text; the command line writes it.
"""

from __future__ import annotations

import datetime as _dt
import inspect
import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

from ilcc_graph.handoff import (
    check_covariance,
    check_rigid,
    invert_with_covariance,
    load_calibration,
)
from ilcc_graph.types import Calibration, sigma_dict

CONVENTION = (
    "T_cam_lidar maps LiDAR-frame points to camera-frame points: p_cam = R @ p_lidar + t "
    "(metres). Covariances are 6x6 in GTSAM's Pose3 tangent convention for the named pose T: "
    "T_true = T * Pose3.Expmap(xi), xi = (rx, ry, rz, tx, ty, tz), rotation first, radians and "
    "metres. LiDAR frame: the sensor's own (x forward, y left, z up). Camera frame: OpenCV's "
    "(z forward, x right, y down) for pinhole and fisheye cameras; x forward (image centre "
    "column), y left, z up for equirectangular cameras."
)

# Rotation from the equirectangular camera frame (x forward, y left, z up) to a camera frame at
# the same place with OpenCV's axes (z forward, x right, y down): p_cv = R_CV_EQ @ p_eq.
R_CV_EQ = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])

CalibrationLike = Calibration | tuple[gtsam.Pose3 | np.ndarray, np.ndarray] | str | Path


def _as_T_cov(cal: CalibrationLike) -> tuple[np.ndarray, np.ndarray | None]:
    """(4, 4) ``T_cam_lidar`` and (6, 6) covariance from any accepted input, checked; the covariance
    is None for a calibration that has none (the paper's refinement writes NaN)."""
    if isinstance(cal, (str, Path)):
        pose, cov = load_calibration(cal)
        return pose.matrix(), cov
    if isinstance(cal, Calibration):
        T, cov = cal.T_cam_lidar, cal.covariance
    else:
        T, cov = cal
    T = T.matrix() if isinstance(T, gtsam.Pose3) else T
    if cov is None or np.all(np.isnan(np.asarray(cov, dtype=np.float64))):
        return check_rigid(T, "T_cam_lidar"), None
    return check_rigid(T, "T_cam_lidar"), check_covariance(cov, "covariance")


def _camera_dict(camera: Any) -> dict | None:
    """Our config schema (``model``, ``width``, ``height``, ``K``, ``dist``) from a dict or a
    ``CameraModel`` (anything with ``to_dict()``); None stays None."""
    if camera is None:
        return None
    if isinstance(camera, Mapping):
        d = dict(camera)
    elif hasattr(camera, "to_dict"):
        d = dict(camera.to_dict())
    else:
        raise TypeError(f"camera: expected a dict or a CameraModel, got {type(camera).__name__}")
    if "model" not in d and "kind" in d:
        d["model"] = d["kind"]
    if d.get("model") not in ("equirectangular", "pinhole", "fisheye"):
        raise ValueError(
            f"camera: unknown model {d.get('model')!r}; expected equirectangular|pinhole|fisheye"
        )
    return d


def _quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) with w >= 0 of a rotation matrix."""
    q = np.array(gtsam.Rot3(R).toQuaternion().coeffs(), dtype=np.float64)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def _num(x: float) -> str:
    """Shortest text that reads back as the same float, with a '.' so YAML 1.1 reads a float."""
    text = repr(float(x))
    if "e" in text and "." not in text.split("e")[0]:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}.0e{exponent}"
    elif "e" not in text and "." not in text and text not in ("inf", "-inf", "nan"):
        text += ".0"
    return text


# --------------------------------------------------------------------------------------- json
def _jsonable(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"cannot write {type(o).__name__} to JSON")


def _export_json(T: np.ndarray, cov: np.ndarray | None, camera: dict | None) -> str:
    T_inv, cov_inv = invert_with_covariance(T, np.eye(6) if cov is None else cov)
    doc = {
        "T_cam_lidar": T.tolist(),
        "T_lidar_cam": T_inv.matrix().tolist(),
        "covariance": None if cov is None else cov.tolist(),
        "covariance_T_lidar_cam": None if cov is None else cov_inv.tolist(),
        "sigma": None if cov is None else sigma_dict(cov),
        "sigma_T_lidar_cam": None if cov is None else sigma_dict(cov_inv),
        "quaternion_xyzw_cam_lidar": _quat_xyzw(T[:3, :3]).tolist(),
        "camera": camera,
        "convention": CONVENTION,
    }
    return json.dumps(doc, indent=2, default=_jsonable) + "\n"


# ------------------------------------------------------------------------------------- ros-tf
def _export_ros_tf(
    T: np.ndarray,
    cov: np.ndarray | None,
    camera: dict | None,
    *,
    parent: str = "lidar",
    lidar_frame: str = "lidar",
    camera_frame: str | None = None,
    ros: str = "both",
) -> str:
    if camera_frame is None:
        optical = camera is not None and camera["model"] in ("pinhole", "fisheye")
        camera_frame = "camera_optical" if optical else "camera"
    if parent == "lidar":
        T_pc, parent_frame, child_frame = np.linalg.inv(T), lidar_frame, camera_frame
    elif parent == "camera":
        T_pc, parent_frame, child_frame = T, camera_frame, lidar_frame
    else:
        raise ValueError(f"parent must be 'lidar' or 'camera', got {parent!r}")
    if ros not in ("both", "ros1", "ros2"):
        raise ValueError(f"ros must be 'both', 'ros1' or 'ros2', got {ros!r}")
    x, y, z = (_num(v) for v in T_pc[:3, 3])
    qx, qy, qz, qw = (_num(v) for v in _quat_xyzw(T_pc[:3, :3]))
    if camera is None:
        axes = "unknown (pass the camera model)"
    elif camera["model"] == "equirectangular":
        axes = "x forward, y left, z up (equirectangular)"
    else:
        axes = "OpenCV optical (z forward, x right, y down)"
    which = "T_lidar_cam = inverse of T_cam_lidar" if parent == "lidar" else "T_cam_lidar"
    about = (
        f"static transform {parent_frame} -> {child_frame}: the pose of '{child_frame}' in "
        f"'{parent_frame}', p_{parent_frame} = R p_{child_frame} + t ({which}); camera axes: {axes}"
    )
    lines: list[str] = []
    if ros in ("both", "ros2"):
        lines += [
            f"# ROS 2 (ilcc_graph): {about}",
            "ros2 run tf2_ros static_transform_publisher"
            f" --x {x} --y {y} --z {z} --qx {qx} --qy {qy} --qz {qz} --qw {qw}"
            f" --frame-id {parent_frame} --child-frame-id {child_frame}",
        ]
    if ros in ("both", "ros1"):
        if lines:
            lines.append("")
        lines += [
            "<launch>",
            f"  <!-- ROS 1 (ilcc_graph): {about.replace('--', '- -')} -->",
            f'  <node pkg="tf2_ros" type="static_transform_publisher" name="{parent_frame}_to_{child_frame}"',
            f'        args="{x} {y} {z} {qx} {qy} {qz} {qw} {parent_frame} {child_frame}" />',
            "</launch>",
        ]
    return "\n".join(lines) + "\n"


# -------------------------------------------------------------------------------------- kitti
def _export_kitti(
    T: np.ndarray,
    cov: np.ndarray | None,
    camera: dict | None,
    *,
    calib_time: _dt.datetime | str | None = None,
) -> str:
    T_out = T.copy()
    if camera is None:
        frame = "camera frame as calibrated (camera model not given; OpenCV axes assumed)"
    elif camera["model"] == "equirectangular":
        T_out[:3, :] = R_CV_EQ @ T[:3, :]
        frame = (
            "OpenCV axes (z forward = equirectangular image centre column, x right, y down), "
            "rotated from ilcc_graph's equirectangular camera frame (x forward, y left, z up)"
        )
    else:
        frame = f"OpenCV camera frame (z forward, x right, y down) of the {camera['model']} camera"
    if calib_time is None:
        calib_time = _dt.datetime.now(_dt.timezone.utc)
    if isinstance(calib_time, _dt.datetime):
        calib_time = calib_time.strftime("%d-%b-%Y %H:%M:%S")
    R, t = T_out[:3, :3], T_out[:3, 3]
    return (
        f"calib_time: {calib_time}\n"
        f"R: {' '.join(format(v, '.12e') for v in R.ravel())}\n"
        f"T: {' '.join(format(v, '.12e') for v in t)}\n"
        f"delta_f: {0.0:e} {0.0:e}\n"
        f"delta_c: {0.0:e} {0.0:e}\n"
        f"camera_frame: {frame}\n"
    )


# ------------------------------------------------------------------------------------- kalibr
def _yaml_row(v: np.ndarray) -> str:
    return "[" + ", ".join(_num(x) for x in v) + "]"


def _export_kalibr(
    T: np.ndarray,
    cov: np.ndarray | None,
    camera: dict | None,
    *,
    rostopic: str = "/camera/image_raw",
) -> str:
    out = [
        "# Kalibr camchain-style YAML written by ilcc_graph.",
        "# T_cam_lidar (like Kalibr's T_cam_imu): p_cam = T_cam_lidar @ p_lidar, metres.",
        "# T_cam_lidar_covariance: GTSAM Pose3 tangent, T_true = T * Expmap(xi), xi = (rx ry rz tx ty tz).",
    ]
    notes: list[str] = []
    body = ["cam0:", "  T_cam_lidar:"]
    body += [f"  - {_yaml_row(r)}" for r in T]
    if cov is not None:
        body += ["  T_cam_lidar_covariance:"]
        body += [f"  - {_yaml_row(r)}" for r in cov]
    else:
        notes.append("no covariance: the calibration method gives none.")
    if camera is not None:
        model = camera["model"]
        if model == "equirectangular":
            notes.append("Kalibr has no equirectangular model: camera frame x forward, y left, z up.")
            body.append("  camera_model: equirectangular")
        else:
            K = np.asarray(camera["K"], dtype=np.float64)
            dist = np.asarray(camera.get("dist", []), dtype=np.float64).ravel()
            body.append("  camera_model: pinhole")
            body.append(f"  intrinsics: {_yaml_row([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])}")
            if model == "fisheye":
                body.append("  distortion_model: equidistant")
                body.append(f"  distortion_coeffs: {_yaml_row(np.pad(dist, (0, max(0, 4 - dist.size)))[:4])}")
            elif np.all(dist[4:] == 0.0):
                body.append("  distortion_model: radtan")
                body.append(f"  distortion_coeffs: {_yaml_row(np.pad(dist, (0, max(0, 4 - dist.size)))[:4])}")
            else:
                notes.append(
                    "OpenCV distortion with k3.. non-zero has no Kalibr model: "
                    "opencv_dist holds (k1, k2, p1, p2, k3, ...) and no distortion_model is written."
                )
                body.append(f"  opencv_dist: {_yaml_row(dist)}")
        body.append(f"  resolution: [{int(camera['width'])}, {int(camera['height'])}]")
    else:
        notes.append("camera intrinsics not given: only the extrinsic is written.")
    body += ["  cam_overlaps: []", f"  rostopic: {rostopic}"]
    return "\n".join(out + [f"# {n}" for n in notes] + body) + "\n"


_EXPORTERS: dict[str, Callable[..., str]] = {
    "json": _export_json,
    "ros-tf": _export_ros_tf,
    "kitti": _export_kitti,
    "kalibr": _export_kalibr,
}
FORMATS: tuple[str, ...] = tuple(_EXPORTERS)


def export_calibration(cal: CalibrationLike, fmt: str, *, camera: Any = None, **options: Any) -> str:
    """The extrinsic as text in format ``fmt`` (one of ``FORMATS``).

    Parameters
    ----------
    cal : a ``Calibration``, a pair ``(T_cam_lidar as Pose3 or (4, 4), covariance (6, 6))``, or the
        path of a calibration.yaml.
    fmt : ``json`` | ``ros-tf`` | ``kitti`` | ``kalibr``.
    camera : the camera model (our config dict or a ``CameraModel``); tells the camera frame's axes
        (KITTI converts an equirectangular camera to OpenCV axes) and gives Kalibr its intrinsics.
    options : per format (see docs/exports.md):
        ros-tf: ``parent`` ("lidar" default | "camera"), ``lidar_frame`` ("lidar"),
        ``camera_frame`` ("camera", or "camera_optical" for pinhole/fisheye), ``ros`` ("both" |
        "ros1" | "ros2"); kitti: ``calib_time`` (datetime or text, default now, UTC);
        kalibr: ``rostopic``.

    Raises ``ValueError`` for an unknown format or option value, ``InputError`` for a bad file.
    """
    if fmt not in _EXPORTERS:
        raise ValueError(f"unknown export format {fmt!r}; expected one of {', '.join(FORMATS)}")
    exporter = _EXPORTERS[fmt]
    allowed = [
        name
        for name, p in inspect.signature(exporter).parameters.items()
        if p.kind is inspect.Parameter.KEYWORD_ONLY
    ]
    for name in options:
        if name not in allowed:
            raise ValueError(f"export format {fmt!r} has no option {name!r}; options: {allowed or 'none'}")
    T, cov = _as_T_cov(cal)
    return exporter(T, cov, _camera_dict(camera), **options)
