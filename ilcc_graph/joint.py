"""Joint calibration graphs: several sessions of one mount, a rig of cameras, a LiDAR range offset.

Pure (no file I/O); inputs are ``graph.GraphFrame`` objects and camera models, outputs frozen
dataclasses of numpy arrays. Poses and covariances follow interface.md: ``T_cam_lidar`` (4, 4),
6x6 covariances in GTSAM's right-tangent convention ``T_true = T_est * Expmap(xi)``, rotation first.

Variables: ``X(e)`` extrinsics (``T_cam_lidar`` of session or camera ``e``), ``B(i)`` board poses
``T_lidar_board`` (one per physical board placement, shared by every camera that saw it), ``O(l)``
the range offset of LiDAR ``l`` (Vector1, metres; optional). Factors: per board its LiDAR-stage
prior (``PriorFactorPose3``, or ``factors.RangeOffsetBoardFactor`` with the offset), per view one
grouped bearing factor (``factors.FrameBearingFactor``); in ``drift`` mode ``BetweenFactorPose3``
ties between the session extrinsics.

- ``solve_sessions``: sessions may differ in board, intrinsics and LiDAR. ``rigid`` keeps one
  extrinsic, ``drift`` one per session tied with a chosen sigma. Chi-square tests say whether the
  mount moved between sessions, which session and by how much (see docs/joint.md).
- ``solve_rig``: one extrinsic per camera, camera-to-camera transforms with covariance.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, O, X
from scipy.stats import chi2 as chi2_dist

from factors import POSE3_DOF, FrameBearingFactor
from factors.range_offset import RangeOffsetBoardFactor
from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem
from ilcc_graph.graph import GraphFrame, GraphOptions, frame_bearing_factor, solve
from ilcc_graph.init import upnp

MODES = ("rigid", "drift")
DRIFT_TIES = ("star", "chain")
MIN_CORNERS = 3

__all__ = [
    "ConsistencyTest",
    "Estimate",
    "JointOptions",
    "JointSolution",
    "RangeOffset",
    "RigFrame",
    "RigOptions",
    "RigSolution",
    "RigView",
    "Session",
    "board_face_samples",
    "compare_estimates",
    "relative_pose",
    "solve_rig",
    "solve_sessions",
    "view_factor",
]


# ------------------------------------------------------------------------------------ results
@dataclass(frozen=True)
class Estimate:
    """A pose with its covariance.

    T: (4, 4) the pose (``T_cam_lidar`` unless a name says otherwise).
    covariance: (6, 6) right-tangent covariance (rotation first, rad and m).
    """

    T: np.ndarray
    covariance: np.ndarray

    @property
    def sigmas(self) -> np.ndarray:
        """(6,) standard deviations (rad, rad, rad, m, m, m)."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def pose(self) -> gtsam.Pose3:
        return gtsam.Pose3(self.T)

    def sigma_dict(self) -> dict[str, float]:
        """Sigmas as calibration.yaml writes them: rx_deg .. tz_mm."""
        s = self.sigmas
        names = ("rx_deg", "ry_deg", "rz_deg", "tx_mm", "ty_mm", "tz_mm")
        vals = np.concatenate([np.degrees(s[:3]), 1e3 * s[3:]])
        return {n: float(v) for n, v in zip(names, vals)}


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
    dof: degrees of freedom of the chi-square law of ``mahalanobis`` when nothing moved.
    p_value: chance of a value at least this large when nothing moved.
    moved: ``p_value < alpha``.
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


# ------------------------------------------------------------------------------ small helpers
def board_face_samples(board: Board, n_long: int = 17, n_short: int = 13) -> np.ndarray:
    """(n_long * n_short, 3) grid over the board's physical face (margin included), board frame."""
    x0, x1, y0, y1 = board.extent()
    gx, gy = np.meshgrid(np.linspace(x0, x1, n_long), np.linspace(y0, y1, n_short))
    return np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])


