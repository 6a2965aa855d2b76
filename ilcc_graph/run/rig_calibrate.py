"""A whole rig calibrated in one graph (issue 24): a rig source in, every sensor's pose out.

``calibrate_rig(source, options) -> RigResult`` is the one entry point (the run's rig strategy
calls it; so can a user): the stages on every sensor's data at every moment (``rig_observe``), the
start (``init.rig_start``: every sensor placed from the data, one corner order per moment), the joint
solve (``estimation.rig_solve``: a board per moment, camera bearings and LiDAR board fits on it).
``solve_observed(observation, options)`` is the same from observations already made (studies,
benchmarks, ``verify``).

The answer is plain data: every sensor's ``T_ref_sensor`` (``p_ref = T_ref_sensor @ p_sensor``,
metres) in the reference sensor's frame, their joint covariance (6N x 6N, right tangent, rotation
first, rad and m; the reference's block zero), any pair's relative pose with its covariance by
propagation (``RigResult.relative``), and per moment and sensor whether its observation was used
and if not, why (``RigResult.fates``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ilcc_graph.config import RigConfig, rig_config_to_dict
from ilcc_graph.datasets import open_source
from ilcc_graph.datasets.rig_source import RigSource
from ilcc_graph.estimation.lidar_errors import errors_entry
from ilcc_graph.estimation.rig_solve import RigOptions, RigSolution, solve_rig
from ilcc_graph.init.rig_start import RigStart, StartOptions, rig_start
from ilcc_graph.io.results import intrinsics_doc
from ilcc_graph.io.rig_results import RigCalibration
from ilcc_graph.lidar.margin import margin_summary
from ilcc_graph.run.rig_observe import RigObservation, observe_rig
from ilcc_graph.run.stages import StageOptions
from ilcc_graph.types import Estimate, PoseTerms

__all__ = [
    "USED",
    "Fate",
    "RigRunOptions",
    "RigResult",
    "calibrate_rig",
    "fates",
    "lidar_errors",
    "solve_observed",
    "to_calibration",
]

#: the reason of an observation that entered the graph
USED = "used"


@dataclass(frozen=True)
class RigRunOptions:
    """stages: the per-moment stages (processes: ``stages.jobs``). start: how the start links the
    sensors and orders the corners. solve: the joint solve (noise policy, range offset).
    reference: the sensor whose frame the poses are in (None: the rig file's ``reference``)."""

    stages: StageOptions = StageOptions()
    start: StartOptions = StartOptions()
    solve: RigOptions = RigOptions()
    reference: str | None = None


@dataclass(frozen=True)
class Fate:
    """One sensor at one moment: ``used`` (its observation is in the graph) or not, with the reason
    (``USED``, no data, the stage's failure, the start's or the gate's reason)."""

    moment: str
    sensor: str
    used: bool
    reason: str


@dataclass(frozen=True)
class RigResult:
    """A calibrated rig.

    rig: the rig's config. solution: the joint solve's answer (``sensors`` solved in the rig's order,
    ``reference``, ``T_ref_sensor`` {sensor: (4, 4)}, ``covariance`` (6N, 6N) joint in ``sensors``
    order, ``unsolved`` {sensor: why it has no pose}, ``variance_factor``; the same as properties
    here). fates: per moment and sensor (``Fate``). skipped: moments the source could not use,
    ``(name, reason)``. start: the start; observation: the stages' answers.
    """

    rig: RigConfig
    solution: RigSolution
    fates: list[Fate]
    skipped: list[tuple[str, str]] = field(default_factory=list)
    start: RigStart | None = None
    observation: RigObservation | None = None

    @property
    def sensors(self) -> tuple[str, ...]:
        return self.solution.sensors

    @property
    def reference(self) -> str:
        return self.solution.reference

    @property
    def T_ref_sensor(self) -> dict[str, np.ndarray]:
        return self.solution.T_ref_sensor

    @property
    def covariance(self) -> np.ndarray:
        return self.solution.covariance

    @property
    def unsolved(self) -> dict[str, str]:
        return self.solution.unsolved

    @property
    def variance_factor(self) -> float:
        return self.solution.variance_factor

    def pose(self, sensor: str) -> Estimate:
        """``T_ref_sensor`` of ``sensor`` with its (6, 6) covariance."""
        return self.solution.pose(sensor)

    def relative(self, a: str, b: str) -> Estimate:
        """``T_a_b`` (``p_a = T_a_b @ p_b``) with its covariance, from the joint covariance; e.g.
        ``relative(camera, lidar)`` is that pair's ``T_cam_lidar``."""
        return self.solution.relative(a, b)

    def joint(self, sensors: Sequence[str]) -> np.ndarray:
        """(6n, 6n) joint covariance of ``sensors``' poses, in that order."""
        return self.solution.joint(sensors)

    def used(self, sensor: str) -> list[str]:
        """The moments whose observation by ``sensor`` is in the graph."""
        return [f.moment for f in self.fates if f.sensor == sensor and f.used]


def fates(observation: RigObservation, start: RigStart, solution: RigSolution) -> list[Fate]:
    """Every (moment, sensor) of the rig: used, or the first reason it was not (module docstring)."""
    dropped_obs = {(m, s): why for m, s, why in start.dropped}
    dropped_moment = dict(solution.dropped)
    kept = set(solution.T_base_board)
    out = []
    for m in observation.moments:
        for s in observation.rig.names:
            saw = s in m.boards or s in m.corners
            if s in m.failures:
                why = m.failures[s]
            elif not saw:
                why = "no data at this moment"
            elif (m.name, s) in dropped_obs:
                why = dropped_obs[(m.name, s)]
            elif m.name in dropped_moment:
                why = dropped_moment[m.name]
            elif s in solution.unsolved:
                why = solution.unsolved[s]
            elif m.name not in kept:
                why = "the board could not be placed"
            else:
                why = USED
            out.append(Fate(m.name, s, why == USED, why))
    return out


def solve_observed(observation: RigObservation, options: RigRunOptions = RigRunOptions()) -> RigResult:
    """The start and the joint solve of a rig already observed (``rig_observe.observe_rig``).

    Raises CalibrationImpossible (no moment relates two sensors), IndeterminateSystem."""
    rig = observation.rig
    lidars = list(rig.lidars)
    cams = {c: cam for c in rig.cameras if (cam := rig.sensor(c).camera) is not None}
    start = rig_start(observation.moments, rig.board, lidars, list(cams), options.start)
    reference = options.reference or rig.reference
    sol = solve_rig(observation.moments, start, rig.board, lidars, cams, reference, options.solve, rig.names)
    return RigResult(rig, sol, fates(observation, start, sol), list(observation.skipped), start, observation)


def calibrate_rig(
    source: RigSource | str | Path,
    options: RigRunOptions = RigRunOptions(),
    progress: Callable[[int, int], None] | None = None,
) -> RigResult:
    """Calibrate a rig: ``source`` a ``datasets.RigSource`` or a path (``open_source(path, rig=True)``:
    a rig folder, a rig file, a single-pair data set as the rig of ``lidar`` and ``camera``).

    progress: ``progress(done, total)`` per moment observed. Raises InputError (bad data set),
    CalibrationImpossible, IndeterminateSystem."""
    src = source if isinstance(source, RigSource) else open_source(source, rig=True)
    observation = observe_rig(src, options.stages, progress)
    return solve_observed(observation, options)


def lidar_errors(result: RigResult) -> dict[str, Any]:
    """The base LiDAR's own errors the chosen model estimated, as a pair's ``Calibration.sensors``
    has them (``estimation.lidar_errors.errors_entry``, with ``lidar``: its name), or {} when the
    model has none."""
    sol = result.solution.solution
    got = None if sol is None else sol.lidar_estimate(0)
    if sol is None or got is None:
        return {}
    values, C = got
    layout = sol.assembly.layouts.get(0)
    names = layout.names if layout is not None else [f"term{i}" for i in range(len(values))]
    lidar = result.rig.sensor(result.solution.base).lidar
    entry = errors_entry(
        (names, values, np.sqrt(np.diag(C))), layout, C, None,
        None if lidar is None else lidar.vertical_angles_deg,
    )  # fmt: skip
    return {"lidar": result.solution.base, **entry}


def _lidar_margins(result: RigResult) -> dict[str, dict[str, float]]:
    """Per LiDAR whose boards contradict the configured margin, the margin they measured
    (``lidar.margin.margin_summary``: mm, as a pair's ``lidar_margin_*`` diagnostics)."""
    moments = result.observation.moments if result.observation is not None else []
    out = {}
    for lidar in result.rig.lidars:
        boards = [m.boards[lidar].diagnostics for m in moments if lidar in m.boards]
        if summary := margin_summary(boards, result.rig.board):
            out[lidar] = summary
    return out


def to_calibration(result: RigResult) -> RigCalibration:
    """The rig's ``calibration.yaml`` content (``io.rig_results``): poses, joint covariance, every
    pair's relative pose and covariance, the rig file's mapping (intrinsics), what was used, the
    base LiDAR's sensor model chosen (``sensor_model``, as the pair's ``selection.Selection``), the
    cameras' refined intrinsics (``camera_intrinsics``, each as a pair's file holds them)."""
    names = result.sensors
    pairs = {}
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            e = result.relative(a, b)
            pairs[(a, b)] = (e.T, e.covariance)
    moments: dict[str, dict[str, str]] = {}
    for f in result.fates:
        moments.setdefault(f.moment, {})[f.sensor] = f.reason
    rig = rig_config_to_dict(result.rig)
    for d in rig["sensors"].values():
        d.pop("T_ref_sensor", None)  # the rig file's guesses: the poses above are the answer
    extra = {
        "variance_factor": result.variance_factor,
        "used": {s: len(result.used(s)) for s in result.rig.names},
        "unsolved": dict(result.unsolved),
        "moments": moments,
        "skipped": [list(x) for x in result.skipped],
    }
    if result.solution.selection is not None:  # the base LiDAR's sensor model and the evidence
        extra["sensor_model"] = result.solution.selection.to_dict()
    if errors := lidar_errors(result):  # and its own errors (verify corrects a capture's ranges by them)
        extra["lidar_errors"] = errors
    if margins := _lidar_margins(result):
        extra["lidar_margin"] = margins
    got = {c: x for c in result.rig.cameras if (x := result.solution.intrinsics(c)) is not None}
    refined = {c: intrinsics_doc(x.entry()) for c, x in got.items()}
    if refined:  # the exports take these (``exports_rig.rig_cameras``)
        extra["camera_intrinsics"] = refined
    T, C = dict(result.T_ref_sensor), result.covariance
    return RigCalibration(names, result.reference, T, C, pairs, rig, extra, _with_terms(result))


def _with_terms(result: RigResult) -> tuple[tuple[str, str, PoseTerms], ...]:
    """Each solved camera's pose ``T_camera_lidar`` in the base LiDAR's frame with that LiDAR's range
    terms (``RigSolution.camera_terms``), as a pair's ``Calibration.with_terms``; empty without
    terms."""
    got = result.solution.camera_terms(result.rig.cameras)
    return tuple((camera, result.solution.base, t) for camera, t in got.items())
