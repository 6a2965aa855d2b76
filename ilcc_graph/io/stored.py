"""The one reader of a stored calibration, a single pair's or a rig's ``calibration.yaml``, and its one
validation (issue 36): ``verify``, ``export``, ``evaluate`` and the GTSAM hand-off read it here.

``read_stored(path)`` -> ``Calibration`` (a pair; its camera from ``config.resolved.yaml`` beside it
when the file has none) or ``RigCalibration`` (``kind: rig-calibration``), validated: every pose rigid,
every covariance symmetric and positive definite (a rig's joint one on the sensors other than the
reference, whose block is zero; a pair's may be all NaN: a method that gives none). ``stored_setup``:
the board and each sensor's kind (``lidar`` or the camera model) the calibration was made with, where
the file or ``config.resolved.yaml`` beside it says.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..types import Calibration
from .files import read_yaml
from .results import calibration_from_doc
from .rig_results import KIND, WITH_TERMS, RigCalibration, rig_calibration_from_doc

__all__ = ["StoredSetup", "covariance_problem", "pose_problem", "read_stored", "stored_setup"]

#: largest relative asymmetry ``max|C - C^T| / max|C|`` of a stored covariance (the writer's are exact)
SYMMETRY_TOL = 1e-9
RESOLVED = "config.resolved.yaml"


def covariance_problem(C: np.ndarray) -> str | None:
    """What is wrong with the covariance ``C`` (square): non-finite, not symmetric, not positive
    definite (its smallest eigenvalue); None when it is a covariance."""
    C = np.asarray(C, dtype=np.float64)
    if not np.all(np.isfinite(C)):
        return "has non-finite entries"
    scale = max(float(np.max(np.abs(C))), np.finfo(float).tiny)
    asym = float(np.max(np.abs(C - C.T))) / scale
    if asym > SYMMETRY_TOL:
        return f"is not symmetric (max relative |C - C^T| = {asym:.3g})"
    try:
        np.linalg.cholesky(0.5 * (C + C.T))
    except np.linalg.LinAlgError:
        eig = np.linalg.eigvalsh(0.5 * (C + C.T))
        return f"is not positive definite (smallest eigenvalue {eig[0]:.3g})"
    return None


def pose_problem(T: np.ndarray) -> str | None:
    """What keeps the 4x4 ``T`` from being a rigid transform, or None."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return "is not a finite 4x4 matrix"
    R = T[:3, :3]
    if (
        not np.allclose(T[3], [0, 0, 0, 1])
        or not np.allclose(R.T @ R, np.eye(3), atol=1e-6)
        or np.linalg.det(R) < 0
    ):
        return "is not a rigid transform (rotation block or last row wrong)"
    return None


def _check_pair(src: str, cal: Calibration) -> None:
    C = np.asarray(cal.covariance, dtype=np.float64)
    if np.all(np.isnan(C)):
        return  # no covariance (the paper's method): the consumers that need one say so
    problem = covariance_problem(C)
    if problem is not None:
        raise InputError(f"{src}: covariance {problem}; not a covariance this tool writes: calibrate again")
    if cal.with_terms is not None and (problem := covariance_problem(cal.with_terms.covariance)):
        raise InputError(
            f"{src}: sensor_errors.extrinsic_with_lidar_terms.covariance {problem}; not a covariance this "
            "tool writes: calibrate again"
        )


def _check_rig(src: str, cal: RigCalibration) -> None:
    for s in cal.sensors:
        problem = pose_problem(cal.T_ref_sensor[s])
        if problem is not None:
            raise InputError(f"{src}: T_ref_sensor.{s} {problem}")
    k = cal.sensors.index(cal.reference)
    free = [i for i in range(cal.covariance.shape[0]) if not 6 * k <= i < 6 * k + 6]
    C = np.asarray(cal.covariance, dtype=np.float64)
    problem = covariance_problem(C)  # the whole: symmetric (the reference's zero block makes it singular)
    if problem is not None and "positive definite" not in problem:
        raise InputError(f"{src}: covariance {problem}; not a covariance this tool writes: calibrate again")
    problem = covariance_problem(C[np.ix_(free, free)])
    if problem is not None:
        raise InputError(
            f"{src}: covariance (the sensors other than the reference {cal.reference}) {problem}; not a "
            "covariance this tool writes: calibrate again"
        )
    for (a, b), (T, P) in cal.pairs.items():
        problem = pose_problem(T) or covariance_problem(P)
        if problem is not None:
            raise InputError(f"{src}: pairs.{a}/{b} {problem}")
    for camera, _, terms in cal.with_terms:
        if problem := covariance_problem(terms.covariance):
            raise InputError(
                f"{src}: {WITH_TERMS} ({camera}): covariance {problem}; not a covariance this tool writes: "
                "calibrate again"
            )


def read_stored(path: str | Path) -> Calibration | RigCalibration:
    """A stored calibration (a pair's or a rig's calibration.yaml), validated; InputError naming the
    file and what is wrong (a folder or a device named for what it is, a missing key, a pose that is
    not rigid, a covariance that is not one)."""
    p = Path(path)
    src = str(p)
    d = read_yaml(p, "calibration file")
    if isinstance(d, dict) and d.get("kind") == KIND:
        rig = rig_calibration_from_doc(d, src)
        _check_rig(src, rig)
        return rig
    cal = calibration_from_doc(d, src)
    _check_pair(src, cal)
    if cal.camera is None:
        camera = _resolved(p).get("camera")
        if isinstance(camera, dict):
            cal = dataclasses.replace(cal, camera=camera)
    return cal


