"""Verify a stored calibration against a short new capture (``ilcc-graph verify``; docs/verify.md).

``load_stored(path)`` reads a rig's calibration.yaml or a single pair's (the rig of ``lidar`` and
``camera``, as a single-pair data set opened as a rig names them) through the one reader and
validation of a stored calibration (``io.stored.read_stored``), with the board and sensor kinds it
was made with; ``verify_capture(stored, source, options)`` refuses a capture that is not comparable
(``check_comparable``: other sensors, another board, another camera model), then observes and solves
it as ``calibrate`` does (a pair: ``pipeline.run`` on it, then ``estimation.verify.verify_pair``; a
larger rig: ``rig_observe`` and ``estimation.verify.verify_rig``); ``verify_to_dict`` and
``verify_text`` are what the command writes and prints. Units in the answer: deg and mm.
"""

from __future__ import annotations

import textwrap
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ilcc_graph.config.rig_config import PAIR_NAMES, RigConfig
from ilcc_graph.datasets import open_source
from ilcc_graph.datasets.rig_source import RigPair, RigSource
from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem, InputError
from ilcc_graph.estimation.selection import AUTO, MODELS
from ilcc_graph.estimation.verify import StoredRig, VerifyOptions, VerifyResult, verify_pair, verify_rig
from ilcc_graph.io.rig_results import RigCalibration
from ilcc_graph.io.stored import StoredSetup, read_stored, stored_setup
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.pipeline import run
from ilcc_graph.run.result import RunOptions
from ilcc_graph.run.rig_observe import RigObservation, observe_rig
from ilcc_graph.run.rig_views import refit_rig
from ilcc_graph.run.stages import StageOptions
from ilcc_graph.types import Estimate, MomentResult, PoseTerms

__all__ = [
    "EXIT_CODES", "StoredCalibration", "VerifyRun", "check_comparable", "load_stored", "verify_capture",
    "verify_pair_capture", "verify_text", "verify_to_dict",
]  # fmt: skip

#: the command's exit status per verdict (docs/verify.md; 1, 2, 3 and the signals' as every command's)
EXIT_CODES = {"pass": 0, "warn": 4, "fail": 5}


@dataclass(frozen=True)
class VerifyRun:
    """A verify run: the test's answer and how many moments the capture had."""

    result: VerifyResult
    moments: int


@dataclass(frozen=True)
class StoredCalibration(StoredRig):
    """A stored calibration as ``verify`` reads it: the poses and covariance (``StoredRig``), what it
    was made with (``io.stored.StoredSetup``: board, sensor kinds), for ``check_comparable``, and a
    camera's pose in the LiDAR's frame with the LiDAR's range terms, per camera (``terms``: a pair's
    ``Calibration.with_terms`` inverted; a rig's ``RigCalibration.with_terms``, its cameras' with
    the base LiDAR's), when the calibration has them; ``terms_lidar``: that LiDAR."""

    setup: StoredSetup = field(default_factory=StoredSetup)
    terms: Mapping[str, PoseTerms] = field(default_factory=dict)
    terms_lidar: str = PAIR_NAMES[0]


def load_stored(path: str | Path) -> StoredCalibration:
    """A stored calibration: a rig's calibration.yaml or a single pair's, validated
    (``io.stored.read_stored``); InputError naming the file otherwise or when it has no covariance."""
    cal = read_stored(path)
    setup = stored_setup(path, cal, PAIR_NAMES)
    if isinstance(cal, RigCalibration):  # the cameras' poses with the base LiDAR's terms, in its frame
        terms = {camera: t.inverse() for camera, lidar, t in cal.with_terms if lidar == cal.reference}
        T, C = cal.T_ref_sensor, cal.covariance
        return StoredCalibration(cal.sensors, cal.reference, T, C, setup, terms, cal.reference)
    if not np.all(np.isfinite(cal.covariance)):
        raise InputError(f"{path}: the calibration has no covariance (method {cal.method}); verify needs one")
    lidar, camera = PAIR_NAMES
    p = StoredRig.pair(cal.T_cam_lidar, cal.covariance, camera, lidar)
    terms = {} if cal.with_terms is None else {camera: cal.with_terms.inverse()}
    return StoredCalibration(p.sensors, p.reference, p.T_ref_sensor, p.covariance, setup, terms, lidar)


