"""The run: frame sources -> the stages per frame -> corner order and start -> an estimation strategy.

``observe.observe`` runs the per-frame stages on a source; ``_prepare`` orders the corners across
frames (half turns) and takes the start from that consensus; one strategy of the estimation core
then solves: batch (``graph``), the paper's refinement (``paper``), incremental (iSAM2 with a
target), or sessions (several sources, or a range offset). Every mode returns one ``RunResult``;
``outputs`` writes it. Only sources read files.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ilcc_graph.config import Config
from ilcc_graph.datasets import FrameSource
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation import NoiseOptions
from ilcc_graph.estimation.batch import BatchSolution
from ilcc_graph.estimation.batch import solve as solve_batch
from ilcc_graph.estimation.geometry import board_geometry
from ilcc_graph.estimation.incremental import FrameUpdate, IncrementalCalibrator
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.noise import BoardStats
from ilcc_graph.estimation.paper import refine_paper
from ilcc_graph.estimation.sessions import JointOptions, JointSolution, Session, solve_sessions
from ilcc_graph.init import resolve_half_turns, upnp
from ilcc_graph.observe import (
    Observation,
    StageOptions,
    check_board_colour,
    observe,
    observe_frame,
    resolve_lidar,
    second_pass,
)
from ilcc_graph.types import (
    Calibration,
    FrameResult,
    GraphFrame,
    ImageCorners,
    rotation_angle_deg,
)

log = logging.getLogger(__name__)

__all__ = [
    "MODES",
    "RunOptions",
    "RunResult",
    "SessionResult",
    "calibrate",
    "frame_issues",
    "run",
    "solve_observations",
    "solve_observed",
]

MODES = ("graph", "paper", "incremental", "sessions")


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
    intrinsics: refine the camera's intrinsics, or propagate their stated ``camera.intrinsics_sigma``.
    """

    mode: str = "graph"
    noise: NoiseOptions = NoiseOptions()
    stages: StageOptions = StageOptions()
    joint: JointOptions = JointOptions()
    target_sigma: tuple[float, float] | None = None
    stop_at_target: bool = False
    second_pass: bool = True
    lidar_errors: LidarErrorOptions | None = None
    intrinsics: IntrinsicsOptions = IntrinsicsOptions()

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"RunOptions.mode must be one of {MODES}, got {self.mode!r}")


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


@dataclass(frozen=True)
class _Prepared:
    """Frames in a consistent corner order with the start from their consensus."""

    frames: list[GraphFrame]
    T_init: np.ndarray
    results: dict[str, FrameResult]  # every frame, with the ordering's drops and re-indexed corners


def _permute_corners(corners: ImageCorners, perm: np.ndarray) -> ImageCorners:
    """The same corners re-indexed: new corner k is old corner perm[k]."""
    return dataclasses.replace(
        corners, uv=corners.uv[perm], bearings=corners.bearings[perm], cov_px=corners.cov_px[perm]
    )


def _drop(results: dict[str, FrameResult], name: str, reason: str) -> None:
    results[name] = dataclasses.replace(results[name], used=False, reason=reason)


def _graph_frame(r: FrameResult, config: Config) -> GraphFrame:
    b, c = r.board, r.corners
    assert b is not None and c is not None
    corners = config.board.corners_board()
    return GraphFrame(r.name, b.T_lidar_board, b.covariance, corners, c.bearings, c.cov_px, b.returns, c.uv)


