"""The run: frame sources -> the stages per frame -> corner order and start -> an estimation strategy.

``observe.observe`` runs the per-frame stages on a source; ``prepare.prepare`` orders the corners
across frames (half turns) and takes the start from that consensus; one strategy of the estimation core
then solves: batch (``graph``), the paper's refinement (``paper``), incremental (iSAM2 with a
target), or sessions (several sources, or a range offset). Every mode returns one ``RunResult``;
``outputs`` writes it. Only sources read files.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ilcc_graph import signals
from ilcc_graph.config import Config
from ilcc_graph.damage import check_image_size
from ilcc_graph.datasets import FrameSource
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation import NoiseOptions
from ilcc_graph.estimation.batch import BatchSolution
from ilcc_graph.estimation.batch import solve as solve_batch
from ilcc_graph.estimation.incremental import FrameUpdate, IncrementalCalibrator
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.noise import BoardStats
from ilcc_graph.estimation.paper import refine_paper
from ilcc_graph.estimation.selection import AUTO, MODELS
from ilcc_graph.estimation.sessions import JointOptions, JointSolution, Session, solve_sessions
from ilcc_graph.observe import (
    Observation,
    StageOptions,
    check_board_colour,
    observe,
    observe_frame,
    resolve_lidar,
    second_pass,
)
from ilcc_graph.prepare import Prepared, finish, permute_corners, prepare, rms_bearing_mrad
from ilcc_graph.setup_mistakes import diagnose_failure, diagnose_result
from ilcc_graph.types import Calibration, FrameResult

log = logging.getLogger(__name__)

__all__ = [
    "MODES",
    "RunOptions",
    "RunResult",
    "SessionResult",
    "calibrate",
    "run",
    "solve_observations",
    "solve_observed",
]

MODES = ("graph", "paper", "incremental", "sessions")
#: ``RunOptions.sensor_model``: auto or one of ``estimation.selection.MODELS``
SENSOR_MODELS = ("auto", *MODELS)


@dataclass(frozen=True)
class RunOptions:
    """Everything a run uses (written to config.resolved.yaml).

    mode: ``graph`` (batch, default), ``paper`` (the paper's refinement, no covariance),
        ``incremental`` (iSAM2, frame by frame) or ``sessions`` (joint; chosen for several sources).
    noise: the estimation core's noise policy. stages: the per-frame stages' options and processes.
    joint: sessions mode (rigid / drift, range offset, tests).
    target_sigma: incremental mode's (deg, mm) target; stop_at_target: read no frame after it.
    second_pass: once an extrinsic is known, search the boards the LiDAR stage missed (or found
        elsewhere than the image says) near where the image and the extrinsic put them, and solve again.
    lidar_errors: the LiDAR's own errors the graph estimates from the boards' returns (None: none,
        the default: on the recorded sets the boards' 6-dof LiDAR priors gave halves that agree,
        the returns with these terms did not; docs/bench_real.md).
    lidar_errors_without_print: when ``lidar_errors`` is None and most boards were placed by their
        outline (the LiDAR shows no print), estimate the LiDAR's errors all the same
        (``LidarErrorOptions()``): the boards' planes then carry the translation, and every beam's
        range offset, common to all frames, biases them alike (docs/lidar_stage.md).
    intrinsics: refine the camera's intrinsics, or propagate their stated ``camera.intrinsics_sigma``.
    sensor_model: ``auto`` (the default: the model of the sensors' own errors the boards support,
        ``estimation.selection``, and the camera's intrinsics refined when the boards support it,
        ``estimation.camera_choice``; ``beams`` when ``lidar_errors`` is given) or one LiDAR model
        forced (``selection.MODELS``: ``none``, ``range``, ``beams``, ``offset``) with the intrinsics
        as ``intrinsics`` says.
    """

    mode: str = "graph"
    noise: NoiseOptions = NoiseOptions()
    stages: StageOptions = StageOptions()
    joint: JointOptions = JointOptions()
    target_sigma: tuple[float, float] | None = None
    stop_at_target: bool = False
    second_pass: bool = True
    lidar_errors: LidarErrorOptions | None = None
    lidar_errors_without_print: bool = True
    intrinsics: IntrinsicsOptions = IntrinsicsOptions()
    sensor_model: str = "auto"

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"RunOptions.mode must be one of {MODES}, got {self.mode!r}")
        if self.sensor_model not in SENSOR_MODELS:
            raise ValueError(
                f"RunOptions.sensor_model must be one of {SENSOR_MODELS}, got {self.sensor_model!r}"
            )

    @property
    def models(self) -> tuple[str, ...]:
        """The sensor models the batch strategy chooses among (one: forced)."""
        if self.sensor_model != "auto":
            return (self.sensor_model,)
        return ("beams",) if self.lidar_errors is not None else AUTO

    @property
    def intrinsics_choice(self) -> str:
        """``auto`` (the camera's intrinsics refined when the boards support it) or ``stated``."""
        return "auto" if self.sensor_model == "auto" and not self.intrinsics.refine else "stated"


@dataclass(frozen=True)
class SessionResult:
    """One source's part of a run: its observation and its calibration (its own frames)."""

    name: str
    observation: Observation
    calibration: Calibration


@dataclass(frozen=True)
class RunResult:
    """What a run gives, in every mode.

    calibration: the result (frames named ``session/frame`` when there are several sessions).
    sessions: per source its config, observations and calibration. joint: the sessions strategy's
    answer (tests, offsets). updates: incremental mode's per-frame states.
    """

    mode: str
    calibration: Calibration
    sessions: tuple[SessionResult, ...]
    options: RunOptions
    joint: JointSolution | None = None
    updates: tuple[FrameUpdate, ...] = ()
    timings: dict[str, float] = field(default_factory=dict)


# ----------------------------------------------------------------------------------------------
# From observations to the extrinsic


def solve_observed(
    observed: Sequence[FrameResult], config: Config, options: RunOptions = RunOptions()
) -> Calibration:
    """Batch (``graph``) or the paper's refinement on observed frames: order, start, solve.

    Raises CalibrationImpossible when no frame has the board in both sensors.
    """
    prep = prepare(observed, config)
    if options.mode == "paper":
        T = refine_paper(prep.frames, prep.T_init, R_pano_cam=config.camera.R_flu_cam)
        if len(prep.frames) < 4:
            log.warning("only %d usable frame(s); at least 4 are advised", len(prep.frames))
        stats = {
            f.name: BoardStats(math.nan, 2 * len(f.bearings), rms_bearing_mrad(T, f)) for f in prep.frames
        }
        sol = BatchSolution(T, np.full((6, 6), np.nan), {}, stats, [], 0)
        return finish(prep, observed, config, "paper", sol)
    sol = solve_batch(
        prep.frames, config.camera, prep.T_init, options.noise, options.lidar_errors, options.intrinsics,
        effects=True, models=options.models, intrinsics_choice=options.intrinsics_choice,
    )  # fmt: skip
    return finish(prep, observed, config, "graph", sol)


# ----------------------------------------------------------------------------------------------
# The modes


def _incremental(
    source: FrameSource, options: RunOptions, report: Callable[[FrameUpdate], None] | None
) -> RunResult:
    """Frames observed one at a time and fed to iSAM2; the last update is the batch answer."""
    config = source.config()  # the config's mistakes first, then the folders'
    refs = source.frames()
    config = resolve_lidar(source, refs, config)
    check_image_size(source, refs, config)
    config, known = check_board_colour(
        source, refs, config, options.stages.image, strict=options.stages.strict
    )
    cal = IncrementalCalibrator(
        config.camera, config.board, target_sigma=options.target_sigma, noise=options.noise,
        lidar_errors=options.lidar_errors, intrinsics=options.intrinsics, models=options.models,
        intrinsics_choice=options.intrinsics_choice,
    )  # fmt: skip
    observed: list[FrameResult] = []
    updates: list[FrameUpdate] = []

    stream = (observe_frame(source, r, config, options.stages, known.get(r.name)) for r in refs)
    for fr in stream:
        signals.check()
        observed.append(fr)
        if fr.damaged:
            log.warning("%s: skipped, %s", fr.name, fr.reason)
        if not fr.used or fr.board is None or fr.corners is None:
            continue
        u = cal.add_frame(fr)
        updates.append(u)
        if report is not None:
            report(u)
        if options.stop_at_target and u.reached_target:
            break
    read = {f.name for f in observed}
    observed += [
        FrameResult(r.name, False, "not read: the target sigma was reached")
        for r in refs
        if r.name not in read
    ]
    observed += [FrameResult(name=n, used=False, reason=why) for n, why in source.skipped()]
    if not updates:
        prepare(observed, config)  # no frame reached the calibrator: raises with every frame's reason
    final = cal.finish()
    updates.append(final)
    if report is not None:
        report(final)
    results = {f.name: f for f in observed}
    for name in cal.flipped:  # the corner order the calibrator chose
        f = results[name]
        results[name] = dataclasses.replace(
            f, corners=permute_corners(f.corners, config.board.half_turn_permutation())
        )  # type: ignore[arg-type]
    offered = {f.name for f in cal.offered}
    prep = Prepared(cal.offered, np.asarray(final.T_cam_lidar), results)
    sol = final.solution
    assert sol is not None
    not_offered = [(f.name, "not offered") for f in observed if f.used and f.name not in offered]
    calib = finish(
        prep, observed, config, "incremental", dataclasses.replace(sol, dropped=sol.dropped + not_offered)
    )
    obs = Observation(source, config, observed)
    return RunResult(
        "incremental", calib, (SessionResult(source.label, obs, calib),), options, updates=tuple(updates)
    )


def _sessions(observations: Sequence[Observation], names: Sequence[str], options: RunOptions) -> RunResult:
    """Sources as sessions of one mount, through the sessions strategy."""
    preps = [prepare(o.frames, o.config) for o in observations]
    sessions = [
        Session(
            n,
            p.frames,
            o.config.camera,
            p.T_init,
            o.config.lidar.name if o.config.lidar else "lidar",
            o.config.board,
        )
        for n, p, o in zip(names, preps, observations, strict=True)
    ]
    joint_opts = dataclasses.replace(
        options.joint, noise=options.noise, lidar_errors=options.lidar_errors, intrinsics=options.intrinsics
    )
    sol = solve_sessions(sessions, joint_opts)
    method = f"joint-{joint_opts.mode}"
    results = []
    for n, p, o in zip(names, preps, observations, strict=True):
        est = sol.sessions[n]
        part = BatchSolution(
            est.T,
            est.covariance,
            sol.T_lidar_board[n],
            sol.per_frame[n],
            sol.dropped[n],
            sol.iterations,
            {},
            sol.variance_factor,
            sol.components[n],
        )
        results.append(SessionResult(n, o, finish(p, o.frames, o.config, method, part)))
    prefix = len(names) > 1
    frames = tuple(
        dataclasses.replace(f, name=f"{r.name}/{f.name}") if prefix else f
        for r in results
        for f in r.calibration.frames
    )
    diag = {"variance_factor": sol.variance_factor}
    for lab, ro in sol.range_offsets.items():
        diag[f"range_offset_mm/{lab}"] = 1e3 * ro.value_m
        diag[f"range_offset_sigma_mm/{lab}"] = 1e3 * ro.sigma_m
    cal = Calibration(
        sol.joint.T,
        sol.joint.covariance,
        frames,
        method=method,
        diagnostics=diag,
        camera=observations[0].config.camera.to_dict(),
    )
    return RunResult("sessions", cal, tuple(results), options, joint=sol)


def session_names(sources: Sequence[FrameSource]) -> list[str]:
    """Source labels made unique (with an index where two share one)."""
    labels = [s.label or f"session{i + 1}" for i, s in enumerate(sources)]
    return [f"{n}#{i + 1}" if labels.count(n) > 1 else n for i, n in enumerate(labels)]


def run(
    sources: Sequence[FrameSource],
    options: RunOptions = RunOptions(),
    progress: Callable[[str, int, int], None] | None = None,
    report: Callable[[FrameUpdate], None] | None = None,
) -> RunResult:
    """Calibrate from one or more sources in the mode of ``options`` (several sources: sessions).

    progress(source label, done, total) reports the per-frame stages; report(update) each
    incremental update. Raises InputError (bad input), CalibrationImpossible, IndeterminateSystem.
    """
    if not sources:
        raise ValueError("run: no source given")
    mode = "sessions" if len(sources) > 1 or options.joint.range_offset else options.mode
    if len(sources) > 1 and options.mode in ("paper", "incremental"):
        raise ValueError(f"mode {options.mode!r} calibrates one data set; {len(sources)} were given")
    if mode == "incremental":
        return _incremental(sources[0], options, report)
    names = session_names(sources)
    observations = []
    for name, src in zip(names, sources, strict=True):
        cb = None if progress is None else (lambda i, n, name=name: progress(name, i, n))
        observations.append(observe(src, options.stages, cb))
    signals.check()
    try:
        result = solve_observations(observations, dataclasses.replace(options, mode=mode), names)
    except CalibrationImpossible as err:  # say what set-up mistake explains it, when one does
        if not (hints := diagnose_failure(observations, options.stages)):
            raise
        advice = "\n".join(f"likely: {h}" for h in hints)  # the set-up mistake is the better advice
        raise CalibrationImpossible(str(err), err.frames, advice) from None
    for s in result.sessions:
        for line in diagnose_result(s.observation, s.calibration):
            log.warning("%s", line)
    return result


def solve_observations(
    observations: Sequence[Observation],
    options: RunOptions = RunOptions(),
    names: Sequence[str] | None = None,
) -> RunResult:
    """The estimation strategy of ``options.mode`` on observed sources (``sessions`` for several,
    or with a range offset); ``names`` label the sessions (default: the sources' labels). With
    ``options.second_pass`` the boards the LiDAR stage missed are searched where the first
    answer puts them (``second_pass``), and the data solved again when some are found."""
    names = list(names) if names is not None else session_names([o.source for o in observations])
    if options.mode == "incremental":
        raise ValueError("incremental mode observes frame by frame: use run()")
    options = _without_print(observations, options)
    log.debug("estimating the extrinsic (%s) from %d source(s)", options.mode, len(observations))
    result = _solve_once(observations, options, names)
    if not options.second_pass:
        return result
    again = [second_pass(s.observation, s.calibration, options.stages) for s in result.sessions]
    if all(a is None for a in again):
        return result
    observations = [o if a is None else a for o, a in zip(observations, again, strict=True)]
    return _solve_once(observations, options, names)


def _without_print(observations: Sequence[Observation], options: RunOptions) -> RunOptions:
    """The options with the LiDAR's errors estimated when most boards were placed by their outline
    (``RunOptions.lidar_errors_without_print``), said once; as given otherwise."""
    if options.lidar_errors is not None or not options.lidar_errors_without_print or options.mode == "paper":
        return options
    boards = [f.board for o in observations for f in o.frames if f.used and f.board is not None]
    plain = sum(1 for b in boards if b.diagnostics.get("no_contrast"))
    if not boards or 2 * plain <= len(boards):
        return options
    log.warning(
        "%d of %d boards were placed by their outline: the LiDAR's own errors (each beam's range offset) "
        "are estimated, as with --lidar-errors, since the boards' planes then carry the translation",
        plain, len(boards),
    )  # fmt: skip
    return dataclasses.replace(options, lidar_errors=LidarErrorOptions())


def _solve_once(observations: Sequence[Observation], options: RunOptions, names: list[str]) -> RunResult:
    if len(observations) > 1 or options.joint.range_offset or options.mode == "sessions":
        return _sessions(observations, names, options)
    obs = observations[0]
    cal = solve_observed(obs.frames, obs.config, options)
    return RunResult(options.mode, cal, (SessionResult(names[0], obs, cal),), options)


def calibrate(data: str, options: RunOptions = RunOptions()):  # noqa: ANN201 - (gtsam.Pose3, (6, 6))
    """Python API: the extrinsic of the data set at ``data`` as ``gtsam.Pose3`` (T_cam_lidar) and its
    6x6 covariance (interface.md convention)."""
    from ilcc_graph.datasets import open_source

    cal = run([open_source(data)], options).calibration
    return cal.extrinsic.pose, cal.covariance