def check_comparable(stored: StoredRig, rig: RigConfig, where: str) -> None:
    """InputError (exit 2) naming the difference when the capture ``rig`` (read from ``where``) cannot
    be judged against ``stored``: a sensor the calibration does not have, a sensor of another kind or
    camera model, another board (squares or square size). What the calibration does not record is
    not compared."""
    missing = [s for s in rig.names if s not in stored.sensors]
    if missing:
        raise InputError(
            f"{where}: sensors {missing} are not in the stored calibration (it has {list(stored.sensors)})"
        )
    setup = stored.setup if isinstance(stored, StoredCalibration) else StoredSetup()
    for s in rig.names:
        cam = rig.sensor(s).camera
        have, had = ("lidar" if cam is None else cam.kind), setup.sensors.get(s)
        if had is not None and had != have:
            raise InputError(
                f"{where}: sensor {s} is a {_kind(have)} in the capture but a {_kind(had)} in the stored "
                f"calibration ({setup.where}): not comparable; verify checks the same sensors against "
                "their calibration (calibrate again after changing a camera or lens)"
            )
    b, want = rig.board, setup.board  # what the calibration does not record is not compared
    size = float("nan") if want is None else float(want["square_size"])
    same_size = not np.isfinite(size) or abs(size - b.square_size) <= 1e-6 * max(size, b.square_size)
    if want is not None and (want["squares"] not in ([], sorted((b.rows, b.cols))) or not same_size):
        raise InputError(
            f"{where}: the capture's board is [{b.rows}, {b.cols}] squares of {b.square_size:g} m, the "
            f"stored calibration's {want['squares']} of {size:g} m ({setup.board_where}): not "
            "comparable; take the capture with the calibration's board"
        )


def _kind(k: str) -> str:
    return "LiDAR" if k == "lidar" else f"{k} camera"


def verify_capture(
    stored: StoredRig,
    source: RigSource | str | Path,
    options: VerifyOptions = VerifyOptions(),
    stages: StageOptions = StageOptions(),
    progress: Callable[[int, int], None] | None = None,
) -> VerifyRun:
    """The capture ``source`` (a rig folder, file or bag, or a single-pair data set) against
    ``stored``; InputError when the capture is not comparable (``check_comparable``). A capture of one
    camera and one LiDAR is observed and solved as ``calibrate`` does a pair (``verify_pair_capture``);
    a larger rig by the rig's pass and solve."""
    src = source if isinstance(source, RigSource) else open_source(source, rig=True)
    rig = src.config()
    check_comparable(stored, rig, str(rig.source or source))
    setup = stored.setup if isinstance(stored, StoredCalibration) else StoredSetup()
    rig, lens = rig.with_intrinsics(setup.intrinsics)  # the cameras as calibrated (refined intrinsics)
    src = RigSource(src.location, rig) if setup.intrinsics else src
    if len(rig.cameras) == 1 and len(rig.lidars) == 1:
        got = verify_pair_capture(stored, src, options, stages, progress)
        got.result.notes.extend(lens)
        return got
    obs = observe_rig(src, stages, progress)
    rig = obs.rig  # as the capture shows it: each LiDAR's beam table, the print's colour
    cams = {c: cam for c in rig.cameras if (cam := rig.sensor(c).camera) is not None}
    solve_with = _stored_model(stored, options)
    moments, corrected = _on_corrected_ranges(stored, src, obs, stages)
    terms = {}  # the stored cameras' poses with the base LiDAR's terms: their checks net of them
    if isinstance(stored, StoredCalibration) and stored.terms_lidar == rig.lidars[0]:
        terms = dict(stored.terms)
    res = verify_rig(stored, moments, rig.board, list(rig.lidars), cams, solve_with, terms)
    if solve_with is not options:
        model = solve_with.rig.models[0]
        res.notes.append(f"the capture's LiDAR errors modelled as the calibration chose: {model}")
    res.notes.extend([corrected, *lens] if corrected else lens)
    return VerifyRun(res, len(obs.moments))


def _on_corrected_ranges(
    stored: StoredRig, source: RigSource, obs: RigObservation, stages: StageOptions
) -> tuple[list[MomentResult], str]:
    """The capture's moments with its base LiDAR's boards fitted again on the ranges corrected by the
    errors the stored calibration estimated for that LiDAR, as ``calibrate`` fitted the calibration's
    own boards (``rig_views.refit_rig``; when the correction matters), and a note saying so ("" and
    the moments as observed otherwise)."""
    errors = stored.setup.lidar_errors if isinstance(stored, StoredCalibration) else None
    base = obs.rig.lidars[0]
    if errors is None or errors.get("lidar", base) != base:
        return obs.moments, ""
    seen = Observation(source, obs.rig, [], "capture", data=obs)
    again = refit_rig(seen, stored.T_ref_sensor, {"lidar_errors": errors}, stages)
    if again is None or again.data is None:
        return obs.moments, ""
    note = f"the capture's boards of {base} fitted on its ranges corrected by the calibration's errors of it"
    return again.data.moments, note


