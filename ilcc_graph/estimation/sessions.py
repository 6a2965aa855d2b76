"""Sessions strategy: several data sets of one LiDAR-camera mount calibrated together.

All sessions go into one problem (board and bearing noise groups per session, a range offset per
LiDAR label when asked) and through the core's noise policy once, in ``rigid`` form (one extrinsic):
that decides the kept frames and each session's variance components. With that noise fixed:

- ``alone``: each session on its own extrinsic; ``others``: the rest jointly (leave one out);
- chi-square tests: each session against the others, consecutive sessions, all against one mount;
- ``drift`` mode: one extrinsic per session, tied to a common mount (``star``) or to the next
  session (``chain``) by ``BetweenFactorPose3`` with a chosen sigma.

Poses and covariances follow interface.md (``T_cam_lidar``, right-tangent, rotation first).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation.graphs import board_face_samples, upnp_start
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.keys import POSE3_DOF
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions, LidarLayout
from ilcc_graph.estimation.noise import NoiseOptions, Solution, replace_scales, solve_problem
from ilcc_graph.estimation.problem import Problem, Tie, frames_problem, merge_problems
from ilcc_graph.estimation.solver import check_pose
from ilcc_graph.types import Estimate, GraphFrame

from . import chi2 as chi2_dist

__all__ = [
    "ConsistencyTest",
    "JointOptions",
    "JointSolution",
    "RangeOffset",
    "Session",
    "compare_estimates",
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
class ConsistencyTest:
    """Is ``session``'s extrinsic the same as the reference's?

    label: what was compared (``"B vs others"``, ``"A -> B"``, ``"all sessions"``).
    session: the session under test (None for the global test).
    delta: (6,) ``Logmap(T_ref^-1 T_session)``, rotation first (rad, m); zeros for the global test.
    rotation_deg, translation_mm: size of ``delta``.
    mahalanobis: ``delta^T C^-1 delta`` (C the covariance of the difference), or the global sum.
    dof: degrees of freedom of its chi-square law when nothing moved. p_value: chance of a value at
    least this large when nothing moved. moved: ``p_value < alpha``.
    kind: ``"global"``, ``"session"`` (one session against the others) or ``"pair"`` (consecutive).
    """

    label: str
    session: str | None
    delta: np.ndarray
    rotation_deg: float
    translation_mm: float
    mahalanobis: float
    dof: int
    p_value: float
    moved: bool
    kind: str = "pair"


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
    entered, what was left out and why).
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


def compare_estimates(ref: Estimate, other: Estimate) -> tuple[np.ndarray, np.ndarray]:
    """``delta = Logmap(T_ref^-1 T_other)`` (6,) and its covariance (6, 6) for independent estimates.

    With ``T_ref * Expmap(a)`` and ``T_other * Expmap(c)`` the difference is
    ``D * Expmap(c - Ad(D^-1) a)`` (first order), ``D = T_ref^-1 T_other``, so
    ``C = Ad(D^-1) P_ref Ad(D^-1)^T + P_other``.
    """
    import gtsam

    D = ref.pose.between(other.pose)
    delta = np.asarray(gtsam.Pose3.Logmap(D), dtype=np.float64)
    Ad = D.inverse().AdjointMap()
    C = Ad @ ref.covariance @ Ad.T + other.covariance
    return delta, 0.5 * (C + C.T)


def _test(
    label: str, session: str | None, delta: np.ndarray, m: float, dof: int, alpha: float, kind: str
) -> ConsistencyTest:
    p = float(chi2_dist.sf(m, dof))
    return ConsistencyTest(
        label=label,
        session=session,
        delta=delta,
        rotation_deg=float(np.degrees(np.linalg.norm(delta[:3]))),
        translation_mm=float(1e3 * np.linalg.norm(delta[3:])),
        mahalanobis=float(m),
        dof=dof,
        p_value=p,
        moved=p < alpha,
        kind=kind,
    )


def _session_problem(sessions: Sequence[Session], options: JointOptions) -> Problem:
    """All sessions in one problem: extrinsic ``si`` and noise group ``name`` per session."""
    labels = list(dict.fromkeys(s.lidar for s in sessions))
    parts = []
    for si, s in enumerate(sessions):
        frames = list(s.frames)
        if not frames:
            raise CalibrationImpossible(f"session {s.name!r} has no frame")
        T0 = upnp_start(frames) if s.T_init is None else np.asarray(s.T_init, dtype=np.float64)
        samples = None if s.board is None else board_face_samples(s.board)
        parts.append(
            frames_problem(
                frames, s.camera, T0, s.name, si, labels.index(s.lidar), samples, prefix=f"{s.name}/"
            )
        )
    sigma = options.range_offset_prior_sigma_m if options.range_offset else None
    return merge_problems(
        parts,
        range_offset_sigma_m=sigma,
        lidar_names=tuple(labels),
        lidar_errors=options.lidar_errors,
        intrinsics=options.intrinsics,
    )


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
    S = len(sessions)
    sep = _session_problem(sessions, options)
    rigid = sep.with_extrinsics({si: 0 for si in range(S)}, {0: sep.T_init[0]})
    # the gate and the noise are judged with each session on its own mount: a moved mount must
    # not read as outlier frames or inflate the noise that the consistency tests then use
    noise_sol = solve_problem(sep, options.noise)
    iterations = noise_sol.iterations
    kept: dict[str, list[str]] = {n: [] for n in names}
    for i in noise_sol.boards:
        kept[sep.boards[i].group].append(sep.boards[i].name)
    for n, k in kept.items():
        if not k:
            raise CalibrationImpossible(f"session {n!r} has no usable frame left")
    fixed = replace_scales(noise_sol, noise_sol.variance_factor)
    sub = _Sub(options.noise, fixed, noise_sol, iterations)
    all_kept = [b for n in names for b in kept[n]]
    sol = sub(rigid, all_kept, {0: noise_sol.extrinsic(0).pose})
    T_rigid = sol.extrinsic(0)

    alone_sol = {n: sub(sep, kept[n], {si: T_rigid.pose}) for si, n in enumerate(names)}
    alone = {n: alone_sol[n].extrinsic(si) for si, n in enumerate(names)}
    Q = np.diag(
        [math.radians(options.repeatability_deg) ** 2] * 3 + [(1e-3 * options.repeatability_mm) ** 2] * 3
    )
    session_tests, global_test = _session_tests(names, kept, rigid, T_rigid, alone, Q, options.alpha, sub)
    pair_tests = []
    for a, b in zip(names[:-1], names[1:]):
        delta, C = compare_estimates(alone[a], alone[b])
        m = float(delta @ np.linalg.solve(C + 2.0 * Q, delta))
        pair_tests.append(_test(f"{a} -> {b}", b, delta, m, POSE3_DOF, options.alpha, "pair"))

    final = sol
    if options.mode == "rigid":
        joint, per_session = T_rigid, {n: T_rigid for n in names}
    else:
        final, joint, per_session = _drift(sep, names, kept, T_rigid, alone, options, sub)
    range_offsets = {}
    if options.range_offset:
        for lid, lab in enumerate(sep.lidar_names):
            v, s = final.offset(lid)
            range_offsets[lab] = RangeOffset(lab, v, s)
    moved = None
    if global_test is not None and global_test.moved and session_tests:
        moved = max(session_tests, key=lambda t: t.mahalanobis).session
    dropped, boards_out, stats_out = _per_session(sep, names, noise_sol, final)
    return JointSolution(
        mode=options.mode,
        joint=joint,
        sessions=per_session,
        alone=alone,
        global_test=global_test,
        session_tests=session_tests,
        pair_tests=pair_tests,
        moved=moved,
        range_offsets=range_offsets,
        dropped=dropped,
        iterations=sub.iterations,
        components={n: sol.components(n) for n in names},
        variance_factor=sol.variance_factor,
        scales=dict(fixed),
        uncertain=dict(noise_sol.uncertain),
        T_lidar_board=boards_out,
        per_frame=stats_out,
        lidar_errors={
            lab: e for lid, lab in enumerate(sep.lidar_names) if (e := final.lidar(lid)) is not None
        },
        lidar_layouts={sep.lidar_names[lid]: lay for lid, lay in sol.assembly.layouts.items()},
    )


@dataclass
class _Sub:
    """A sub-problem solve under the noise the first solve found (``noise_sol``: its components
    ``fixed`` with its final factor folded in, no gate, its LiDAR layouts); ``iterations`` counts
    every solve's."""

    noise: NoiseOptions
    fixed: dict[tuple[str, str], float]
    noise_sol: Solution
    iterations: int

    def __call__(self, problem: Problem, boards: list[str], start: dict) -> Solution:
        s = solve_problem(problem, self.noise, boards=boards, scales=self.fixed, variance_factor=1.0,
                          gate=False, start=start, layouts=self.noise_sol.assembly.layouts,
                          uncertain=self.noise_sol.uncertain)  # fmt: skip
        self.iterations += s.iterations
        return s