def _prepare(observed: Sequence[FrameResult], config: Config) -> _Prepared:
    """Repeated board poses out, corners ordered across frames (half turns), the start from the consensus.

    Raises CalibrationImpossible when no frame has the board in both sensors, the distinct board
    poses cannot calibrate (``estimation.geometry``), or the corner order is ambiguous.
    """
    results = {r.name: r for r in observed}
    usable = [r for r in observed if r.used and r.board is not None and r.corners is not None]
    if not usable:
        issues = frame_issues(observed)
        raise CalibrationImpossible(
            f"no frame has the board in both the scan and the image ({_counts(observed, issues)})",
            issues,
            _stage_advice(issues),
        )
    geometry = board_geometry([_graph_frame(r, config) for r in usable])
    for name, first in geometry.repeats.items():
        _drop(results, name, f"same board pose as {first}: one observation, not an independent one")
    if not geometry.ok:
        reason = re.sub(r" \([^)]*show one pose\)", "", geometry.reason or "too few distinct board poses")
        issues = frame_issues([r for r in observed if not r.used or r.board is None or r.corners is None])
        n = len(geometry.groups)
        issues += tuple(
            (r.name, "geometry", f"same board pose as {geometry.repeats[r.name]}")
            if r.name in geometry.repeats
            else (r.name, "geometry", f"usable: one of only {n} distinct board pose{'s' if n != 1 else ''}")
            for r in usable
        )
        raise CalibrationImpossible(reason, issues, f"capture next: {geometry.advice}")
    if geometry.parallel:
        log.warning("%s: %s", config.source, geometry.parallel)
    usable = [r for r in usable if r.name not in geometry.repeats]
    board = config.board
    perm = board.half_turn_permutation() if board.half_turn_symmetric else None
    order = resolve_half_turns(
        [r.board.corners_lidar for r in usable],  # type: ignore[union-attr]
        [r.corners.bearings for r in usable],  # type: ignore[union-attr]
        perm,
        [r.name for r in usable],
    )
    if order.ambiguous:
        raise CalibrationImpossible(
            "the corner order between image and scan cannot be decided",
            tuple((r.name, "order", order.ambiguous) for r in usable[:1]),
            "add frames with the board turned differently in its plane (not only half turns apart)",
        )
    for name, reason in order.dropped:
        _drop(results, name, reason)
    kept: list[FrameResult] = []
    for r in usable:
        if not results[r.name].used:
            continue
        if perm is not None and order.flip.get(r.name, False):
            r = dataclasses.replace(r, corners=_permute_corners(r.corners, perm))  # type: ignore[arg-type]
            results[r.name] = r
        kept.append(r)
    if not kept:
        raise CalibrationImpossible(
            "no frame left after ordering the corners",
            tuple((n, "order", why) for n, why in order.dropped),
            "check board.squares and board.lower_left in config.yaml against the print",
        )
    frames = [_graph_frame(r, config) for r in kept]
    T_init = order.T_cam_lidar
    if T_init is None:
        P = np.vstack([r.board.corners_lidar for r in kept])  # type: ignore[union-attr]
        F = np.vstack([r.corners.bearings for r in kept])  # type: ignore[union-attr]
        T_init = upnp(P, F, prefer_front=True)[0].T_cam_points  # corners lie ahead along their rays
    return _Prepared(frames, np.asarray(T_init, dtype=np.float64), results)


#: frame reasons as ``observe.observe_frame`` writes them: "LiDAR: ...; image: ..."
_STAGE_PREFIXES = (("LiDAR: ", "lidar"), ("image: ", "image"))


def frame_issues(frames: Sequence[FrameResult]) -> tuple[tuple[str, str, str], ...]:
    """``(frame, stage, reason)`` of every frame not used: stage ``lidar`` or ``image`` (both when
    both failed), ``pairing`` for a scan or image without its partner, ``frame`` otherwise."""
    out: list[tuple[str, str, str]] = []
    for f in frames:
        if f.used:
            continue
        why = f.reason or "not used"
        if why.startswith("LiDAR: ") or why.startswith("image: "):
            head, sep, tail = why.partition("; image: ")
            parts = [head] + ([f"image: {tail}"] if sep else [])
            for part in parts:
                for prefix, stage in _STAGE_PREFIXES:
                    if part.startswith(prefix):
                        out.append((f.name, stage, part[len(prefix) :]))
        elif f.board is None and f.corners is None and ("has no scan" in why or "has no image" in why):
            out.append((f.name, "pairing", why))
        else:
            out.append((f.name, "frame", why))
    return tuple(out)


