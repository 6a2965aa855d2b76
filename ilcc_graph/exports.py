"""Write the extrinsic in other tools' formats (JSON, ROS static tf, KITTI, Kalibr), and the LiDAR's
own errors the graph estimated (``lidar-offsets``, YAML or CSV).

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

from ilcc_graph.cameras import CameraModel, camera_class, make_camera
from ilcc_graph.errors import InputError
from ilcc_graph.handoff import check_covariance, check_rigid, invert_with_covariance
from ilcc_graph.types import Calibration, lidar_term_units, sigma_dict

CONVENTION = (
    "T_cam_lidar maps LiDAR-frame points to camera-frame points: p_cam = R @ p_lidar + t "
    "(metres). Covariances are 6x6 in GTSAM's Pose3 tangent convention for the named pose T: "
    "T_true = T * Pose3.Expmap(xi), xi = (rx, ry, rz, tx, ty, tz), rotation first, radians and "
    "metres. LiDAR frame: the sensor's own (x forward, y left, z up). Camera frame: the camera "
    "model's own: OpenCV's (z forward, x right, y down) for lens models (pinhole, fisheye, ...); "
    "x forward (image centre column), y left, z up for equirectangular cameras."
)

CalibrationLike = Calibration | tuple[gtsam.Pose3 | np.ndarray, np.ndarray] | str | Path


def _as_T_cov(
    cal: Calibration | tuple[gtsam.Pose3 | np.ndarray, np.ndarray | None],
) -> tuple[np.ndarray, np.ndarray | None]:
    """(4, 4) ``T_cam_lidar`` and (6, 6) covariance of a Calibration or a pair, checked; the
    covariance is None for a calibration that has none (the paper's refinement writes NaN)."""
    T: gtsam.Pose3 | np.ndarray
    cov: np.ndarray | None
    if isinstance(cal, Calibration):
        T, cov = cal.T_cam_lidar, cal.covariance
    else:
        T, cov = cal
    T = T.matrix() if isinstance(T, gtsam.Pose3) else T
    if cov is None or np.all(np.isnan(np.asarray(cov, dtype=np.float64))):
        return check_rigid(T, "T_cam_lidar"), None
    return check_rigid(T, "T_cam_lidar"), check_covariance(cov, "covariance")


def _camera(camera: Any) -> CameraModel | None:
    """The camera model from our config schema (a mapping) or a ``CameraModel``; None stays None.

    Raises ValueError for a mapping that is not a valid ``camera:`` section.
    """
    if camera is None or isinstance(camera, CameraModel):
        return camera
    if not isinstance(camera, Mapping):
        raise TypeError(f"camera: expected a dict or a CameraModel, got {type(camera).__name__}")
    d = dict(camera)
    if "model" not in d and "kind" in d:
        d["model"] = d.pop("kind")
    camera_class(d.get("model", ""))  # an unknown model: say so plainly
    return make_camera(d)


def calibration_camera(cal: Calibration) -> CameraModel | None:
    """The camera a calibration was estimated with: its ``camera`` section, with the refined
    intrinsics when the run refined them (``sensors["camera_intrinsics"]``); None when it holds none.

    Raises ValueError when the refined intrinsics do not belong to that camera.
    """
    camera = _camera(cal.camera)
    refined = (cal.sensors or {}).get("camera_intrinsics")
    return camera if camera is None or refined is None else refined_camera(camera, refined)


def refined_camera(camera: CameraModel, refined: Mapping[str, Any], where: str = "") -> CameraModel:
    """``camera`` with the intrinsics a run refined (``{names, values, ...}``, as
    ``Calibration.sensors["camera_intrinsics"]``); ValueError (prefixed by ``where``) when they are
    not that camera's."""
    if tuple(refined["names"]) != camera.intrinsic_names:
        raise ValueError(
            f"{where}the refined intrinsics ({', '.join(refined['names'])}) are not those of the "
            f"{camera.kind} camera ({', '.join(camera.intrinsic_names)})"
        )
    return camera.with_intrinsics(np.asarray(refined["values"], dtype=np.float64))


def _quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) with w >= 0 of a rotation matrix."""
    # gtsam's stub: Rot3's static method Quaternion() hides the class in toQuaternion's return type
    q = np.array(gtsam.Rot3(R).toQuaternion().coeffs(), dtype=np.float64)  # type: ignore[attr-defined]
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


def _export_json(T: np.ndarray, cov: np.ndarray | None, camera: CameraModel | None) -> str:
    T_inv, cov_inv = invert_with_covariance(T, np.eye(6) if cov is None else cov)
    doc = {
        "T_cam_lidar": T.tolist(),
        "T_lidar_cam": T_inv.matrix().tolist(),
        "covariance": None if cov is None else cov.tolist(),
        "covariance_T_lidar_cam": None if cov is None else cov_inv.tolist(),
        "sigma": None if cov is None else sigma_dict(cov),
        "sigma_T_lidar_cam": None if cov is None else sigma_dict(cov_inv),
        "quaternion_xyzw_cam_lidar": _quat_xyzw(T[:3, :3]).tolist(),
        "camera": None if camera is None else camera.to_dict(),
        "convention": CONVENTION,
    }
    return json.dumps(doc, indent=2, default=_jsonable) + "\n"


# ------------------------------------------------------------------------------------- ros-tf
def _export_ros_tf(
    T: np.ndarray,
    cov: np.ndarray | None,
    camera: CameraModel,
    *,
    parent: str = "lidar",
    lidar_frame: str = "lidar",
    camera_frame: str | None = None,
    ros: str = "both",
) -> str:
    if camera_frame is None:  # REP 103: an optical frame (z forward, x right, y down) is "<name>_optical"
        camera_frame = "camera_optical" if camera.optical else "camera"
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
    if camera.optical:
        axes = "OpenCV optical (z forward, x right, y down)"
    else:
        axes = f"{camera.axes} ({camera.kind})"
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
    camera: CameraModel,
    *,
    calib_time: _dt.datetime | str | None = None,
) -> str:
    T_out = T.copy()
    if camera.optical:
        frame = f"OpenCV camera frame (z forward, x right, y down) of the {camera.kind} camera"
    else:
        T_out[:3, :] = camera.R_opencv_cam @ T[:3, :]
        frame = (
            f"OpenCV axes (z forward, x right, y down), rotated from ilcc_graph's {camera.kind} "
            f"camera frame ({camera.axes})"
        )
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
    camera: CameraModel,
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
    fields, camera_notes = camera.kalibr()  # ValueError when Kalibr has no model for the camera
    notes += camera_notes
    for key, value in fields.items():
        body.append(f"  {key}: {value if isinstance(value, str) else _yaml_row(value)}")
    body.append(f"  resolution: [{int(camera.width)}, {int(camera.height)}]")
    body += ["  cam_overlaps: []", f"  rostopic: {rostopic}"]
    return "\n".join(out + [f"# {n}" for n in notes] + body) + "\n"


# ------------------------------------------------------------------------------ lidar-offsets
def _export_lidar_offsets(cal: Calibration, *, table: str = "yaml") -> str:
    """The LiDAR's own errors the graph estimated (a LiDAR intrinsic check): per beam its range
    offset with sigma (mm), the dark-print offset, and the terms left out with the reason."""
    if table not in ("yaml", "csv"):
        raise ValueError(f"table must be 'yaml' or 'csv', got {table!r}")
    lid = (cal.sensors or {}).get("lidar_errors")
    if lid is None:
        raise ValueError(
            "the calibration holds no LiDAR error terms (calibrate with --sensor-model beams to "
            "estimate them)"
        )
    elev = lid.get("elevation_deg", {})
    rows = []
    shown = {"m": "mm", "rad": "mrad"}
    for n, u, v, s in zip(lid["names"], lidar_term_units(lid), lid["values"], lid["sigmas"], strict=True):
        beam = int(n[n.index("[") + 1 : -1]) if "[" in n else None
        unit = shown.get(u, "")
        k = 1e3 if unit else 1.0
        rows.append((n, beam, elev.get(n), k * float(v), k * float(s), unit))
    if table == "csv":
        out = ["term,beam,elevation_deg,value,sigma,unit"]
        for n, beam, e, v, s, unit in rows:
            cells = (n, "" if beam is None else beam, "" if e is None else _num(e), _num(v), _num(s), unit)
            out.append(",".join(str(c) for c in cells))
        out += [f"# left out: {t}: {r}" for t, r in lid.get("left_out", [])]
        return "\n".join(out) + "\n"
    out = [
        "# LiDAR error terms estimated by ilcc_graph from the chessboard's returns, shared by all frames.",
        "# offset[b]: range offset of beam b (0 = lowest elevation), measured minus true range: subtract it",
        "# from the measured range to correct. dark: extra range of returns from black print (scaled by",
        "# the return's darkness, 0 white .. 1 black). Sigmas are one standard deviation.",
        "beams:",
    ]
    for n, beam, e, v, s, _ in rows:
        if beam is not None and n.startswith("offset"):
            el = "" if e is None else f", elevation_deg: {_num(e)}"
            out.append(f"  - {{beam: {beam}{el}, offset_mm: {_num(v)}, sigma_mm: {_num(s)}}}")
    if not any(b is not None and n.startswith("offset") for n, b, *_ in rows):
        out[-1] = "beams: []"
    for n, beam, _, v, s, unit in rows:
        if beam is None:
            key = f"{n}_{unit}" if unit else n
            out.append(f"{key}: {{value: {_num(v)}, sigma: {_num(s)}}}")
    elev_terms = [(n, b, v, s) for n, b, _, v, s, _ in rows if b is not None and n.startswith("elevation")]
    if elev_terms:
        out.append("elevation_errors:")
        out += [
            f"  - {{beam: {b}, value_mrad: {_num(v)}, sigma_mrad: {_num(s)}}}" for _, b, v, s in elev_terms
        ]
    left = lid.get("left_out", [])
    out.append("left_out:" if left else "left_out: []")
    out += [f"  - {{term: {json.dumps(str(t))}, reason: {json.dumps(str(r))}}}" for t, r in left]
    return "\n".join(out) + "\n"


_EXPORTERS: dict[str, Callable[..., str]] = {
    "json": _export_json,
    "ros-tf": _export_ros_tf,
    "kitti": _export_kitti,
    "kalibr": _export_kalibr,
}
#: formats that write the sensors' own errors rather than the extrinsic (they take the Calibration)
_SENSOR_EXPORTERS: dict[str, Callable[..., str]] = {"lidar-offsets": _export_lidar_offsets}
FORMATS: tuple[str, ...] = tuple(_EXPORTERS) + tuple(_SENSOR_EXPORTERS)
#: formats whose content depends on the camera model (its axes, its intrinsics): never written without it
NEEDS_CAMERA: tuple[str, ...] = ("ros-tf", "kitti", "kalibr")


def export_calibration(cal: CalibrationLike, fmt: str, *, camera: Any = None, **options: Any) -> str:
    """The extrinsic as text in format ``fmt`` (one of ``FORMATS``).

    Parameters
    ----------
    cal : a ``Calibration``, a pair ``(T_cam_lidar as Pose3 or (4, 4), covariance (6, 6))``, or the
        path of a calibration.yaml.
    fmt : ``json`` | ``ros-tf`` | ``kitti`` | ``kalibr`` | ``lidar-offsets`` (the LiDAR's own
        errors of a calibration with ``--lidar-errors``; needs a ``Calibration`` or a path).
    camera : the camera model (our config dict or a ``CameraModel``); tells the camera frame's axes
        (KITTI converts a camera without OpenCV axes, e.g. equirectangular, to OpenCV axes) and
        gives Kalibr its intrinsics (``CameraModel.kalibr``). Default: the calibration's own
        (``calibration_camera``: calibration.yaml's ``camera``, or ``config.resolved.yaml`` beside
        it, with the intrinsics as refined when they were). ``ros-tf``, ``kitti`` and ``kalibr``
        are never written without one (``NEEDS_CAMERA``).
    options : per format (see docs/exports.md):
        ros-tf: ``parent`` ("lidar" default | "camera"), ``lidar_frame`` ("lidar"),
        ``camera_frame`` ("camera_optical" for a camera with OpenCV axes, "camera" else: REP 103),
        ``ros`` ("both" | "ros1" | "ros2"); kitti: ``calib_time`` (datetime or text, default now,
        UTC); kalibr: ``rostopic``; lidar-offsets: ``table`` ("yaml" default | "csv").

    Raises ``ValueError`` for an unknown format or option value, a format that needs the camera
    model without one, a camera Kalibr cannot hold; ``InputError`` for a bad file.
    """
    if fmt not in FORMATS:
        raise ValueError(f"unknown export format {fmt!r}; expected one of {', '.join(FORMATS)}")
    exporter = _EXPORTERS.get(fmt) or _SENSOR_EXPORTERS[fmt]
    allowed = [
        name
        for name, p in inspect.signature(exporter).parameters.items()
        if p.kind is inspect.Parameter.KEYWORD_ONLY
    ]
    for name in options:
        if name not in allowed:
            raise ValueError(f"export format {fmt!r} has no option {name!r}; options: {allowed or 'none'}")
    if isinstance(cal, (str, Path)):
        from ilcc_graph.io.stored import read_stored

        stored = read_stored(cal)
        if not isinstance(stored, Calibration):
            raise InputError(f"{cal}: a rig's calibration: export it with exports_rig.export_rig")
        cal = stored
    if fmt in _SENSOR_EXPORTERS:
        if not isinstance(cal, Calibration):
            raise ValueError(f"export format {fmt!r} needs a Calibration or a calibration.yaml")
        return exporter(cal, **options)
    T, cov = _as_T_cov(cal)
    cam = _camera(camera)
    if cam is None and isinstance(cal, Calibration):
        cam = calibration_camera(cal)
    if cam is None and fmt in NEEDS_CAMERA:
        raise ValueError(
            f"the {fmt} export needs the camera model (which axes its frame has"
            + (", its intrinsics" if fmt == "kalibr" else "")
            + "), and the calibration holds none: pass camera= (a config.yaml camera section), or add "
            "the data set's `camera:` section to calibration.yaml"
        )
    return exporter(T, cov, cam, **options)