def _samples_from_corners(points_board: np.ndarray, n: int = 13) -> np.ndarray:
    """A grid over the corners' rectangle grown by one corner spacing (a board cut to its pattern)."""
    p = np.asarray(points_board, dtype=np.float64)
    xs, ys = np.unique(np.round(p[:, 0], 9)), np.unique(np.round(p[:, 1], 9))
    sx = float(np.median(np.diff(xs))) if len(xs) > 1 else 0.0
    sy = float(np.median(np.diff(ys))) if len(ys) > 1 else sx
    gx, gy = np.meshgrid(np.linspace(xs[0] - sx, xs[-1] + sx, n), np.linspace(ys[0] - sy, ys[-1] + sy, n))
    return np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])


def view_factor(
    key_cam_lidar: int,
    key_lidar_board: int,
    points_board: np.ndarray,
    bearings: np.ndarray,
    cov_px: np.ndarray,
    camera: CameraModel,
    robust: gtsam.noiseModel.mEstimator.Base | None = None,
) -> FrameBearingFactor | None:
    """One board seen by one camera as a grouped bearing factor; None with too few usable corners
    (``graph.frame_bearing_factor``, as ``graph.solve`` builds it)."""
    return frame_bearing_factor(
        key_cam_lidar, key_lidar_board, points_board, bearings, cov_px, camera, robust, "view"
    )[0]


_KERNELS = {
    "huber": (gtsam.noiseModel.mEstimator.Huber, 1.345),
    "cauchy": (gtsam.noiseModel.mEstimator.Cauchy, 2.3849),
    "tukey": (gtsam.noiseModel.mEstimator.Tukey, 4.6851),
}


def _robust_kernel(name: str) -> gtsam.noiseModel.mEstimator.Base:
    """A per-corner m-estimator at its 95 %-efficiency threshold (thin stand-in for graph's own table)."""
    key = name.lower().replace("-", "_")
    if key not in _KERNELS:
        raise ValueError(f"robust: unknown kernel {name!r}; choose from {sorted(_KERNELS)}")
    cls, k = _KERNELS[key]
    return cls.Create(k)


def _pose(T: np.ndarray | gtsam.Pose3) -> gtsam.Pose3:
    if isinstance(T, gtsam.Pose3):
        return T
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"expected a finite (4, 4) pose, got shape {T.shape}")
    return gtsam.Pose3(gtsam.Rot3(T[:3, :3]), T[:3, 3])


def _upnp_init(points_lidar: np.ndarray, bearings: np.ndarray) -> np.ndarray:
    b = bearings / np.linalg.norm(bearings, axis=1, keepdims=True)
    ok = np.all(np.isfinite(points_lidar), axis=1) & np.all(np.isfinite(b), axis=1)
    if ok.sum() < 4:
        raise CalibrationImpossible("fewer than 4 usable corners to initialise an extrinsic")
    return upnp(points_lidar[ok], b[ok], prefer_front=True)[0].T_cam_points


def compare_estimates(ref: Estimate, other: Estimate) -> tuple[np.ndarray, np.ndarray]:
    """``delta = Logmap(T_ref^-1 T_other)`` (6,) and its covariance (6, 6) for independent estimates.

    With ``T_ref * Expmap(a)`` and ``T_other * Expmap(c)`` the difference is
    ``D * Expmap(c - Ad(D^-1) a)`` (first order), ``D = T_ref^-1 T_other``, so
    ``C = Ad(D^-1) P_ref Ad(D^-1)^T + P_other``.
    """
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


def relative_pose(T_a: np.ndarray, T_b: np.ndarray, joint_cov: np.ndarray) -> Estimate:
    """``T_a * T_b^-1`` with covariance from the 12x12 joint covariance of (``T_a``, ``T_b``).

    For extrinsics ``T_a = T_ca_lidar``, ``T_b = T_cb_lidar`` this is ``T_ca_cb`` (``p_ca = T_ca_cb p_cb``).
    Jacobians (right tangent): ``d/d a = Ad(T_b)``, ``d/d b = -Ad(T_b)``.
    """
    Ta, Tb = _pose(T_a), _pose(T_b)
    Ad = Tb.AdjointMap()
    J = np.hstack([Ad, -Ad])
    C = J @ np.asarray(joint_cov, dtype=np.float64) @ J.T
    return Estimate(np.asarray(Ta.compose(Tb.inverse()).matrix()), 0.5 * (C + C.T))


