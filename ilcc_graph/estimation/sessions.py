"""Sessions strategy: several data sets of one LiDAR-camera mount calibrated together.

Each session is one source of the one solve every calibration goes through (``sources.solve_sources``:
the sensor model chosen once for all sessions, each session solved alone under it by the core's
noise policy: gate, variance components, final factor). A single source is the one-session case
(``batch.solve``). With each session's noise, kept frames and LiDAR terms fixed as its own solve
found them (a moved mount must not read as outlier frames or inflate the noise the tests use):

- ``rigid``: all sessions on one extrinsic, the LiDAR's own errors (``L(l)``, ``O(l)``) one set per
  LiDAR label, shared by its sessions (a term enters when some session's own solve determined it);
- ``alone``: each session's own solve; ``others``: the rest jointly (leave one out);
- chi-square tests (``consistency``): each session against the others, consecutive sessions, all
  against one mount;
- ``drift`` mode: one extrinsic per session, tied to a common mount (``star``) or to the next
  session (``chain``) by ``BetweenFactorPose3`` with a chosen sigma.

Poses and covariances follow interface.md (``T_cam_lidar``, right-tangent, rotation first).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation.batch import BatchSolution, batch_solution, sensor_models
from ilcc_graph.estimation.consistency import (
    ConsistencyTest,
    compare_estimates,
    consistency_test,
    session_tests,
)
from ilcc_graph.estimation.graphs import board_face_samples, upnp_start
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.keys import POSE3_DOF
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions, LidarLayout, merge_layouts
from ilcc_graph.estimation.noise import NoiseOptions, Solution, replace_scales, solve_problem
from ilcc_graph.estimation.problem import Problem, Tie, frames_problem, merge_problems
from ilcc_graph.estimation.selection import Selection, SensorModel, mixture
from ilcc_graph.estimation.solver import check_pose
from ilcc_graph.estimation.sources import Chosen, solve_sources
from ilcc_graph.types import Estimate, GraphFrame

__all__ = [
    "ConsistencyTest",
    "JointOptions",
    "JointSolution",
    "RangeOffset",
    "Session",
    "compare_estimates",
    "own_part",
    "session_part",
    "solve_sessions",
]

MODES = ("rigid", "drift")
DRIFT_TIES = ("star", "chain")


@dataclass(frozen=True)
class Session:
    """One calibration session (a data set): its frames, camera and LiDAR.

    name: unique label. frames: ``GraphFrame`` per board placement (corners in the order used).
    camera: this session's camera model. T_init: (4, 4) start, None for UPnP on the frames.
    lidar: LiDAR unit label; sessions with the same label share one range-offset variable.
    board: this session's board (its face is what the LiDAR fit averages over, for the range
    offset); None: a grid over the corners' rectangle grown by one square.
    """

    name: str
    frames: Sequence[GraphFrame]
    camera: CameraModel
    T_init: np.ndarray | None = None
    lidar: str = "lidar"
    board: Board | None = None


@dataclass(frozen=True)
class JointOptions:
    """How sessions are joined.

    mode: ``"rigid"`` (one extrinsic) or ``"drift"`` (one per session, tied by between-factors).
    drift_sigma_deg, drift_sigma_mm: per-axis sigma of the tie (rotation, translation).
    drift_tie: ``"star"`` (each session tied to a common mount, the joint extrinsic) or ``"chain"``
        (session k to session k+1 in the given order; the joint extrinsic is the last session's).
    alpha: significance of the consistency tests (false-alarm probability of the global test).
    repeatability_deg, repeatability_mm: per-axis sigma of a session-to-session scatter that the
        frames' covariances do not describe; added to each session's covariance in the tests only.
    range_offset: estimate a range offset per LiDAR label. range_offset_prior_sigma_m: its weak prior.
    noise: the core's noise policy (gate, variance components, robust kernel).
    lidar_errors: the LiDAR's own errors to estimate from the boards' returns, per LiDAR label.
    intrinsics: refine the sessions' camera intrinsics, or propagate their stated sigmas.
    models: the sensor models to choose among (``selection.MODELS`` names; one forces it; None:
        ``beams`` with ``lidar_errors``, else ``none``, as ``batch.sensor_models``); with
        ``range_offset`` the ``offset`` model (with ``lidar_errors`` when given) is forced.
    intrinsics_choice: ``stated`` or ``auto`` (refined when every session's boards support it).
    """

    mode: str = "rigid"
    drift_sigma_deg: float = 0.1
    drift_sigma_mm: float = 2.0
    drift_tie: str = "star"
    alpha: float = 0.01
    repeatability_deg: float = 0.0
    repeatability_mm: float = 0.0
    range_offset: bool = False
    range_offset_prior_sigma_m: float = 0.1
    noise: NoiseOptions = NoiseOptions()
    lidar_errors: LidarErrorOptions | None = None
    intrinsics: IntrinsicsOptions | None = None
    models: tuple[str, ...] | None = None
    intrinsics_choice: str = "stated"

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"JointOptions.mode must be one of {MODES}, got {self.mode!r}")
        if self.drift_tie not in DRIFT_TIES:
            raise ValueError(f"JointOptions.drift_tie must be one of {DRIFT_TIES}, got {self.drift_tie!r}")
        if not (self.drift_sigma_deg > 0 and self.drift_sigma_mm > 0):
            raise ValueError("JointOptions.drift_sigma_deg and drift_sigma_mm must be > 0")
        if self.repeatability_deg < 0 or self.repeatability_mm < 0:
            raise ValueError("JointOptions.repeatability_deg and repeatability_mm must be >= 0")
        if not 0 < self.alpha < 1:
            raise ValueError(f"JointOptions.alpha must be in (0, 1), got {self.alpha!r}")
        if not self.range_offset_prior_sigma_m > 0:
            raise ValueError("JointOptions.range_offset_prior_sigma_m must be > 0")


@dataclass(frozen=True)
class RangeOffset:
    """A LiDAR's estimated range offset ``b`` (measured minus true range), metres, with its sigma."""

    lidar: str
    value_m: float
    sigma_m: float


@dataclass(frozen=True)
class JointSolution:
    """The joint answer.

    mode: as asked. joint: the joint extrinsic (rigid: the one; drift: the common mount, or the
    last session's with a chain). sessions: each session's extrinsic in the joint graph (rigid: all
    the joint one). alone: each session on its own (under the joint noise). global_test: the alone
    estimates against one mount (6 (S-1) dof). session_tests: each session alone against all others
    jointly (6 dof). pair_tests: consecutive sessions alone against each other. moved: the session
    that most likely differs when the global test fails, else None. range_offsets: per LiDAR label
    (when asked). dropped: per session the frames the gate dropped. components: per session the
    (board priors, bearings) variance components (bearings: the median over its views when each
    view has its own); scales: every variance component by (kind, noise group), the final factor
    folded in. uncertain: the components estimated (key: redundancy), whose uncertainty the
    covariances carry (``noise`` step 5). variance_factor: the final factor.
    T_lidar_board: per session the refined board poses of the kept frames. per_frame: per session
    the kept frames' residual statistics (``noise.BoardStats``). lidar_errors: per LiDAR label
    (names, values, sigmas) of its own errors when estimated; lidar_layouts: their layouts (what
    entered, what was left out and why). selection: the sensor model chosen for all sessions and the
    evidence. solution: the final joint solve (its LiDAR terms, boards, components). own: each
    session's own solve under the chosen model (``alone``; its boards named ``session/frame``).
    """

    mode: str
    joint: Estimate
    sessions: dict[str, Estimate]
    alone: dict[str, Estimate]
    global_test: ConsistencyTest | None
    session_tests: list[ConsistencyTest]
    pair_tests: list[ConsistencyTest]
    moved: str | None
    range_offsets: dict[str, RangeOffset]
    dropped: dict[str, list[tuple[str, str]]]
    iterations: int = 0
    components: dict[str, tuple[float, float]] = field(default_factory=dict)
    variance_factor: float = 1.0
    scales: dict[tuple[str, str], float] = field(default_factory=dict)
    uncertain: dict[tuple[str, str], float] = field(default_factory=dict)
    T_lidar_board: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    per_frame: dict[str, dict] = field(default_factory=dict)
    lidar_errors: dict[str, tuple] = field(default_factory=dict)
    lidar_layouts: dict[str, LidarLayout] = field(default_factory=dict)
    selection: Selection | None = None
    solution: Solution | None = None
    own: dict[str, Solution] = field(default_factory=dict)


def _bases(sessions: Sequence[Session], labels: list[str]) -> list[Problem]:
    """Each session's problem without sensor terms as the batch strategy's (extrinsic 0), its name the
    noise group and the boards' prefix, its LiDAR's index among ``labels``."""
    out = []
    for s in sessions:
        frames = list(s.frames)
        if not frames:
            raise CalibrationImpossible(f"session {s.name!r} has no frame")
        T0 = upnp_start(frames) if s.T_init is None else np.asarray(s.T_init, dtype=np.float64)
        samples = None if s.board is None else board_face_samples(s.board)
        p = frames_problem(
            frames, s.camera, T0, s.name, 0, labels.index(s.lidar), samples, prefix=f"{s.name}/"
        )
        out.append(replace(p, lidar_names=tuple(labels)))
    return out


def _models(options: JointOptions) -> list[SensorModel]:
    """The candidate sensor models (``JointOptions.models``; the range offset forces its own)."""
    if options.range_offset:
        sigma = options.range_offset_prior_sigma_m
        return [SensorModel("offset", options.lidar_errors, sigma, "one range offset per LiDAR")]
    return sensor_models(options.models, options.lidar_errors)


@dataclass
class _Sub:
    """Sub-problems of the sessions solved under the noise each session's own solve found (its
    components with its final factor folded in, no gate, the LiDAR terms some session of the
    sub-problem determined with each such session's prior, the components' uncertainty as there):
    ``sep`` every session on its own extrinsic, ``kept`` each session's kept boards, ``layouts`` each
    session's LiDAR layouts; ``iterations`` counts every solve's."""

    noise: NoiseOptions
    sep: Problem
    kept: dict[str, list[str]]
    fixed: dict[tuple[str, str], float]
    layouts: dict[str, dict[int, LidarLayout]]
    uncertain: dict[tuple[str, str], float]
    iterations: int

    @classmethod
    def of(cls, alone: Sequence[Solution], names: list[str], noise: NoiseOptions) -> _Sub:
        """From the sessions' own solutions (in the order of ``names``)."""
        first = alone[0].problem
        parts = [s.problem.with_extrinsics({0: si}, {si: s.extrinsic(0).T}) for si, s in enumerate(alone)]
        sep = merge_problems(parts, range_offset_sigma_m=first.range_offset_sigma_m,
                             lidar_names=first.lidar_names, lidar_errors=first.lidar_errors,
                             intrinsics=first.intrinsics)  # fmt: skip
        fixed: dict[tuple[str, str], float] = {}
        uncertain: dict[tuple[str, str], float] = {}
        for s in alone:
            fixed.update(replace_scales(s, s.variance_factor))
            uncertain.update(s.uncertain)
        kept = {n: [s.problem.boards[i].name for i in s.boards] for n, s in zip(names, alone, strict=True)}
        layouts = {n: dict(s.assembly.layouts) for n, s in zip(names, alone, strict=True)}
        return cls(noise, sep, kept, fixed, layouts, uncertain, sum(s.iterations for s in alone))

    def __call__(self, problem: Problem, names: Sequence[str], start: dict) -> Solution:
        """``problem`` on the kept boards of the sessions ``names``."""
        per: dict[int, list[LidarLayout]] = {}
        for n in names:
            for lid, lay in self.layouts[n].items():
                per.setdefault(lid, []).append(lay)
        s = solve_problem(
            problem, self.noise, boards=[b for n in names for b in self.kept[n]], scales=self.fixed,
            variance_factor=1.0, gate=False, start=start, uncertain=self.uncertain,
            layouts={lid: merge_layouts(lays) for lid, lays in per.items()},
        )  # fmt: skip
        self.iterations += s.iterations
        return s

    def rigid(self, start: Estimate, names: Sequence[str] | None = None) -> Solution:
        """All sessions (or ``names``) on one extrinsic ``X(0)``, started at ``start``."""
        rigid = self.sep.with_extrinsics({e: 0 for e in self.sep.T_init}, {0: start.T})
        return self(rigid, list(self.kept) if names is None else names, {0: start.pose})


def solve_sessions(sessions: Sequence[Session], options: JointOptions = JointOptions()) -> JointSolution:
    """Calibrate several sessions of one LiDAR-camera mount together (see the module docstring).

    Raises ValueError (bad options or session names), CalibrationImpossible (a session has no usable
    frame), IndeterminateSystem (the data do not determine an extrinsic).
    """
    names = [s.name for s in sessions]
    if not names:
        raise CalibrationImpossible("no session given")
    if len(set(names)) != len(names):
        raise ValueError(f"session names must be unique, got {names}")
    labels = list(dict.fromkeys(s.lidar for s in sessions))
    got = solve_sources(_bases(sessions, labels), _models(options), options.noise, options.intrinsics,
                        options.intrinsics_choice)  # fmt: skip
    sub = _Sub.of(got.chosen, names, options.noise)
    for n, k in sub.kept.items():
        if not k:
            raise CalibrationImpossible(f"session {n!r} has no usable frame left")
    alone = {n: _covariance(got, si, s.extrinsic(0)) for si, (n, s) in enumerate(zip(names, got.chosen))}
    sol = sub.rigid(alone[names[0]])
    T_rigid = _joint_covariance(got, names, sol.extrinsic(0), options.noise)
    Q = np.diag(
        [math.radians(options.repeatability_deg) ** 2] * 3 + [(1e-3 * options.repeatability_mm) ** 2] * 3
    )
    others = lambda n: sub.rigid(T_rigid, [m for m in names if m != n]).extrinsic(0)  # noqa: E731
    tests, global_test = session_tests(names, others, T_rigid, alone, Q, options.alpha)
    pair_tests = []
    for a, b in zip(names[:-1], names[1:]):
        delta, C = compare_estimates(alone[a], alone[b])
        m = float(delta @ np.linalg.solve(C + 2.0 * Q, delta))
        pair_tests.append(consistency_test(f"{a} -> {b}", b, delta, m, POSE3_DOF, options.alpha, "pair"))
    final = sol
    if options.mode == "rigid":
        joint, per_session = T_rigid, {n: T_rigid for n in names}
    else:
        final, joint, per_session = _drift(sub.sep, names, T_rigid, alone, options, sub)
    range_offsets = {}
    if final.problem.range_offset_sigma_m is not None:
        for lid, lab in enumerate(sub.sep.lidar_names):
            v, s = final.offset(lid)
            range_offsets[lab] = RangeOffset(lab, v, s)
    moved = None
    if global_test is not None and global_test.moved and tests:
        moved = max(tests, key=lambda t: t.mahalanobis).session
    dropped, boards_out, stats_out = _per_session(sub.sep, names, got.chosen, final)
    return JointSolution(
        mode=options.mode, joint=joint, sessions=per_session, alone=alone, global_test=global_test,
        session_tests=tests, pair_tests=pair_tests, moved=moved, range_offsets=range_offsets,
        dropped=dropped, iterations=sub.iterations, components={n: sol.components(n) for n in names},
        variance_factor=sol.variance_factor, scales=dict(sub.fixed), uncertain=dict(sub.uncertain),
        T_lidar_board=boards_out, per_frame=stats_out,
        lidar_errors={lab: e for lid, lab in enumerate(sub.sep.lidar_names) if (e := final.lidar(lid))},
        lidar_layouts={sub.sep.lidar_names[lid]: lay for lid, lay in sol.assembly.layouts.items()},
        selection=got.selection, solution=final, own=dict(zip(names, got.chosen)),
    )  # fmt: skip


def _held_out_factor(got: Chosen) -> float:
    """The chosen model's held-out factor (covariances of refined intrinsics are scaled by it)."""
    return got.selection.factor


def _covariance(got: Chosen, si: int, est: Estimate) -> Estimate:
    """Session ``si``'s own estimate with its covariance as ``calibrate`` of it alone gives it: times
    the held-out factor with refined intrinsics, else (a choice made) the mixture over the models by
    the weights its own boards give (``Chosen.own``; one model weighing: its covariance times its
    held-out factor)."""
    if got.refined:
        return Estimate(est.T, _held_out_factor(got) * est.covariance)
    sel = replace(got.own[si], chosen=got.selection.chosen) if got.own else got.selection
    if sel.forced:
        return est
    models = {n: (s.extrinsic(0).T, s.extrinsic(0).covariance) for n, s in got.sols[si].items()}
    return Estimate(est.T, mixture(models, sel))


def _joint_covariance(got: Chosen, names: list[str], est: Estimate, noise: NoiseOptions) -> Estimate:
    """The rigid joint estimate with its covariance treated as ``_covariance`` treats a session's (the
    other models' joint answers solved as the chosen one's)."""
    if got.refined:
        return Estimate(est.T, _held_out_factor(got) * est.covariance)
    sel = got.selection
    if sel.forced:
        return est
    models = {sel.chosen: (est.T, est.covariance)}
    for name in sel.carried():
        if name != sel.chosen and all(name in s for s in got.sols):
            other = _Sub.of([s[name] for s in got.sols], names, noise).rigid(est).extrinsic(0)
            models[name] = (other.T, other.covariance)
    return Estimate(est.T, mixture(models, sel))


def _drift(
    sep: Problem,
    names: list[str],
    T_rigid: Estimate,
    alone: dict[str, Estimate],
    options: JointOptions,
    sub: _Sub,
) -> tuple[Solution, Estimate, dict[str, Estimate]]:
    """The sessions' extrinsics tied by drift (a star about a common mount, or a chain): the
    solution, the joint extrinsic (the hub's) and each session's."""
    S = len(names)
    sig = tuple([math.radians(options.drift_sigma_deg)] * 3 + [1e-3 * options.drift_sigma_mm] * 3)
    init = {si: alone[n].T for si, n in enumerate(names)}
    if options.drift_tie == "star":
        hub = S
        init[hub] = T_rigid.T
        ties = [Tie(hub, si, sig) for si in range(S)]
    else:
        hub = S - 1
        ties = [Tie(si, si + 1, sig) for si in range(S - 1)]
    drift = sep.with_ties(ties, init)
    final = sub(drift, names, {e: check_pose(T, "") for e, T in init.items()})
    return final, final.extrinsic(hub), {n: final.extrinsic(si) for si, n in enumerate(names)}


def _per_session(
    sep: Problem, names: list[str], alone: Sequence[Solution], final: Solution
) -> tuple[dict[str, list[tuple[str, str]]], dict[str, dict[str, np.ndarray]], dict[str, dict]]:
    """Per session: the frames its own solve's gate dropped (frame, why), and the kept frames'
    refined board poses and residual statistics in the ``final`` solve, by frame name."""
    dropped: dict[str, list[tuple[str, str]]] = {n: [] for n in names}
    for full, why in (d for s in alone for d in s.dropped):
        n, frame = _split(sep, sep.index(full))
        dropped[n].append((frame, why))
    boards_out: dict[str, dict[str, np.ndarray]] = {n: {} for n in names}
    stats_out: dict[str, dict] = {n: {} for n in names}
    for i in final.boards:
        n, frame = _split(sep, i)
        boards_out[n][frame] = final.board_pose(i)
        stats_out[n][frame] = final.stats[i]
    return dropped, boards_out, stats_out


def _split(problem: Problem, board: int) -> tuple[str, str]:
    """(session, frame name) of a board named ``session/frame``."""
    b = problem.boards[board]
    return b.group, b.name[len(b.group) + 1 :]


def session_part(sol: JointSolution, name: str) -> BatchSolution:
    """Session ``name``'s part of the joint answer as the batch strategy's answer: its extrinsic, its
    boards, the LiDAR's own errors of its LiDAR (estimated with every session of that LiDAR), the
    sensor model chosen (``run.finish.from_batch`` turns it into a calibration)."""
    final = sol.solution
    if final is None:
        raise ValueError("session_part: the joint solution carries no final solve")
    lid = next(b.lidar for b in final.problem.boards if b.group == name)
    view = next(j for j, v in enumerate(final.problem.views) if v.group == name)
    points = any(final.problem.boards[i].group == name for i in final.assembly.points if i in final.boards)
    est = sol.sessions[name]
    return BatchSolution(
        T_cam_lidar=est.T, covariance=est.covariance, T_lidar_board=sol.T_lidar_board[name],
        per_frame=sol.per_frame[name], dropped=list(sol.dropped[name]), iterations=sol.iterations,
        variance_factor=sol.variance_factor, variance_components=sol.components[name],
        lidar=final.lidar(lid), lidar_layout=final.assembly.layouts.get(lid),
        intrinsics=final.intrinsics(final.assembly.camera_of(view)),
        lidar_covariance=final.lidar_covariance(lid),
        board_plane=final.board_plane(name) if points else None, selection=sol.selection,
    )  # fmt: skip


def own_part(sol: JointSolution, name: str) -> BatchSolution:
    """Session ``name``'s own solve (``JointSolution.own``, the model chosen for all) as the batch
    strategy's answer of that session alone: what ``calibrate`` of the session alone under that model
    gives (its covariance as ``alone``'s), boards named by frame."""
    n = len(name) + 1
    part = batch_solution(sol.own[name], group=name)
    return replace(
        part, covariance=sol.alone[name].covariance, selection=sol.selection,
        T_lidar_board={k[n:]: v for k, v in part.T_lidar_board.items()},
        per_frame={k[n:]: v for k, v in part.per_frame.items()},
        dropped=[(k[n:], why) for k, why in part.dropped],
    )  # fmt: skip