def _counts(frames: Sequence[FrameResult], issues: Sequence[tuple[str, str, str]]) -> str:
    n = len(frames)
    by = {s: len({f for f, st, _ in issues if st == s}) for s in ("lidar", "image", "pairing")}
    parts = [f"{n} frame{'s' if n != 1 else ''}"]
    if by["lidar"]:
        parts.append(f"no board in {by['lidar']} scan{'s' if by['lidar'] != 1 else ''}")
    if by["image"]:
        parts.append(f"no corners in {by['image']} image{'s' if by['image'] != 1 else ''}")
    if by["pairing"]:
        parts.append(f"{by['pairing']} without a partner")
    return ", ".join(parts)


def _stage_advice(issues: Sequence[tuple[str, str, str]]) -> str:
    """One line on what to check, from which stage failed most."""
    lidar = sum(1 for _, s, _ in issues if s == "lidar")
    image = sum(1 for _, s, _ in issues if s == "image")
    if not issues:
        return "no frames: put scans in DATA/pcd and images with the same names in DATA/img"
    if image >= lidar:
        return (
            "the image stage found no chessboard: check board.squares (squares, not inner corners) and the "
            "camera section of config.yaml, and that the whole board is in the pictures"
        )
    return (
        "the LiDAR stage found no board: check board.squares, board.square_size and lidar.model in "
        "config.yaml; if the board is in view, narrow the search with board.roi"
    )


def _finish(
    prep: _Prepared, observed: Sequence[FrameResult], config: Config, method: str, sol: BatchSolution
) -> Calibration:
    """The Calibration of one source from a strategy's answer: every frame in input order with its fate."""
    results = dict(prep.results)
    for name, reason in sol.dropped:
        _drop(results, name, reason)
    frames = []
    for r in (results[o.name] for o in observed):
        if r.used:
            stats = sol.per_frame.get(r.name)
            rms = None if stats is None else stats.rms_bearing_error_mrad
            r = dataclasses.replace(
                r, rms_bearing_error_mrad=rms, T_lidar_board_refined=sol.T_lidar_board.get(r.name)
            )
        frames.append(r)
    diagnostics = {
        "iterations": float(sol.iterations),
        "variance_factor": sol.variance_factor,
        "variance_component_board": sol.variance_components[0],
        "variance_component_bearing": sol.variance_components[1],
        "upnp_rotation_deg": rotation_angle_deg(prep.T_init[:3, :3].T @ sol.T_cam_lidar[:3, :3]),
    }
    cam = config.camera.to_dict()
    return Calibration(
        sol.T_cam_lidar, sol.covariance, tuple(frames), method, diagnostics, cam, _sensors(sol, config)
    )


def _sensors(sol: BatchSolution, config: Config) -> dict:
    """``Calibration.sensors`` of a strategy's answer: the LiDAR's errors and the camera's intrinsics."""
    out: dict = {}
    lay = sol.lidar_layout
    if sol.lidar is not None or (lay is not None and lay.excluded):
        names, values, sigmas = sol.lidar if sol.lidar is not None else ([], np.zeros(0), np.zeros(0))
        left = [] if lay is None else [list(x) for x in lay.excluded]
        out["lidar_errors"] = {"names": list(names), "values": values, "sigmas": sigmas, "left_out": left}
    if sol.intrinsics is not None:
        names, values, sigmas = sol.intrinsics
        stated = config.camera.intrinsics()
        out["camera_intrinsics"] = {
            "names": list(names),
            "stated": stated,
            "values": values,
            "sigmas": sigmas,
        }
    return out


def _rms_bearing_mrad(T_cam_lidar: np.ndarray, f: GraphFrame) -> float:
    """RMS angle (mrad) between measured bearings and the corners predicted through T."""
    T = T_cam_lidar @ f.T_lidar_board
    p = f.points_board @ T[:3, :3].T + T[:3, 3]
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    ang = np.arctan2(np.linalg.norm(np.cross(p, f.bearings), axis=1), np.sum(p * f.bearings, axis=1))
    return float(1e3 * np.sqrt(np.mean(ang**2)))