# ------------------------------------------------------------------------- the general graph
@dataclass
class _Board:
    index: int
    name: str
    prior: gtsam.Pose3
    cov: np.ndarray
    samples: np.ndarray
    lidar: int


@dataclass
class _View:
    ext: int
    board: int
    factor: FrameBearingFactor


@dataclass
class _Problem:
    """Boards, views and ties; extrinsic indices are ``0..n_ext-1``."""

    boards: list[_Board]
    views: list[_View]
    T_init: dict[int, gtsam.Pose3]
    ties: list[tuple[int, int, gtsam.noiseModel.Base]] = field(default_factory=list)
    range_offset: bool = False
    offset_prior_sigma: float = 0.1


def _build(
    problem: _Problem, exts: set[int] | None = None
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Graph and initial values; ``exts`` keeps only the views of those extrinsics (and their boards)."""
    views = [v for v in problem.views if exts is None or v.ext in exts]
    used_boards = {v.board for v in views}
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    lidars: set[int] = set()
    for bd in problem.boards:
        if bd.index not in used_boards:
            continue
        values.insert(B(bd.index), bd.prior)
        if problem.range_offset:
            lidars.add(bd.lidar)
            f = RangeOffsetBoardFactor(B(bd.index), O(bd.lidar), bd.prior, bd.cov, bd.samples)
            graph.add(f.factor())
        else:
            graph.add(
                gtsam.PriorFactorPose3(B(bd.index), bd.prior, gtsam.noiseModel.Gaussian.Covariance(bd.cov))
            )
    for v in views:
        graph.add(v.factor.factor())
    ext_used = {v.ext for v in views}
    for i, j, noise in problem.ties:
        if exts is None or (i in exts and j in exts):
            graph.add(gtsam.BetweenFactorPose3(X(i), X(j), gtsam.Pose3(), noise))
            ext_used |= {i, j}
    for e in sorted(ext_used):
        values.insert(X(e), problem.T_init[e])
    for lid in sorted(lidars):
        values.insert(O(lid), np.zeros(1))
        graph.add(
            gtsam.PriorFactorVector(
                O(lid), np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, problem.offset_prior_sigma)
            )
        )
    return graph, values


def _lm(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int = 100
) -> tuple[gtsam.Values, int]:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    try:
        result = opt.optimize()
    except RuntimeError as exc:
        raise IndeterminateSystem(f"Levenberg-Marquardt failed on an indeterminate system: {exc}") from None
    return result, int(opt.iterations())


@dataclass
class _Solved:
    values: gtsam.Values
    marginals: gtsam.Marginals
    iterations: int

    def estimate(self, e: int) -> Estimate:
        C = np.asarray(self.marginals.marginalCovariance(X(e)), dtype=np.float64)
        return Estimate(
            np.asarray(self.values.atPose3(X(e)).matrix()), _checked_cov(0.5 * (C + C.T), f"X({e})")
        )

    def joint_cov(self, keys: Sequence[int]) -> np.ndarray:
        jm = self.marginals.jointMarginalCovariance(gtsam.KeyVector(list(keys)))
        n = len(keys)
        C = np.zeros((POSE3_DOF * n, POSE3_DOF * n))
        for a, ka in enumerate(keys):
            for b, kb in enumerate(keys):
                C[6 * a : 6 * a + 6, 6 * b : 6 * b + 6] = jm.at(ka, kb)
        return 0.5 * (C + C.T)

    def offset(self, lid: int, name: str) -> RangeOffset:
        v = float(self.values.atVector(O(lid))[0])
        s = float(np.sqrt(np.asarray(self.marginals.marginalCovariance(O(lid)))[0, 0]))
        return RangeOffset(name, v, s)


def _checked_cov(C: np.ndarray, what: str) -> np.ndarray:
    eig = np.linalg.eigvalsh(C)
    if not np.all(np.isfinite(C)) or eig.min() <= 0 or math.sqrt(eig.max()) > 10.0:
        raise IndeterminateSystem(
            f"the data do not determine {what} (covariance eigenvalues {eig.min():.3g} .. {eig.max():.3g})"
        )
    return C


def _solve(problem: _Problem, exts: set[int] | None = None, max_iterations: int = 100) -> _Solved:
    graph, values = _build(problem, exts)
    result, n_it = _lm(graph, values, max_iterations)
    try:
        marg = gtsam.Marginals(graph, result)
    except (RuntimeError, IndexError, ValueError) as exc:
        raise IndeterminateSystem(f"the graph does not determine the extrinsics: {exc}") from None
    return _Solved(result, marg, n_it)


# --------------------------------------------------------------------------------- sessions
@dataclass(frozen=True)
class Session:
    """One calibration session (a data set): its frames, camera and LiDAR.

    name: unique label. frames: ``GraphFrame`` per board placement (board frame of this session's
    board). camera: this session's camera model. T_init: (4, 4) start, None for UPnP on the frames.
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
        frames' covariances do not describe (e.g. stage biases that change with the board placements);
        added to each session's covariance in the consistency tests only (0: trust the covariances).
    range_offset: estimate a range offset per LiDAR label. range_offset_prior_sigma_m: its weak prior.
    graph: options of the per-session pre-solve (``graph.solve``: chi-square gate, robust kernel).
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
    graph: GraphOptions = GraphOptions()


@dataclass(frozen=True)
class JointSolution:
    """The joint answer.

    mode: as asked. joint: the joint extrinsic (rigid: the one; drift: the common mount, or the
    last session's with a chain). sessions: each session's extrinsic in the joint graph (rigid: all
    the joint one). alone: each session solved on its own. global_test: the alone estimates against
    one mount (6 (S-1) dof). session_tests: each session alone against all others jointly (6 dof).
    pair_tests: consecutive sessions alone against each other. moved: the session whose mount most
    likely differs (largest ``session_tests`` statistic) when the global test fails, else None.
    range_offsets: per LiDAR label (when asked). dropped: per session the frames ``graph.solve`` dropped.
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


def _check_options(options: JointOptions) -> None:
    if options.mode not in MODES:
        raise ValueError(f"JointOptions.mode must be one of {MODES}, got {options.mode!r}")
    if options.drift_tie not in DRIFT_TIES:
        raise ValueError(f"JointOptions.drift_tie must be one of {DRIFT_TIES}, got {options.drift_tie!r}")
    if not (options.drift_sigma_deg > 0 and options.drift_sigma_mm > 0):
        raise ValueError("JointOptions.drift_sigma_deg and drift_sigma_mm must be > 0")
    if options.repeatability_deg < 0 or options.repeatability_mm < 0:
        raise ValueError("JointOptions.repeatability_deg and repeatability_mm must be >= 0")
    if not 0 < options.alpha < 1:
        raise ValueError(f"JointOptions.alpha must be in (0, 1), got {options.alpha!r}")
    if not options.range_offset_prior_sigma_m > 0:
        raise ValueError("JointOptions.range_offset_prior_sigma_m must be > 0")


def solve_sessions(sessions: Sequence[Session], options: JointOptions = JointOptions()) -> JointSolution:
    """Calibrate several sessions of one LiDAR-camera mount together.

    Each session is first solved alone with ``graph.solve`` (its chi-square gate drops bad frames;
    the answer initialises the joint graph). Then, on the kept frames: each session alone, each
    session's complement jointly (leave-one-out), and all sessions in ``options.mode``.

    Raises
    ------
    ValueError : bad options or session names. CalibrationImpossible : a session has no usable frame.
    IndeterminateSystem : the data do not determine an extrinsic.
    """
    _check_options(options)
    names = [s.name for s in sessions]
    if not names:
        raise CalibrationImpossible("no session given")
    if len(set(names)) != len(names):
        raise ValueError(f"session names must be unique, got {names}")
    S = len(sessions)
    lidar_ids = {lab: i for i, lab in enumerate(dict.fromkeys(s.lidar for s in sessions))}
    boards: list[_Board] = []
    views: list[_View] = []
    T_init: dict[int, gtsam.Pose3] = {}
    dropped: dict[str, list[tuple[str, str]]] = {}
    for si, sess in enumerate(sessions):
        frames = list(sess.frames)
        if not frames:
            raise CalibrationImpossible(f"session {sess.name!r} has no frame")
        if sess.T_init is None:
            pts = np.vstack(
                [f.points_board @ f.T_lidar_board[:3, :3].T + f.T_lidar_board[:3, 3] for f in frames]
            )
            T0 = _upnp_init(pts, np.vstack([f.bearings for f in frames]))
        else:
            T0 = np.asarray(sess.T_init, dtype=np.float64)
        # an unmodelled range offset would make the gate drop good frames: no gate then
        pre_options = replace(options.graph, chi2_gate_prob=None) if options.range_offset else options.graph
        pre = solve(frames, sess.camera, T0, pre_options)
        dropped[sess.name] = list(pre.dropped)
        # the session's noise, rescaled by its own variance components and factor (as graph.solve
        # reports them); not with a range offset, whose absence from the pre-solve inflates them
        k_board, k_bearing = (
            (1.0, 1.0)
            if options.range_offset
            else (
                pre.variance_components[0] * pre.variance_factor,
                pre.variance_components[1] * pre.variance_factor,
            )
        )
        T_init[si] = _pose(pre.T_cam_lidar)
        gone = {n for n, _ in pre.dropped}
        samples_default = None if sess.board is None else board_face_samples(sess.board)
        for f in frames:
            if f.name in gone:
                continue
            idx = len(boards)
            samples = (
                samples_default if samples_default is not None else _samples_from_corners(f.points_board)
            )
            boards.append(
                _Board(
                    idx,
                    f"{sess.name}/{f.name}",
                    _pose(f.T_lidar_board),
                    k_board * np.asarray(f.board_cov),
                    samples,
                    lidar_ids[sess.lidar],
                )
            )
            fac = view_factor(
                X(si), B(idx), f.points_board, f.bearings, k_bearing * np.asarray(f.cov_px), sess.camera
            )
            if fac is not None:
                views.append(_View(si, idx, fac))
    problem = _Problem(
        boards,
        views,
        T_init,
        range_offset=options.range_offset,
        offset_prior_sigma=options.range_offset_prior_sigma_m,
    )
    iterations = 0

    alone: dict[str, Estimate] = {}
    for si, sess in enumerate(sessions):
        sol = _solve(problem, {si})
        iterations += sol.iterations
        alone[sess.name] = sol.estimate(si)

    def rigid_of(members: list[int]) -> tuple[Estimate, _Solved]:
        """One extrinsic for the sessions in ``members``: remap their views onto X(members[0])."""
        e0 = members[0]
        remapped = [
            _View(e0, v.board, _rekey(v.factor, X(e0))) if v.ext in members else v for v in problem.views
        ]
        sub = _Problem(
            problem.boards, remapped, problem.T_init, [], problem.range_offset, problem.offset_prior_sigma
        )
        sol = _solve(sub, {e0})
        return sol.estimate(e0), sol

    # session-to-session scatter beyond the covariances (JointOptions.repeatability_*); the joint of
    # n others carries about Q / n of it
    Q = np.diag(
        [math.radians(options.repeatability_deg) ** 2] * 3 + [(1e-3 * options.repeatability_mm) ** 2] * 3
    )
    session_tests: list[ConsistencyTest] = []
    global_test = None
    if S >= 2:
        for si, sess in enumerate(sessions):
            others = [j for j in range(S) if j != si]
            est, sol = rigid_of(others)
            iterations += sol.iterations
            delta, C = compare_estimates(est, alone[sess.name])
            C = C + Q * (1.0 + 1.0 / len(others))
            m = float(delta @ np.linalg.solve(C, delta))
            session_tests.append(
                _test(f"{sess.name} vs others", sess.name, delta, m, POSE3_DOF, options.alpha, "session")
            )
    pair_tests = []
    for a, b in zip(sessions[:-1], sessions[1:]):
        delta, C = compare_estimates(alone[a.name], alone[b.name])
        C = C + 2.0 * Q
        m = float(delta @ np.linalg.solve(C, delta))
        pair_tests.append(_test(f"{a.name} -> {b.name}", b.name, delta, m, POSE3_DOF, options.alpha, "pair"))

    rigid_est, rigid_sol = rigid_of(list(range(S)))
    iterations += rigid_sol.iterations
    if S >= 2:
        total = 0.0
        for sess in sessions:
            d = rigid_est.pose.localCoordinates(alone[sess.name].pose)
            total += float(d @ np.linalg.solve(alone[sess.name].covariance + Q, d))
        global_test = _test(
            "all sessions", None, np.zeros(POSE3_DOF), total, POSE3_DOF * (S - 1), options.alpha, "global"
        )

    range_offsets: dict[str, RangeOffset] = {}
    if options.mode == "rigid":
        joint = rigid_est
        per_session = {s.name: rigid_est for s in sessions}
        final = rigid_sol
    else:
        sig = np.array([math.radians(options.drift_sigma_deg)] * 3 + [1e-3 * options.drift_sigma_mm] * 3)
        noise = gtsam.noiseModel.Diagonal.Sigmas(sig)
        init = dict(problem.T_init)
        if options.drift_tie == "star":
            hub = S
            init[hub] = rigid_est.pose
            ties = [(hub, si, noise) for si in range(S)]
        else:
            hub = S - 1
            ties = [(si, si + 1, noise) for si in range(S - 1)]
        sub = _Problem(
            problem.boards, problem.views, init, ties, problem.range_offset, problem.offset_prior_sigma
        )
        final = _solve(sub)
        iterations += final.iterations
        joint = final.estimate(hub)
        per_session = {s.name: final.estimate(si) for si, s in enumerate(sessions)}
    if options.range_offset:
        for lab, lid in lidar_ids.items():
            range_offsets[lab] = final.offset(lid, lab)

    moved = None
    if global_test is not None and global_test.moved and session_tests:
        moved = max(session_tests, key=lambda t: t.mahalanobis).session
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
        iterations=iterations,
    )


def _rekey(f: FrameBearingFactor, key_cam_lidar: int) -> FrameBearingFactor:
    """The same grouped factor on another extrinsic key (shares the arrays)."""
    g = copy.copy(f)
    g.keys = (int(key_cam_lidar), f.keys[1])
    return g


# ------------------------------------------------------------------------------------- rigs
@dataclass(frozen=True)
class RigView:
    """One camera's view of a board.

    camera: the camera's name (key of ``cameras`` in ``solve_rig``).
    bearings: (K', 3) unit bearings, this camera's frame. cov_px: (K', 2, 2) pixel covariances.
    corners: (K',) indices into the frame's ``points_board`` of the corners seen; None: all, in order.
    """

    camera: str
    bearings: np.ndarray
    cov_px: np.ndarray
    corners: np.ndarray | None = None


@dataclass(frozen=True)
class RigFrame:
    """One board placement seen by the LiDAR and by one or more cameras.

    T_lidar_board (4, 4), board_cov (6, 6), points_board (K, 3) as ``graph.GraphFrame``.
    """

    name: str
    T_lidar_board: np.ndarray
    board_cov: np.ndarray
    points_board: np.ndarray
    views: Sequence[RigView]


@dataclass(frozen=True)
class RigOptions:
    """range_offset / range_offset_prior_sigma_m as ``JointOptions``; robust: a ``GraphOptions.robust``
    kernel name or None; samples_board: (M, 3) board-face points for the range offset (None: from corners)."""

    range_offset: bool = False
    range_offset_prior_sigma_m: float = 0.1
    robust: str | None = None
    samples_board: np.ndarray | None = None
    max_iterations: int = 100


@dataclass(frozen=True)
class RigSolution:
    """The rig's answer.

    cameras: camera names in order. extrinsics: ``T_cam_lidar`` per camera. relative: for each
    ordered pair (a, b), a before b in ``cameras``, ``T_ca_cb`` (``p_ca = T_ca_cb p_cb``) with its
    covariance (from the joint marginal). joint_covariance: (6C, 6C) joint covariance of the
    extrinsics in ``cameras`` order. range_offset: when asked. T_lidar_board: refined board poses.
    """

    cameras: tuple[str, ...]
    extrinsics: dict[str, Estimate]
    relative: dict[tuple[str, str], Estimate]
    joint_covariance: np.ndarray
    range_offset: RangeOffset | None
    T_lidar_board: dict[str, np.ndarray]
    iterations: int


def solve_rig(
    frames: Sequence[RigFrame],
    cameras: Mapping[str, CameraModel],
    T_init: Mapping[str, np.ndarray] | None = None,
    options: RigOptions = RigOptions(),
) -> RigSolution:
    """One extrinsic per camera; a board seen by several cameras is one variable.

    T_init: per camera (4, 4) ``T_cam_lidar`` start; missing cameras start from UPnP on their views.
    Raises CalibrationImpossible when a camera has no usable view, IndeterminateSystem when the
    data do not determine an extrinsic.
    """
    names = tuple(cameras)
    cam_index = {n: i for i, n in enumerate(names)}
    robust = None
    if options.robust is not None:
        robust = _robust_kernel(options.robust)
    boards: list[_Board] = []
    views: list[_View] = []
    pts: dict[int, list[np.ndarray]] = {i: [] for i in range(len(names))}
    brs: dict[int, list[np.ndarray]] = {i: [] for i in range(len(names))}
    for f in frames:
        idx = len(boards)
        samples = (
            options.samples_board
            if options.samples_board is not None
            else _samples_from_corners(f.points_board)
        )
        T_lb = _pose(f.T_lidar_board)
        boards.append(_Board(idx, f.name, T_lb, np.asarray(f.board_cov), samples, 0))
        for v in f.views:
            if v.camera not in cam_index:
                raise ValueError(
                    f"frame {f.name!r}: view of unknown camera {v.camera!r}; cameras: {list(names)}"
                )
            ci = cam_index[v.camera]
            p = f.points_board if v.corners is None else f.points_board[np.asarray(v.corners)]
            fac = view_factor(X(ci), B(idx), p, v.bearings, v.cov_px, cameras[v.camera], robust)
            if fac is not None:
                views.append(_View(ci, idx, fac))
                pts[ci].append(np.asarray(T_lb.transformFrom(np.asarray(p).T)).T)
                brs[ci].append(np.asarray(v.bearings))
    init: dict[int, gtsam.Pose3] = {}
    for n, ci in cam_index.items():
        if not pts[ci]:
            raise CalibrationImpossible(f"camera {n!r} has no usable view of a board")
        if T_init is not None and n in T_init:
            init[ci] = _pose(T_init[n])
        else:
            init[ci] = _pose(_upnp_init(np.vstack(pts[ci]), np.vstack(brs[ci])))
    problem = _Problem(
        boards,
        views,
        init,
        range_offset=options.range_offset,
        offset_prior_sigma=options.range_offset_prior_sigma_m,
    )
    sol = _solve(problem, max_iterations=options.max_iterations)
    ext = {n: sol.estimate(ci) for n, ci in cam_index.items()}
    keys = [X(cam_index[n]) for n in names]
    J = sol.joint_cov(keys)
    rel: dict[tuple[str, str], Estimate] = {}
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            Cab = np.zeros((12, 12))
            Cab[:6, :6], Cab[6:, 6:] = (
                J[6 * a : 6 * a + 6, 6 * a : 6 * a + 6],
                J[6 * b : 6 * b + 6, 6 * b : 6 * b + 6],
            )
            Cab[:6, 6:] = J[6 * a : 6 * a + 6, 6 * b : 6 * b + 6]
            Cab[6:, :6] = Cab[:6, 6:].T
            rel[(names[a], names[b])] = relative_pose(ext[names[a]].T, ext[names[b]].T, Cab)
    used = {v.board for v in views}
    return RigSolution(
        cameras=names,
        extrinsics=ext,
        relative=rel,
        joint_covariance=J,
        range_offset=sol.offset(0, "lidar") if options.range_offset else None,
        T_lidar_board={
            bd.name: np.asarray(sol.values.atPose3(B(bd.index)).matrix()) for bd in boards if bd.index in used
        },
        iterations=sol.iterations,
    )
