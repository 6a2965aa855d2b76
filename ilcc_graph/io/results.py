"""``calibration.yaml`` and ``ground_truth.yaml`` (interface.md, "What a calibration writes").

calibration.yaml keys, in order: ``T_cam_lidar`` (4x4), ``covariance`` (6x6, GTSAM Pose3 tangent
of T_cam_lidar, rotation first), ``sigma`` (square roots of the covariance diagonal in degrees and
millimetres), ``frames`` (per frame: ``name``, ``used``, ``reason`` when dropped, ``damaged: true``
when a file of the frame could not be read,
``lidar_corners`` (K,3) LiDAR frame metres, ``image_corners`` (K,2) pixels,
``rms_bearing_error_mrad``, then ``T_lidar_board`` (4x4, the LiDAR stage's) and
``T_lidar_board_refined`` (4x4, the estimation core's) when known), then ``method``,
``diagnostics``, ``camera`` (the camera model in our config schema, so that exports need nothing
else) and ``sensor_errors`` (``model``: the sensor model chosen, how, and each candidate's
held-out score and weight; when the graph estimated the sensors' own errors, ``lidar``: per term
its value and sigma, mm for range terms, and the terms left out with the reason;
``camera_intrinsics``: stated, refined, sigma; ``effect_on_extrinsic``: what each group moved the
extrinsic). With the LiDAR's errors estimated, ``lidar_corners`` are the refined board's corners
(``lidar_corners_stage`` the LiDAR stage's).

Reading it back gives a ``Calibration`` whose frames carry minimal ``BoardFit`` /
``ImageCorners``: what the file stores (corners, T_lidar_board) is filled in; the rest (segment
points, bearings, covariances) is not stored and is empty or NaN.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..types import BoardFit, Calibration, FrameResult, ImageCorners, PoseTerms, lidar_term_units, sigma_dict
from .files import read_yaml, write_yaml

__all__ = [
    "write_calibration",
    "read_calibration",
    "read_calibration_with_camera",
    "calibration_from_doc",
    "calibration_to_dict",
    "refined_corners",
    "intrinsics_doc",
    "intrinsics_from_doc",
    "pose_terms_doc",
    "pose_terms_from_doc",
    "GroundTruth",
    "write_ground_truth",
    "read_ground_truth",
]

GROUND_TRUTH_FILE = "ground_truth.yaml"


def refined_corners(f: FrameResult) -> np.ndarray | None:
    """(K, 3) the board's inner corners at the pose the estimation core settled on
    (``T_lidar_board_refined``), LiDAR frame, metres; None without a board or a refined pose."""
    if f.board is None or f.T_lidar_board_refined is None:
        return None
    T0, T1 = np.asarray(f.board.T_lidar_board, np.float64), np.asarray(f.T_lidar_board_refined, np.float64)
    c = np.asarray(f.board.corners_lidar, dtype=np.float64)
    if not (np.all(np.isfinite(T0)) and np.all(np.isfinite(T1))):
        return None
    T = T1 @ np.linalg.inv(T0)  # the stage's corners carried onto the refined board
    return c @ T[:3, :3].T + T[:3, 3]


def _frame_dict(f: FrameResult, refined: bool = False) -> dict[str, Any]:
    d: dict[str, Any] = {"name": str(f.name), "used": bool(f.used)}
    if f.reason is not None or not f.used:
        d["reason"] = f.reason or "not used"
    if f.damaged:
        d["damaged"] = True
    corners = refined_corners(f) if refined else None
    if corners is not None:
        d["lidar_corners"] = corners
        d["lidar_corners_stage"] = np.asarray(f.board.corners_lidar, dtype=np.float64)  # type: ignore[union-attr]
    elif f.board is not None:
        d["lidar_corners"] = np.asarray(f.board.corners_lidar, dtype=np.float64)
    if f.corners is not None:
        d["image_corners"] = np.asarray(f.corners.uv, dtype=np.float64)
    d["rms_bearing_error_mrad"] = (
        None if f.rms_bearing_error_mrad is None else float(f.rms_bearing_error_mrad)
    )
    if f.board is not None:
        d["T_lidar_board"] = np.asarray(f.board.T_lidar_board, dtype=np.float64)
    if f.T_lidar_board_refined is not None:
        d["T_lidar_board_refined"] = np.asarray(f.T_lidar_board_refined, dtype=np.float64)
    return d


def calibration_to_dict(cal: Calibration) -> dict[str, Any]:
    """The calibration.yaml content as plain data (numpy arrays left for the YAML writer).

    With the LiDAR's own errors estimated, ``lidar_corners`` are the corners of the board the
    estimation core settled on (its returns corrected by the calibrated beams, its in-plane pose
    from the intensity fit and the image), and ``lidar_corners_stage`` the LiDAR stage's own.
    """
    refined = bool(cal.sensors.get("lidar_errors", {}).get("names"))
    return {
        "T_cam_lidar": np.asarray(cal.T_cam_lidar, dtype=np.float64),
        "covariance": np.asarray(cal.covariance, dtype=np.float64),
        "sigma": sigma_dict(cal.covariance),
        "frames": [_frame_dict(f, refined) for f in cal.frames],
        "method": cal.method,
        "diagnostics": {str(k): v for k, v in cal.diagnostics.items()},
        **({"camera": cal.camera} if cal.camera is not None else {}),
        **({"sensor_errors": _sensors_dict(cal.sensors, cal.with_terms)} if cal.sensors else {}),
    }


def _sensors_dict(sensors: dict[str, Any], with_terms: PoseTerms | None = None) -> dict[str, Any]:
    """``sensor_errors`` of calibration.yaml: per term its value and sigma (mm for range terms, mrad
    for elevations, each term's unit as the solve gives it), and ``extrinsic_with_lidar_terms``."""
    out: dict[str, Any] = {}
    if sensors.get("model"):  # the sensor model chosen and the evidence (estimation.selection)
        out["model"] = sensors["model"]
    lid = sensors.get("lidar_errors")
    if lid is not None:
        terms = {}
        units = lidar_term_units(lid)
        for n, u, v, s in zip(lid["names"], units, lid["values"], lid["sigmas"], strict=True):
            if u == "m":
                terms[n] = {"value_mm": 1e3 * float(v), "sigma_mm": 1e3 * float(s)}
            elif u == "rad":
                terms[n] = {"value_mrad": 1e3 * float(v), "sigma_mrad": 1e3 * float(s)}
            else:
                terms[n] = {"value": float(v), "sigma": float(s)}
            if n in lid.get("elevation_deg", {}):
                terms[n]["elevation_deg"] = float(lid["elevation_deg"][n])
        out["lidar"] = {"terms": terms, "left_out": [{"term": t, "reason": r} for t, r in lid["left_out"]]}
        bp = lid.get("board_plane")
        if bp is not None:  # each board's own plane: sigmas used (estimated or configured)
            out["lidar"]["board_plane"] = {
                "offset_mm": 1e3 * float(bp["offset_m"]),
                "offset_sd_mm": 1e3 * float(bp["offset_sd"]),
                "tilt_deg": math.degrees(float(bp["tilt_rad"])),
                "tilt_sd_deg": math.degrees(float(bp["tilt_sd"])),
                "estimated": bool(bp["estimated"]),
                "note": str(bp["note"]),
            }
            if math.isfinite(float(bp.get("beam_m", math.nan))):  # each beam's offset on a board
                out["lidar"]["board_plane"]["beam_mm"] = 1e3 * float(bp["beam_m"])
                out["lidar"]["board_plane"]["beam_sd_mm"] = 1e3 * float(bp["beam_sd"])
    cam = sensors.get("camera_intrinsics")
    if cam is not None:
        out["camera_intrinsics"] = intrinsics_doc(cam)
    if sensors.get("effects"):
        out["effect_on_extrinsic"] = {
            k: {n: float(x) for n, x in v.items()} for k, v in sensors["effects"].items()
        }
    if with_terms is not None:
        out["extrinsic_with_lidar_terms"] = pose_terms_doc(with_terms)
    return out


def intrinsics_doc(entry: dict[str, Any]) -> dict[str, dict[str, float]]:
    """A camera's refined intrinsics as a file holds them, ``{name: {stated, refined, sigma}}`` (the
    config's units: pixels, or none), from ``{names, stated, values, sigmas}``
    (``Calibration.sensors["camera_intrinsics"]``)."""
    return {
        str(n): {"stated": float(a), "refined": float(v), "sigma": float(s)}
        for n, a, v, s in zip(entry["names"], entry["stated"], entry["values"], entry["sigmas"], strict=True)
    }


def intrinsics_from_doc(doc: dict[str, Any]) -> dict[str, Any]:
    """``{names, stated, values, sigmas}`` from the file's ``{name: {stated, refined, sigma}}``
    (``intrinsics_doc``); KeyError, TypeError or ValueError when malformed."""
    return {
        "names": [str(n) for n in doc],
        "stated": np.array([float(t["stated"]) for t in doc.values()]),
        "values": np.array([float(t["refined"]) for t in doc.values()]),
        "sigmas": np.array([float(t["sigma"]) for t in doc.values()]),
    }


def pose_terms_doc(t: PoseTerms) -> dict[str, Any]:
    """A pose with the LiDAR's range terms as a file holds it (the pose itself stored beside it): SI
    units as the solve has them; the covariance's rows rx .. tz, then the terms."""
    return {
        "terms": list(t.terms),
        "units": list(t.units),
        "values": [float(x) for x in t.values],
        "covariance": np.asarray(t.covariance, dtype=np.float64),
    }


def pose_terms_from_doc(
    src: str, T: np.ndarray, d: Any, where: str = "sensor_errors.extrinsic_with_lidar_terms"
) -> PoseTerms | None:
    """The ``PoseTerms`` of pose ``T`` from what ``pose_terms_doc`` wrote at key ``where`` (None when
    absent); InputError naming the file and the key when it is malformed (``io.stored`` checks its
    covariance)."""
    if d is None:
        return None
    if not isinstance(d, dict) or not {"terms", "units", "values", "covariance"} <= set(d):
        raise InputError(f"{src}: {where} must be a mapping with terms, units, values and covariance")
    terms, units = tuple(str(t) for t in d["terms"]), tuple(str(u) for u in d["units"])
    k = len(terms)
    values = _matrix(src, [d["values"]], f"{where}.values", (1, k))[0]
    C = _matrix(src, d["covariance"], f"{where}.covariance", (6 + k, 6 + k))
    if len(units) != k or k == 0:
        raise InputError(f"{src}: {where}: {k} terms but {len(units)} units")
    return PoseTerms(T, terms, units, values, C)


def _sensors_from_dict(src: str, d: Any) -> dict[str, Any]:
    """``Calibration.sensors`` from calibration.yaml's ``sensor_errors`` (SI units, as written)."""
    if d is None:
        return {}
    if not isinstance(d, dict):
        raise InputError(f"{src}: sensor_errors must be a mapping")
    out: dict[str, Any] = {}
    try:
        if d.get("model") is not None:
            if not isinstance(d["model"], dict) or "chosen" not in d["model"]:
                raise InputError(f"{src}: sensor_errors.model must be a mapping with 'chosen'")
            out["model"] = d["model"]
        lid = d.get("lidar")
        if lid is not None:
            names, units, values, sigmas, elev = [], [], [], [], {}
            for n, t in (lid.get("terms") or {}).items():
                if "value_mm" in t:
                    v, s, u = 1e-3 * float(t["value_mm"]), 1e-3 * float(t["sigma_mm"]), "m"
                elif "value_mrad" in t:
                    v, s, u = 1e-3 * float(t["value_mrad"]), 1e-3 * float(t["sigma_mrad"]), "rad"
                else:
                    v, s, u = float(t["value"]), float(t["sigma"]), "1"
                names.append(str(n))
                units.append(u)
                values.append(v)
                sigmas.append(s)
                if "elevation_deg" in t:
                    elev[str(n)] = float(t["elevation_deg"])
            out["lidar_errors"] = {
                "names": names, "units": units, "values": np.array(values), "sigmas": np.array(sigmas),
                "left_out": [[str(x["term"]), str(x["reason"])] for x in lid.get("left_out") or []],
                **({"elevation_deg": elev} if elev else {}),
            }  # fmt: skip
            bp = lid.get("board_plane")
            if bp is not None:
                out["lidar_errors"]["board_plane"] = {
                    "offset_m": 1e-3 * float(bp["offset_mm"]),
                    "offset_sd": 1e-3 * float(bp["offset_sd_mm"]),
                    "tilt_rad": math.radians(float(bp["tilt_deg"])),
                    "tilt_sd": math.radians(float(bp["tilt_sd_deg"])),
                    "estimated": bool(bp["estimated"]),
                    "note": str(bp["note"]),
                    "beam_m": 1e-3 * float(bp.get("beam_mm", math.nan)),
                    "beam_sd": 1e-3 * float(bp.get("beam_sd_mm", math.nan)),
                }
        cam = d.get("camera_intrinsics")
        if cam is not None:
            out["camera_intrinsics"] = intrinsics_from_doc(cam)
        if d.get("effect_on_extrinsic"):
            out["effects"] = {
                str(k): {str(n): float(x) for n, x in v.items()} for k, v in d["effect_on_extrinsic"].items()
            }
    except (AttributeError, KeyError, TypeError, ValueError) as err:
        raise InputError(f"{src}: sensor_errors is malformed ({err!r})") from None
    return out


def write_calibration(path: str | Path, cal: Calibration) -> Path:
    """Write ``calibration.yaml`` atomically (layout in interface.md)."""
    return write_yaml(path, calibration_to_dict(cal))


def _matrix(src: str, v: Any, key: str, shape: tuple[int, ...], pose: bool = False) -> np.ndarray:
    try:
        m = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{src}: {key} is not a numeric matrix") from None
    if m.shape != shape and not (
        len(shape) == 2 and shape[0] == -1 and m.ndim == 2 and m.shape[1] == shape[1]
    ):
        if len(shape) == 2 and shape[0] == -1 and m.size == 0:
            return np.zeros((0, shape[1]))
        expected = "(" + ", ".join("K" if n == -1 else str(n) for n in shape) + ")"
        raise InputError(f"{src}: {key} has shape {m.shape}, expected {expected}")
    if pose:
        if not np.all(np.isfinite(m)):
            raise InputError(f"{src}: {key} has non-finite entries")
        R = m[:3, :3]
        if (
            not np.allclose(m[3], [0, 0, 0, 1])
            or not np.allclose(R.T @ R, np.eye(3), atol=1e-6)
            or np.linalg.det(R) < 0
        ):
            raise InputError(f"{src}: {key} is not a rigid transform (rotation block or last row wrong)")
    return m


def read_calibration(path: str | Path) -> Calibration:
    """Read ``calibration.yaml`` written by :func:`write_calibration` (InputError on bad content; its
    covariance is validated by ``io.stored.read_stored``, the commands' reader)."""
    p = Path(path)
    return calibration_from_doc(read_yaml(p, "calibration file"), str(p))


def calibration_from_doc(d: Any, src: str = "calibration.yaml") -> Calibration:
    """The ``Calibration`` of a calibration.yaml's content; InputError naming ``src`` and the key."""
    if not isinstance(d, dict):
        raise InputError(f"{src}: expected a mapping with T_cam_lidar, covariance, frames")
    for k in ("T_cam_lidar", "covariance", "frames"):
        if k not in d:
            raise InputError(f"{src}: missing key {k!r}")
    T = _matrix(src, d["T_cam_lidar"], "T_cam_lidar", (4, 4), pose=True)
    cov = _matrix(src, d["covariance"], "covariance", (6, 6))
    if not isinstance(d["frames"], list):
        raise InputError(f"{src}: frames must be a list")
    frames = []
    for i, fd in enumerate(d["frames"]):
        key = f"frames[{i}]"
        if not isinstance(fd, dict) or "name" not in fd or "used" not in fd:
            raise InputError(f"{src}: {key} must be a mapping with name and used")
        board = None
        if fd.get("lidar_corners") is not None:
            # the BoardFit is the LiDAR stage's: its own corners when the file also has refined ones
            which = "lidar_corners_stage" if fd.get("lidar_corners_stage") is not None else "lidar_corners"
            corners = _matrix(src, fd[which], f"{key}.{which}", (-1, 3))
            Tb = (
                _matrix(src, fd["T_lidar_board"], f"{key}.T_lidar_board", (4, 4), pose=True)
                if fd.get("T_lidar_board") is not None
                else np.full((4, 4), np.nan)
            )
            board = BoardFit(
                T_lidar_board=Tb,
                covariance=np.full((6, 6), np.nan),
                corners_lidar=corners,
                points_lidar=np.zeros((0, 3)),
                intensity=np.zeros(0),
                half_turn_ambiguous=False,
            )
        img = None
        if fd.get("image_corners") is not None:
            uv = _matrix(src, fd["image_corners"], f"{key}.image_corners", (-1, 2))
            k = uv.shape[0]
            img = ImageCorners(
                uv=uv,
                bearings=np.full((k, 3), np.nan),
                cov_px=np.full((k, 2, 2), np.nan),
                half_turn_ambiguous=False,
            )
        rms = fd.get("rms_bearing_error_mrad")
        refined = (
            None
            if fd.get("T_lidar_board_refined") is None
            else _matrix(src, fd["T_lidar_board_refined"], f"{key}.T_lidar_board_refined", (4, 4), pose=True)
        )
        frames.append(
            FrameResult(
                name=str(fd["name"]),
                used=bool(fd["used"]),
                reason=fd.get("reason"),
                board=board,
                corners=img,
                rms_bearing_error_mrad=None if rms is None else float(rms),
                T_lidar_board_refined=refined,
                damaged=bool(fd.get("damaged", False)),
            )
        )
    diag = d.get("diagnostics") or {}
    if not isinstance(diag, dict):
        raise InputError(f"{src}: diagnostics must be a mapping")
    camera = d.get("camera")
    if camera is not None and not isinstance(camera, dict):
        raise InputError(f"{src}: camera must be a mapping (the camera section of config.yaml)")
    errors = d.get("sensor_errors")
    terms = errors.get("extrinsic_with_lidar_terms") if isinstance(errors, dict) else None
    return Calibration(
        T_cam_lidar=T,
        covariance=cov,
        frames=tuple(frames),
        method=str(d.get("method", "graph")),
        diagnostics=dict(diag),
        camera=camera,
        sensors=_sensors_from_dict(src, d.get("sensor_errors")),
        with_terms=pose_terms_from_doc(src, T, terms),
    )


@dataclass(frozen=True)
class GroundTruth:
    """A simulated data set's truth: ``T_cam_lidar`` (4,4), ``T_lidar_board`` per frame stem
    (4,4) with ``p_lidar = T_lidar_board @ p_board``, and any further keys in ``extra``."""

    T_cam_lidar: np.ndarray
    T_lidar_board: dict[str, np.ndarray]
    extra: dict[str, Any] = field(default_factory=dict)


def read_calibration_with_camera(path: str | Path) -> Calibration:
    """``read_calibration``, with the camera from ``config.resolved.yaml`` beside the file when the file
    has none (calibration.yaml of older versions), as ``export`` needs it."""
    cal = read_calibration(path)
    resolved = Path(path).parent / "config.resolved.yaml"
    if cal.camera is None and resolved.is_file():
        doc = read_yaml(resolved)
        camera = doc.get("camera") if isinstance(doc, dict) else None
        if camera is not None:
            cal = dataclasses.replace(cal, camera=camera)
    return cal


def write_ground_truth(
    path: str | Path,
    T_cam_lidar: np.ndarray,
    T_lidar_board: dict[str, np.ndarray],
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write ``ground_truth.yaml`` (T_cam_lidar, T_lidar_board {stem: 4x4}, then ``extra``'s keys).

    path: the file, or a data folder (then ``<folder>/ground_truth.yaml``).
    """
    p = Path(path)
    if p.suffix.lower() not in (".yaml", ".yml"):
        p = p / GROUND_TRUTH_FILE
    extra = dict(extra or {})
    clash = {"T_cam_lidar", "T_lidar_board"} & extra.keys()
    if clash:
        raise ValueError(f"extra must not repeat {sorted(clash)}")
    obj = {
        "T_cam_lidar": np.asarray(T_cam_lidar, dtype=np.float64),
        "T_lidar_board": {str(k): np.asarray(v, dtype=np.float64) for k, v in T_lidar_board.items()},
    }
    obj.update(extra)
    return write_yaml(p, obj)


def read_ground_truth(data_dir: str | Path) -> GroundTruth:
    """Read ``<data_dir>/ground_truth.yaml`` (or the file itself). InputError if absent or malformed."""
    p = Path(data_dir)
    if p.is_dir():
        p = p / GROUND_TRUTH_FILE
    src = str(p)
    d = read_yaml(p)
    if not isinstance(d, dict) or "T_cam_lidar" not in d:
        raise InputError(f"{src}: expected a mapping with T_cam_lidar and T_lidar_board")
    T = _matrix(src, d["T_cam_lidar"], "T_cam_lidar", (4, 4), pose=True)
    tb = d.get("T_lidar_board") or {}
    if not isinstance(tb, dict):
        raise InputError(f"{src}: T_lidar_board must map frame stems to 4x4 matrices")
    boards = {str(k): _matrix(src, v, f"T_lidar_board.{k}", (4, 4), pose=True) for k, v in tb.items()}
    extra = {k: v for k, v in d.items() if k not in ("T_cam_lidar", "T_lidar_board")}
    return GroundTruth(T, boards, extra)