def solve_observed(
    observed: Sequence[FrameResult], config: Config, options: RunOptions = RunOptions()
) -> Calibration:
    """Batch (``graph``) or the paper's refinement on observed frames: order, start, solve.

    Raises CalibrationImpossible when no frame has the board in both sensors.
    """
    prep = _prepare(observed, config)
    if options.mode == "paper":
        T = refine_paper(prep.frames, prep.T_init, R_pano_cam=config.camera.R_flu_cam)
        if len(prep.frames) < 4:
            log.warning("only %d usable frame(s); at least 4 are advised", len(prep.frames))
        stats = {
            f.name: BoardStats(math.nan, 2 * len(f.bearings), _rms_bearing_mrad(T, f)) for f in prep.frames
        }
        sol = BatchSolution(T, np.full((6, 6), np.nan), {}, stats, [], 0)
        return _finish(prep, observed, config, "paper", sol)
    sol = solve_batch(
        prep.frames, config.camera, prep.T_init, options.noise, options.lidar_errors, options.intrinsics
    )
    return _finish(prep, observed, config, "graph", sol)


# ----------------------------------------------------------------------------------------------
# The modes


def _incremental(
    source: FrameSource, options: RunOptions, report: Callable[[FrameUpdate], None] | None
) -> RunResult:
    """Frames observed one at a time and fed to iSAM2; the last update is the batch answer."""
    config = source.config()  # the config's mistakes first, then the folders'
    refs = source.frames()
    config = resolve_lidar(source, refs, config)
    config, known = check_board_colour(source, refs, config, options.stages.image)
    cal = IncrementalCalibrator(
        config.camera, config.board, target_sigma=options.target_sigma, noise=options.noise,
        lidar_errors=options.lidar_errors, intrinsics=options.intrinsics,
    )  # fmt: skip
    observed: list[FrameResult] = []
    updates: list[FrameUpdate] = []

    stream = (observe_frame(source, r, config, options.stages, known.get(r.name)) for r in refs)
    for fr in stream:
        observed.append(fr)
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
        _prepare(observed, config)  # no frame reached the calibrator: raises with every frame's reason
    final = cal.finish()
    updates.append(final)
    if report is not None:
        report(final)
    results = {f.name: f for f in observed}
    for name in cal.flipped:  # the corner order the calibrator chose
        f = results[name]
        results[name] = dataclasses.replace(
            f, corners=_permute_corners(f.corners, config.board.half_turn_permutation())
        )  # type: ignore[arg-type]
    offered = {f.name for f in cal.offered}
    prep = _Prepared(cal.offered, np.asarray(final.T_cam_lidar), results)
    sol = final.solution
    assert sol is not None
    not_offered = [(f.name, "not offered") for f in observed if f.used and f.name not in offered]
    calib = _finish(
        prep, observed, config, "incremental", dataclasses.replace(sol, dropped=sol.dropped + not_offered)
    )
    obs = Observation(source, config, observed)
    return RunResult(
        "incremental", calib, (SessionResult(source.label, obs, calib),), options, updates=tuple(updates)
    )


def _sessions(observations: Sequence[Observation], names: Sequence[str], options: RunOptions) -> RunResult:
    """Sources as sessions of one mount, through the sessions strategy."""
    preps = [_prepare(o.frames, o.config) for o in observations]
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
        results.append(SessionResult(n, o, _finish(p, o.frames, o.config, method, part)))
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
    return solve_observations(observations, dataclasses.replace(options, mode=mode), names)


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
    result = _solve_once(observations, options, names)
    if not options.second_pass:
        return result
    again = [second_pass(s.observation, s.calibration, options.stages) for s in result.sessions]
    if all(a is None for a in again):
        return result
    observations = [o if a is None else a for o, a in zip(observations, again, strict=True)]
    return _solve_once(observations, options, names)


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
