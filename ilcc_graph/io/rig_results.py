"""A rig's ``calibration.yaml`` (docs/rig.md, "A rig's calibration.yaml"): every sensor's pose in the
reference frame, their joint covariance, every pair's relative pose with its own, what was used.

Frames and covariances as interface.md's: ``T_ref_sensor`` maps a sensor's points into the
reference's frame (metres); covariances are right-tangent (``T_true = T_est Exp(xi)``), rotation
first, rad and m. The file is plain data; the math that makes pairs from the joint covariance is
the caller's (``estimation.rig_solve.between``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ilcc_graph.errors import InputError, quote
from ilcc_graph.io.files import read_yaml, write_yaml
from ilcc_graph.io.results import intrinsics_from_doc, pose_terms_doc, pose_terms_from_doc
from ilcc_graph.types import PoseTerms, sigma_dict

__all__ = [
    "KIND",
    "RigCalibration",
    "is_rig_calibration",
    "read_rig_calibration",
    "rig_calibration_doc",
    "rig_calibration_from_doc",
    "write_rig_calibration",
]

#: the ``kind`` key of a rig's calibration.yaml (a single pair's has none)
KIND = "rig-calibration"
#: the key of the cameras' poses with the base LiDAR's range terms (``RigCalibration.with_terms``): a
#: list of mappings, one per camera (a file of an earlier version: one mapping, the first camera's)
WITH_TERMS = "extrinsic_with_lidar_terms"


@dataclass(frozen=True)
class RigCalibration:
    """A rig's calibration as stored.

    sensors: names in the covariance's order; reference: the frame of the poses; T_ref_sensor:
    {sensor: (4, 4)}; covariance: (6N, 6N) joint (the reference's block zero). pairs: {(a, b): (T_a_b
    (4, 4), covariance (6, 6))}. rig: the rig's config as rig.yaml's mapping (cameras' intrinsics,
    board), or None. extra: what was used and other numbers (``moments``, ``unsolved``, ...).
    with_terms: per camera (camera, LiDAR, ``T_camera_lidar`` with the LiDAR's range terms): each
    camera and the base LiDAR as a pair's ``Calibration.with_terms`` (verify nets the terms out).
    """

    sensors: tuple[str, ...]
    reference: str
    T_ref_sensor: dict[str, np.ndarray]
    covariance: np.ndarray
    pairs: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    rig: dict[str, Any] | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    with_terms: tuple[tuple[str, str, PoseTerms], ...] = ()

    def block(self, sensor: str) -> np.ndarray:
        """(6, 6) the covariance of ``sensor``'s pose."""
        k = self.sensors.index(sensor)
        return self.covariance[6 * k : 6 * k + 6, 6 * k : 6 * k + 6]

    def refined_intrinsics(self) -> dict[str, dict[str, Any]]:
        """{camera: its intrinsics the run refined, ``{names, stated, values, sigmas}``
        (``results.intrinsics_from_doc``; ``cameras.RefinedIntrinsics.from_entry`` types it)} from
        ``extra["camera_intrinsics"]``; empty when it refined none. KeyError, TypeError, ValueError or
        AttributeError when malformed."""
        stored = self.extra.get("camera_intrinsics") or {}
        return {str(c): intrinsics_from_doc(d) for c, d in stored.items()}


def rig_calibration_doc(cal: RigCalibration) -> dict[str, Any]:
    """The file's content as plain data (the sigmas in deg and mm added for people)."""
    return {
        "kind": KIND,
        "reference": cal.reference,
        "sensors": list(cal.sensors),
        "T_ref_sensor": {s: cal.T_ref_sensor[s] for s in cal.sensors},
        "sigmas": {s: sigma_dict(cal.block(s)) for s in cal.sensors if s != cal.reference},
        "covariance": cal.covariance,
        "pairs": {
            f"{a}/{b}": {"T_a_b": T, "covariance": C, "sigmas": sigma_dict(C)}
            for (a, b), (T, C) in cal.pairs.items()
        },
        **({"rig": cal.rig} if cal.rig is not None else {}),
        **cal.extra,
        **({WITH_TERMS: [_with_terms_doc(w) for w in cal.with_terms]} if cal.with_terms else {}),
    }


def _with_terms_doc(w: tuple[str, str, PoseTerms]) -> dict[str, Any]:
    camera, lidar, terms = w
    return {"camera": camera, "lidar": lidar, **pose_terms_doc(terms)}


def _with_terms(
    src: str, d: Any, T_ref_sensor: dict[str, np.ndarray]
) -> tuple[tuple[str, str, PoseTerms], ...]:
    """``RigCalibration.with_terms`` from the file's ``extrinsic_with_lidar_terms`` (a list, or an
    earlier version's one mapping; each pose from the two sensors' poses), empty when absent;
    InputError naming the file and the key otherwise."""
    if d is None:
        return ()
    out, keys = [], ("camera", "lidar")
    for k, e in enumerate(d if isinstance(d, list) else [d]):
        where = WITH_TERMS if isinstance(d, dict) else f"{WITH_TERMS}[{k}]"
        named = isinstance(e, dict) and all(isinstance(e.get(x), str) and e[x] in T_ref_sensor for x in keys)
        if not named:
            raise InputError(f"{src}: {where} must name a camera and a LiDAR of the rig's sensors")
        camera, lidar = str(e["camera"]), str(e["lidar"])
        T = np.linalg.solve(T_ref_sensor[camera], T_ref_sensor[lidar])  # T_camera_lidar
        terms = pose_terms_from_doc(src, T, e, where)
        if terms is not None:
            out.append((camera, lidar, terms))
    return tuple(out)


def write_rig_calibration(path: str | Path, cal: RigCalibration) -> Path:
    """``path`` (a file) written atomically (:func:`rig_calibration_doc`)."""
    return write_yaml(Path(path), rig_calibration_doc(cal))


def is_rig_calibration(path: str | Path) -> bool:
    """True when ``path`` is a rig's calibration.yaml (its ``kind``)."""
    try:
        d = read_yaml(Path(path))
    except (InputError, OSError):
        return False
    return isinstance(d, dict) and d.get("kind") == KIND


def _matrix(src: str, v: Any, key: str, shape: tuple[int, int]) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{src}: {key}: expected a {shape[0]}x{shape[1]} matrix of numbers") from None
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise InputError(f"{src}: {key}: expected a finite {shape[0]}x{shape[1]} matrix, got shape {a.shape}")
    return a


def read_rig_calibration(path: str | Path) -> RigCalibration:
    """Read what :func:`write_rig_calibration` wrote; InputError naming the file and key otherwise."""
    return rig_calibration_from_doc(read_yaml(Path(path)), str(path))


def rig_calibration_from_doc(d: Any, src: str = "calibration.yaml") -> RigCalibration:
    """The ``RigCalibration`` of a file's content (:func:`rig_calibration_doc`); InputError naming
    ``src`` and the key when it is not one."""
    if not isinstance(d, dict) or d.get("kind") != KIND:
        raise InputError(f"{src}: not a rig calibration (expected kind: {KIND})")
    for k in ("reference", "sensors", "T_ref_sensor", "covariance"):
        if k not in d:
            raise InputError(f"{src}: missing key {k!r}")
    sensors = d["sensors"]
    if (
        not isinstance(sensors, list)
        or not all(isinstance(s, str) for s in sensors)
        or d["reference"] not in sensors
    ):
        raise InputError(
            f"{src}: sensors must be a list of names holding the reference {quote(d['reference'])}"
        )
    if not isinstance(d["T_ref_sensor"], dict) or set(d["T_ref_sensor"]) != set(sensors):
        raise InputError(f"{src}: T_ref_sensor must give a 4x4 pose for every sensor of {quote(sensors)}")
    T = {s: _matrix(src, d["T_ref_sensor"][s], f"T_ref_sensor.{s}", (4, 4)) for s in sensors}
    n = 6 * len(sensors)
    C = _matrix(src, d["covariance"], "covariance", (n, n))
    pairs = {}
    for key, p in (d.get("pairs") or {}).items():
        a, _, b = str(key).partition("/")
        if not isinstance(p, dict) or a not in sensors or b not in sensors:
            raise InputError(f"{src}: pairs.{key}: expected <sensor>/<sensor> with T_a_b and covariance")
        pairs[(a, b)] = (
            _matrix(src, p.get("T_a_b"), f"pairs.{key}.T_a_b", (4, 4)),
            _matrix(src, p.get("covariance"), f"pairs.{key}.covariance", (6, 6)),
        )
    known = {"kind", "reference", "sensors", "T_ref_sensor", "sigmas", "covariance", "pairs", "rig"}
    known.add(WITH_TERMS)
    extra = {k: v for k, v in d.items() if k not in known}
    with_terms = _with_terms(src, d.get(WITH_TERMS), T)
    return RigCalibration(tuple(sensors), d["reference"], T, C, pairs, d.get("rig"), extra, with_terms)