def _resolved(path: Path) -> dict[str, Any]:
    """``config.resolved.yaml`` beside a calibration file (the run's config), or {}."""
    resolved = path.parent / RESOLVED
    if not resolved.is_file():
        return {}
    doc = read_yaml(resolved, "resolved config")
    return doc if isinstance(doc, dict) else {}


@dataclass(frozen=True)
class StoredSetup:
    """What a calibration was made with. board: ``squares`` (sorted; [] unreadable) and
    ``square_size`` (NaN unreadable), or None (not recorded). sensors: {name: ``"lidar"`` or the
    camera's model}; a sensor whose kind is not recorded is absent. where, board_where: the files
    that say them. sensor_model: the model of the LiDAR's own errors the calibration chose
    (``selection.Selection.chosen``), or None.
    lidar_errors: the LiDAR's own errors it estimated (``names``, ``values``; a rig's also
    ``lidar``, its base LiDAR), or None. intrinsics: {camera: its intrinsics the calibration
    refined, ``{names, stated, values, sigmas}``}.
    """

    board: Mapping[str, Any] | None = None
    sensors: Mapping[str, str] = field(default_factory=dict)
    where: str = ""
    board_where: str = ""
    sensor_model: str | None = None
    lidar_errors: Mapping[str, Any] | None = None
    intrinsics: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)


def _board(d: Any) -> dict[str, Any] | None:
    """``squares`` (sorted ints; [] when unreadable) and ``square_size`` (m; NaN when unreadable) of a
    stored ``board`` section, or None without one."""
    if not isinstance(d, dict) or "squares" not in d:
        return None
    try:
        squares = sorted(int(x) for x in d["squares"])
    except (TypeError, ValueError):
        squares = []
    try:
        size = float(d.get("square_size"))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        size = float("nan")
    return {"squares": squares, "square_size": size}


def stored_setup(path: str | Path, cal: Calibration | RigCalibration, names: tuple[str, str]) -> StoredSetup:
    """The board and sensor kinds of the calibration ``cal`` read from ``path``; a pair's sensors named
    ``names`` (LiDAR, camera), as a single pair opened as a rig names them."""
    p = Path(path)
    if isinstance(cal, RigCalibration):
        rig = cal.rig or {}
        kinds = {}
        for s, sd in (rig.get("sensors") or {}).items():
            if isinstance(sd, dict) and isinstance(sd.get("camera"), dict):
                kinds[str(s)] = str(sd["camera"].get("model"))
            elif isinstance(sd, dict) and "lidar" in sd:
                kinds[str(s)] = "lidar"
        model = _chosen(cal.extra.get("sensor_model"))
        errors = _lidar_errors(cal.extra.get("lidar_errors"), p)
        intrinsics = _intrinsics(cal, "", p)
        return StoredSetup(_board(rig.get("board")), kinds, str(p), str(p), model, errors, intrinsics)
    resolved = _resolved(p)
    lidar, camera = names
    kinds = {lidar: "lidar"}
    if isinstance(cal.camera, dict) and cal.camera.get("model") is not None:
        kinds[camera] = str(cal.camera["model"])
    board = _board(resolved.get("board"))
    model = _chosen((cal.sensors or {}).get("model"))
    errors = _lidar_errors((cal.sensors or {}).get("lidar_errors"), p)
    intrinsics = _intrinsics(cal, camera, p)
    return StoredSetup(board, kinds, str(p), str(p.parent / RESOLVED), model, errors, intrinsics)


def _intrinsics(cal: Calibration | RigCalibration, camera: str, where: Path) -> dict[str, dict[str, Any]]:
    """The cameras' intrinsics the calibration refined (a rig's ``RigCalibration.refined_intrinsics``,
    a pair's ``camera``'s); InputError naming the file when its ``camera_intrinsics`` is malformed."""
    try:
        if isinstance(cal, RigCalibration):
            return cal.refined_intrinsics()
        refined = (cal.sensors or {}).get("camera_intrinsics")
        return {} if refined is None else {camera: dict(refined)}
    except (AttributeError, KeyError, TypeError, ValueError):
        raise InputError(
            f"{where}: camera_intrinsics must give each camera's intrinsics, stated, refined and sigma: "
            "calibrate again"
        ) from None


def _lidar_errors(d: Any, where: Path) -> dict[str, Any] | None:
    """A stored ``lidar_errors`` (names and values of equal length, the values finite), or None when
    there is none; InputError naming the file otherwise."""
    if d is None:
        return None
    names = d.get("names") if isinstance(d, dict) else None
    values = d.get("values") if isinstance(d, dict) else None
    try:
        v = np.asarray(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if not isinstance(names, list) or len(v) != len(names) or not np.all(np.isfinite(v)):
        raise InputError(
            f"{where}: lidar_errors must have names and as many finite values (found {d!r:.120}): "
            "calibrate again"
        )
    return {**d, "names": [str(n) for n in names], "values": [float(x) for x in v]}


def _chosen(selection: Any) -> str | None:
    """The chosen model's name of a stored ``selection.Selection.to_dict()``, or None."""
    got = selection.get("chosen") if isinstance(selection, dict) else None
    return got if isinstance(got, str) else None