def _stored_model(stored: StoredRig, options: VerifyOptions) -> VerifyOptions:
    """``options`` with the capture's LiDAR errors modelled as the stored calibration chose (when it
    says and the options leave the choice open): a short capture, often one board per camera, cannot
    tell the models apart (held out, a camera's only board leaves it unsolved), and a richer model's
    range offset is then set by its weak lever alone. Seen on a simulated ring of four cameras
    verified on one board each: the range model's offset 158 +- 32 mm moved every camera 155 mm
    along its axis (a false fail); with the stored model (beams) the changes were 5-21 mm."""
    model = stored.setup.sensor_model if isinstance(stored, StoredCalibration) else None
    if model is None or model not in MODELS or options.rig.range_offset or options.rig.models != AUTO:
        return options
    return replace(options, rig=replace(options.rig, models=(model,)))


def verify_pair_capture(
    stored: StoredRig,
    source: RigSource,
    options: VerifyOptions = VerifyOptions(),
    stages: StageOptions = StageOptions(),
    progress: Callable[[int, int], None] | None = None,
) -> VerifyRun:
    """A capture of one camera and one LiDAR calibrated as ``calibrate`` calibrates a pair (the same
    start, observation pass, sensor model, refit, second look and gate: ``pipeline.run``), its answer
    compared with ``stored`` (``estimation.verify.verify_pair``); a capture that does not calibrate
    leaves the camera unchecked, saying why."""
    rig = source.config()
    camera, lidar = rig.cameras[0], rig.lidars[0]
    pair = RigPair(source, camera, lidar)
    cb = None if progress is None else (lambda _name, i, n: progress(i, n))
    notes: list[str] = []
    try:
        result = run([pair], RunOptions(stages=stages), cb)
    except (CalibrationImpossible, IndeterminateSystem) as err:
        notes.append(f"the capture could not be calibrated: {err}")
        res = verify_pair(stored, camera, None, 0, options, notes)
        return VerifyRun(res, len(source.moments()))
    cal = result.calibration
    checked, new = camera, StoredRig.pair(cal.T_cam_lidar, cal.covariance, camera, lidar).pose(camera)
    new_terms = None if cal.with_terms is None else cal.with_terms.inverse()
    if stored.reference != lidar:  # the camera is the reference: the LiDAR's pose is T_cam_lidar
        checked, new, new_terms = lidar, Estimate(cal.T_cam_lidar, cal.covariance), None
    used = sum(1 for f in cal.frames if f.used)
    stored_terms = None
    if isinstance(stored, StoredCalibration) and stored.terms_lidar == lidar:
        stored_terms = stored.terms.get(camera)  # kept for this camera and LiDAR
    res = verify_pair(stored, checked, new, used, options, notes, (stored_terms, new_terms))
    return VerifyRun(res, len(source.moments()))


def verify_to_dict(run: VerifyRun, options: VerifyOptions) -> dict[str, Any]:
    """verify.yaml's content: the verdict, its exit status, each sensor's check, the rule."""
    r = run.result
    keys = ("change", "sigma", "z", "p_value", "detectable")
    sensors = {
        s: {
            "verdict": c.verdict, "reason": c.reason, "boards": c.boards, "chi2": c.chi2,
            "p_value": c.p_value, "rotation_deg": c.rotation_deg, "translation_mm": c.translation_mm,
            "detectable_deg": c.detectable_deg, "detectable_mm": c.detectable_mm,
            "axes": {a.name: {"verdict": a.verdict, **{k: getattr(a, k) for k in keys}} for a in c.axes},
        }
        for s, c in r.sensors.items()
    }  # fmt: skip
    glob = (
        None if r.global_test is None else dict(zip(("chi2", "dof", "p_value"), r.global_test, strict=True))
    )
    return {
        "verdict": r.verdict,
        "exit_status": EXIT_CODES[r.verdict],
        "reference": r.reference,
        "sensors": sensors,
        "alpha": options.alpha,
        "alpha_per_sensor": r.alpha_sensor,
        "power": options.power,
        "tolerance_deg": options.tolerance_deg,
        "tolerance_mm": options.tolerance_mm,
        "global_test": glob,
        "moments": run.moments,
        "notes": list(r.notes),
        "rule": r.rule,
    }


def verify_text(run: VerifyRun) -> str:
    """What the command prints: per sensor its verdict and reason, per axis the change, its sigma and
    the smallest detectable change; the verdict word last."""
    r = run.result
    lines = [f"verify: {run.moments} moments; poses relative to {r.reference}"]
    for s, c in r.sensors.items():
        lines += textwrap.wrap(f"{s}: {c.verdict.upper()} - {c.reason}", 80, subsequent_indent="   ")
        if c.axes:
            lines.append("   axis     change    sigma  detectable  (deg or mm)")
            lines += [
                f"   {a.name:<7}{a.change:>8.3f} {a.sigma:>8.3f} {a.detectable:>10.3f}  {a.verdict}"
                for a in c.axes
            ]
    for n in r.notes:
        lines += textwrap.wrap(f"note: {n}", 80, subsequent_indent="   ")
    lines.append(f"verdict: {r.verdict}")
    return "\n".join(lines)