def _session_tests(
    names: list[str],
    kept: dict[str, list[str]],
    rigid: Problem,
    T_rigid: Estimate,
    alone: dict[str, Estimate],
    Q: np.ndarray,
    alpha: float,
    sub: _Sub,
) -> tuple[list[ConsistencyTest], ConsistencyTest | None]:
    """Each session alone against all others jointly, and the global test of the alone estimates
    against one mount (none with one session)."""
    S = len(names)
    session_tests: list[ConsistencyTest] = []
    if S < 2:
        return session_tests, None
    for n in names:
        others = [b for m in names if m != n for b in kept[m]]
        est = sub(rigid, others, {0: T_rigid.pose}).extrinsic(0)
        delta, C = compare_estimates(est, alone[n])
        C = C + Q * (1.0 + 1.0 / (S - 1))  # the joint of S-1 others carries about Q / (S-1) of it
        m = float(delta @ np.linalg.solve(C, delta))
        session_tests.append(_test(f"{n} vs others", n, delta, m, POSE3_DOF, alpha, "session"))
    total = 0.0
    for n in names:
        d = T_rigid.pose.localCoordinates(alone[n].pose)
        total += float(d @ np.linalg.solve(alone[n].covariance + Q, d))
    global_test = _test(
        "all sessions", None, np.zeros(POSE3_DOF), total, POSE3_DOF * (S - 1), alpha, "global"
    )
    return session_tests, global_test


def _drift(
    sep: Problem,
    names: list[str],
    kept: dict[str, list[str]],
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
    final = sub(drift, [b for n in names for b in kept[n]], {e: check_pose(T, "") for e, T in init.items()})
    return final, final.extrinsic(hub), {n: final.extrinsic(si) for si, n in enumerate(names)}


def _per_session(
    sep: Problem, names: list[str], noise_sol: Solution, final: Solution
) -> tuple[dict[str, list[tuple[str, str]]], dict[str, dict[str, np.ndarray]], dict[str, dict]]:
    """Per session: the frames the gate dropped (frame, why), and the kept frames' refined board
    poses and residual statistics, by frame name."""
    dropped: dict[str, list[tuple[str, str]]] = {n: [] for n in names}
    for full, why in noise_sol.dropped:
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
