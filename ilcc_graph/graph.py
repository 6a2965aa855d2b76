"""The extrinsic as a GTSAM factor graph: bearing factors, board priors, LM, marginal covariance.

Variables: ``X(0)`` = ``T_cam_lidar`` (Pose3, ``p_cam = T_cam_lidar * p_lidar``) and ``B(i)`` =
``T_lidar_board`` of frame i (Pose3, ``p_lidar = T_lidar_board * p_board``). Factors: per frame one
``PriorFactorPose3`` on ``B(i)`` with the LiDAR stage's 6x6 covariance and one grouped bearing factor
(``factors.FrameBearingFactor``) holding all its corners, each with its own 2x2 bearing covariance
mapped from the pixel covariance through the camera model. Levenberg-Marquardt from ``T_init``;
``gtsam.Marginals`` gives the 6x6 covariance of ``X(0)`` in the convention of interface.md
(``T_true = T_est * Expmap(xi)``, rotation first). A frame whose residual fails a chi-square gate
is dropped and the graph re-solved.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, X
from scipy.stats import chi2 as chi2_dist

from factors import POSE3_DOF, FrameBearingFactor, tangent_bases
from ilcc_graph.cameras import CameraModel
from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem

logger = logging.getLogger(__name__)

MIN_FRAMES_ADVISED = 4
MIN_CORNERS = 3
_ROBUST_DEFAULT_K = {
    "huber": 1.345,
    "cauchy": 2.3849,
    "tukey": 4.6851,
    "geman_mcclure": 2.9846,
    "welsch": 2.9846,
}
_ROBUST = {
    "huber": gtsam.noiseModel.mEstimator.Huber,
    "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
    "tukey": gtsam.noiseModel.mEstimator.Tukey,
    "geman_mcclure": gtsam.noiseModel.mEstimator.GemanMcClure,
    "welsch": gtsam.noiseModel.mEstimator.Welsch,
}
# Largest 1-sigma (rad or m) we still call a determined estimate.
_MAX_SIGMA = 10.0


@dataclass(frozen=True)
class GraphFrame:
    """One frame's input to the graph.

    name: frame name (file stem).
    T_lidar_board: (4, 4) board pose from the LiDAR stage, ``p_lidar = T_lidar_board @ p_board``.
    board_cov: (6, 6) its Pose3-tangent covariance (rotation first, rad and m).
    points_board: (K, 3) corners in the board frame, metres (``Board.corners_board()`` order).
    bearings: (K, 3) measured bearings of the same corners, camera frame (normalised here).
    cov_px: (K, 2, 2) pixel covariance of each image corner, px^2.
    """

    name: str
    T_lidar_board: np.ndarray
    board_cov: np.ndarray
    points_board: np.ndarray
    bearings: np.ndarray
    cov_px: np.ndarray


@dataclass(frozen=True)
class GraphOptions:
    """Solver settings.

    robust: None or an m-estimator applied per corner to its whitened bearing error (after a plain
        least-squares pass from ``T_init``): ``"huber"``,
        ``"cauchy"``, ``"tukey"``, ``"geman_mcclure"``, ``"welsch"``.
    robust_k: the kernel's threshold in sigmas (None: the usual 95 %-efficiency value).
    chi2_gate_prob: a frame whose chi-square (bearing and board-prior terms, 2K dof) exceeds this
        quantile is dropped; None disables the gate. With a robust kernel the gate tests the robust
        cost ``2 sum rho`` instead (never above the chi-square), so that one outlier corner need
        not cost its frame while a frame wrong as a whole still fails.
    max_dropped_fraction: the gate drops at most this fraction of the usable frames (a noise model
        that is wrong for every frame should not empty the graph); the rest are kept with a warning.
    variance_factor: when True, the stated noise is checked against the residuals. The gate
        compares each frame's chi-square divided by the median of chi2/dof over the frames (when
        that exceeds 1), so a noise model that is too optimistic for every frame does not drop
        good frames. On the kept frames (without a robust kernel), two variance components are
        then estimated (Foerstner's method: each group's chi-square over its redundancy), one for
        the board priors and one for the bearings, and each group's covariances are multiplied by
        its factor when above 1 (never shrunk); last, the covariance is multiplied by the remaining
        a-posteriori variance factor ``sum chi2 / (sum dof - 6)`` when it exceeds 1.
    max_iterations, relative_error_tol, absolute_error_tol: Levenberg-Marquardt stopping rules.
    """

    robust: str | None = None
    robust_k: float | None = None
    chi2_gate_prob: float | None = 0.999
    max_dropped_fraction: float = 0.5
    variance_factor: bool = True
    max_iterations: int = 100
    relative_error_tol: float = 1e-10
    absolute_error_tol: float = 1e-12


@dataclass(frozen=True)
class FrameStats:
    """Residual statistics of one frame at the solution.

    chi2: whitened squared bearing errors plus the board prior's term; dof: 2K;
    rms_bearing_error_mrad: RMS angle between predicted and measured bearings, mrad;
    chi2_robust: with a robust kernel, ``2 sum_k rho(|r_k|)`` plus the prior's term (the cost the
    solver minimised, and what the gate tests then); None without a kernel.
    """

    chi2: float
    dof: int
    rms_bearing_error_mrad: float
    chi2_robust: float | None = None


@dataclass(frozen=True)
class GraphSolution:
    """The graph's answer.

    T_cam_lidar: (4, 4). covariance: (6, 6) of ``T_cam_lidar`` (interface.md convention, exactly
    ``Marginals.marginalCovariance(X(0))``). T_lidar_board: refined board poses of the used frames.
    per_frame: statistics of the used frames. dropped: ``(name, reason)`` in the order dropped.
    iterations: LM iterations over all solves. timings: seconds (build, optimize, marginals, total).
    """

    T_cam_lidar: np.ndarray
    covariance: np.ndarray
    T_lidar_board: dict[str, np.ndarray]
    per_frame: dict[str, FrameStats]
    dropped: list[tuple[str, str]]
    iterations: int
    timings: dict[str, float] = field(default_factory=dict)
    variance_factor: float = 1.0
    variance_components: tuple[float, float] = (1.0, 1.0)

    @property
    def pose(self) -> gtsam.Pose3:
        """``T_cam_lidar`` as a ``gtsam.Pose3``."""
        return gtsam.Pose3(self.T_cam_lidar)


# ------------------------------------------------------------------------------ input checks
def _check_pose(T: np.ndarray, what: str) -> gtsam.Pose3:
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{what}: expected a finite (4, 4) rigid transform, got shape {T.shape}")
    R = T[:3, :3]
    if (
        np.abs(R.T @ R - np.eye(3)).max() > 1e-6
        or np.linalg.det(R) < 0
        or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9
    ):
        raise ValueError(f"{what}: not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)")
    return gtsam.Pose3(gtsam.Rot3(R), T[:3, 3])


def _check_cov(C: np.ndarray, n: int, what: str) -> np.ndarray:
    C = np.asarray(C, dtype=np.float64)
    if C.shape != (n, n) or not np.all(np.isfinite(C)):
        raise ValueError(f"{what}: expected a finite ({n}, {n}) covariance, got shape {C.shape}")
    C = 0.5 * (C + C.T)
    if np.linalg.eigvalsh(C).min() <= 0:
        raise ValueError(f"{what}: covariance is not positive definite")
    return C


def _robust_kernel(options: GraphOptions) -> gtsam.noiseModel.mEstimator.Base | None:
    if options.robust is None:
        return None
    name = options.robust.lower().replace("-", "_")
    if name not in _ROBUST:
        raise ValueError(
            f"GraphOptions.robust: unknown kernel {options.robust!r}; choose from {sorted(_ROBUST)}"
        )
    k = _ROBUST_DEFAULT_K[name] if options.robust_k is None else float(options.robust_k)
    if not k > 0:
        raise ValueError(f"GraphOptions.robust_k must be > 0, got {options.robust_k!r}")
    return _ROBUST[name].Create(k)


@dataclass
class _Frame:
    """A frame ready for the graph (internal)."""

    name: str
    index: int
    prior: gtsam.Pose3
    prior_cov: np.ndarray
    bearing: FrameBearingFactor


def frame_bearing_factor(
    key_cam_lidar: int,
    key_lidar_board: int,
    points_board: np.ndarray,
    bearings: np.ndarray,
    cov_px: np.ndarray,
    camera: CameraModel,
    robust: gtsam.noiseModel.mEstimator.Base | None = None,
    what: str = "frame",
) -> tuple[FrameBearingFactor | None, int]:
    """One board seen by one camera as a grouped bearing factor, and its number of usable corners.

    Pixel covariances (K, 2, 2) go to the bearing tangent plane through
    ``camera.bearing_tangent_cov``; corners with a non-finite bearing or covariance, or a
    covariance that is not positive definite there, are left out. The factor is None with fewer
    than ``MIN_CORNERS`` usable corners. Raises ValueError (naming ``what``) for malformed arrays.
    """
    p = np.asarray(points_board, dtype=np.float64)
    b = np.asarray(bearings, dtype=np.float64)
    c = np.asarray(cov_px, dtype=np.float64)
    K = len(p)
    if p.shape != (K, 3) or b.shape != (K, 3) or c.shape != (K, 2, 2):
        raise ValueError(
            f"{what}: need points_board (K,3), bearings (K,3), cov_px (K,2,2), "
            f"got {p.shape}, {b.shape}, {c.shape}"
        )
    with np.errstate(invalid="ignore", divide="ignore"):
        b = b / np.linalg.norm(b, axis=1, keepdims=True)
    ok = np.all(np.isfinite(b), axis=1) & np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(c), axis=(1, 2))
    cov_t = np.full((K, 2, 2), np.nan)
    if ok.any():
        cov_t[ok] = camera.bearing_tangent_cov(b[ok], c[ok], tangent_bases(b[ok]))
    ok &= np.all(np.isfinite(cov_t), axis=(1, 2))
    good = np.flatnonzero(ok)
    if good.size:
        ok[good] = np.linalg.eigvalsh(cov_t[good]).min(axis=1) > 0
    n_ok = int(ok.sum())
    if n_ok < MIN_CORNERS:
        return None, n_ok
    return FrameBearingFactor(key_cam_lidar, key_lidar_board, p[ok], b[ok], cov_t[ok], robust), n_ok


def _prepare(
    frames: Sequence[GraphFrame], camera: CameraModel, robust: gtsam.noiseModel.mEstimator.Base | None
) -> tuple[list[_Frame], list[tuple[str, str]]]:
    names = [f.name for f in frames]
    if len(set(names)) != len(names):
        raise ValueError(
            f"GraphFrame names must be unique, got {sorted(n for n in set(names) if names.count(n) > 1)}"
        )
    ready: list[_Frame] = []
    dropped: list[tuple[str, str]] = []
    for i, f in enumerate(frames):
        what = f"GraphFrame {f.name!r}"
        prior = _check_pose(f.T_lidar_board, f"{what}.T_lidar_board")
        prior_cov = _check_cov(f.board_cov, POSE3_DOF, f"{what}.board_cov")
        factor, n_ok = frame_bearing_factor(
            X(0), B(i), f.points_board, f.bearings, f.cov_px, camera, robust, what
        )
        if factor is None:
            dropped.append((f.name, f"only {n_ok} corners with a usable bearing and covariance"))
            continue
        if n_ok < len(f.points_board):
            logger.info(
                "frame %s: %d of %d corners without a usable bearing covariance skipped",
                f.name,
                len(f.points_board) - n_ok,
                len(f.points_board),
            )
        ready.append(_Frame(f.name, i, prior, prior_cov, factor))
    return ready, dropped


# -------------------------------------------------------------------------------- the graph
def _build(ready: Sequence[_Frame], plain: bool = False) -> gtsam.NonlinearFactorGraph:
    """The graph; ``plain`` leaves out the robust kernel (least squares)."""
    graph = gtsam.NonlinearFactorGraph()
    for fr in ready:
        graph.add(
            # smart=False: GTSAM's default treats off-diagonals below 1e-9 (absolute) as zero,
            # which drops real correlations of covariances in rad^2 and m^2
            gtsam.PriorFactorPose3(
                B(fr.index), fr.prior, gtsam.noiseModel.Gaussian.Covariance(fr.prior_cov, False)
            )
        )
        graph.add((fr.bearing.with_robust(None) if plain else fr.bearing).factor())
    return graph


def _initial(ready: Sequence[_Frame], T_cam_lidar: gtsam.Pose3) -> gtsam.Values:
    values = gtsam.Values()
    values.insert(X(0), T_cam_lidar)
    for fr in ready:
        values.insert(B(fr.index), fr.prior)
    return values


def _optimize(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, options: GraphOptions
) -> tuple[gtsam.Values, int]:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(options.max_iterations))
    params.setRelativeErrorTol(float(options.relative_error_tol))
    params.setAbsoluteErrorTol(float(options.absolute_error_tol))
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    try:
        result = optimizer.optimize()
    except RuntimeError as exc:
        raise IndeterminateSystem(f"Levenberg-Marquardt failed on an indeterminate system: {exc}") from None
    n_it = int(optimizer.iterations())
    if n_it >= options.max_iterations:
        logger.warning("Levenberg-Marquardt stopped at the iteration limit (%d) before converging", n_it)
    return result, n_it


def _frame_stats(fr: _Frame, values: gtsam.Values) -> FrameStats:
    T_cl, T_lb = values.atPose3(X(0)), values.atPose3(B(fr.index))
    e = fr.bearing.unwhitened(T_cl, T_lb)[0]
    r = fr.bearing.whitened(T_cl, T_lb)
    xi = np.asarray(fr.prior.localCoordinates(T_lb))
    prior_term = float(xi @ np.linalg.solve(fr.prior_cov, xi))
    chi2 = float(np.sum(r * r)) + prior_term
    chi2_robust = None
    if fr.bearing.robust is not None:
        chi2_robust = float(np.sum(fr.bearing.evaluate(T_cl, T_lb, False)[0] ** 2)) + prior_term
    # |e| is the sine of the angle between the bearings (their angle is < 90 deg near a solution)
    angles = np.arcsin(np.clip(np.linalg.norm(e, axis=1), 0.0, 1.0))
    rms = float(1e3 * np.sqrt(np.mean(angles**2)))
    return FrameStats(chi2, 2 * fr.bearing.n_corners, rms, chi2_robust)


def _marginal_covariance(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> np.ndarray:
    try:
        cov = np.asarray(gtsam.Marginals(graph, values).marginalCovariance(X(0)), dtype=np.float64)
    except (RuntimeError, IndexError, ValueError) as exc:
        raise IndeterminateSystem(f"the graph does not determine T_cam_lidar: {exc}") from None
    cov = 0.5 * (cov + cov.T)
    if not np.all(np.isfinite(cov)):
        raise IndeterminateSystem("the marginal covariance of T_cam_lidar is not finite")
    eig = np.linalg.eigvalsh(cov)
    if eig.min() <= 0 or math.sqrt(eig.max()) > _MAX_SIGMA:
        raise IndeterminateSystem(
            "the data barely determine T_cam_lidar "
            f"(covariance eigenvalues {eig.min():.3g} .. {eig.max():.3g})"
        )
    return cov


def _gate_scale(stats: dict[str, FrameStats]) -> float:
    """Robust noise scale for the gate: the median chi2/dof over frames, at least 1."""
    ratios = [(s.chi2 if s.chi2_robust is None else s.chi2_robust) / s.dof for s in stats.values()]
    return max(1.0, float(np.median(ratios))) if ratios else 1.0


def _gate_failures(
    ready: Sequence[_Frame], stats: dict[str, FrameStats], prob: float, scale: float = 1.0
) -> list[tuple[float, _Frame, str]]:
    """Frames failing the gate as (log survival probability, frame, reason), worst first.

    scale: the chi-square values are divided by it (the noise model's robust variance factor).
    """
    failing = []
    for fr in ready:
        s = stats[fr.name]
        value, what = (s.chi2, "chi2") if s.chi2_robust is None else (s.chi2_robust, "robust chi2")
        value /= scale
        bound = float(chi2_dist.ppf(prob, s.dof))
        if value > bound:
            scaled = f" (divided by the frames' median chi2/dof {scale:.2f})" if scale > 1.0 else ""
            reason = (
                f"chi-square gate: residual {what}{scaled} {value:.1f} > {bound:.1f} ({s.dof} dof, "
                f"p={prob}); rms bearing error {s.rms_bearing_error_mrad:.3f} mrad"
            )
            failing.append((float(chi2_dist.logsf(value, s.dof)), fr, reason))
    return sorted(failing, key=lambda item: item[0])


def _scaled(ready: Sequence[_Frame], s_prior: float, s_bearing: float) -> list[_Frame]:
    """The frames with board-prior covariances times ``s_prior`` and bearing ones times ``s_bearing``."""
    return [
        dataclasses.replace(fr, prior_cov=fr.prior_cov * s_prior, bearing=fr.bearing.scaled(s_bearing))
        for fr in ready
    ]


def _component_ratios(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> tuple[float, float]:
    """Foerstner's variance-component estimates (board priors, bearings) at a solution of ``graph``.

    A group's ratio is its whitened chi-square over its redundancy: its number of residuals less
    ``trace(N^-1 N_g)``, N the information matrix of the whitened linear system and N_g the group's
    share. The graph is as ``_build`` makes it (per frame: the board prior on B(i), then the bearing
    factor on X(0), B(i)), so N is an arrow matrix and the trace costs O(frames) by the Schur
    complement on the extrinsic, with no dense (6n x 6n) algebra.
    """
    n_frames = graph.size() // 2
    chi2 = [0.0, 0.0]
    m = [0, 0]
    Np, D, C = [], [], []  # per frame: prior information, board block, board-extrinsic coupling
    E = np.zeros((POSE3_DOF, POSE3_DOF))
    for i in range(n_frames):
        Ap, bp = graph.at(2 * i).linearize(values).jacobian()
        Ab, bb = graph.at(2 * i + 1).linearize(values).jacobian()  # columns: X(0), then B(i)
        Ax, Ab = Ab[:, :POSE3_DOF], Ab[:, POSE3_DOF:]
        chi2[0] += float(bp @ bp)
        chi2[1] += float(bb @ bb)
        m[0] += len(bp)
        m[1] += len(bb)
        Np.append(Ap.T @ Ap)
        D.append(Np[-1] + Ab.T @ Ab)
        C.append(Ab.T @ Ax)
        E += Ax.T @ Ax
    Dinv = [np.linalg.inv(d) for d in D]
    S_inv = np.linalg.inv(E - sum(c.T @ di @ c for c, di in zip(C, Dinv)))
    trace_prior = 0.0
    for npr, di, c in zip(Np, Dinv, C):
        cov_bb = di + di @ c @ S_inv @ c.T @ di  # marginal covariance of the board (whitened units)
        trace_prior += float(np.sum(cov_bb * npr))  # trace(cov_bb @ npr), npr symmetric
    n_params = POSE3_DOF * (n_frames + 1)
    redundancy = (m[0] - trace_prior, m[1] - (n_params - trace_prior))
    return tuple(c / r if r > 0.5 else 1.0 for c, r in zip(chi2, redundancy))  # type: ignore[return-value]


def _variance_factor(stats: dict[str, FrameStats]) -> float:
    """A-posteriori variance factor: sum chi2 / (sum dof - 6), at least 1."""
    chi2 = sum(s.chi2 for s in stats.values())
    dof = sum(s.dof for s in stats.values()) - POSE3_DOF
    return max(1.0, chi2 / dof) if dof > 0 else 1.0


def solve(
    frames: Sequence[GraphFrame],
    camera: CameraModel,
    T_init: np.ndarray,
    options: GraphOptions = GraphOptions(),
) -> GraphSolution:
    """Refine ``T_cam_lidar`` over all frames and return it with its marginal covariance.

    Parameters
    ----------
    frames : the frames (see ``GraphFrame``); bearings in the camera frame of ``camera``.
    camera : maps each corner's pixel covariance to a bearing covariance (``bearing_tangent_cov``).
    T_init : (4, 4) starting ``T_cam_lidar`` (e.g. UPnP's).
    options : ``GraphOptions``.

    Raises
    ------
    CalibrationImpossible : no usable frame.
    IndeterminateSystem : the information matrix does not determine ``T_cam_lidar``.
    ValueError : malformed input (message names the frame and the array).
    """
    t_start = time.perf_counter()
    T0 = _check_pose(T_init, "T_init")
    if options.chi2_gate_prob is not None and not 0.0 < options.chi2_gate_prob < 1.0:
        raise ValueError(
            f"GraphOptions.chi2_gate_prob must be in (0, 1) or None, got {options.chi2_gate_prob!r}"
        )
    robust = _robust_kernel(options)
    ready, dropped = _prepare(frames, camera, robust)
    if not ready:
        raise CalibrationImpossible(
            f"no usable frame for the graph ({len(frames)} given"
            + (f"; dropped: {'; '.join(f'{n}: {r}' for n, r in dropped)})" if dropped else ")")
        )
    allowed_drops = int(math.floor(options.max_dropped_fraction * len(ready)))
    timings = {"build": 0.0, "optimize": 0.0, "marginals": 0.0}
    iterations = 0
    T_cam_lidar = T0
    board_estimates: dict[int, gtsam.Pose3] = {}
    if robust is not None:
        # Least squares first: from a start far off every residual is "large" and a redescending
        # kernel would weight them all to zero.
        t0 = time.perf_counter()
        result, n_it = _optimize(_build(ready, plain=True), _initial(ready, T0), options)
        timings["optimize"] += time.perf_counter() - t0
        iterations += n_it
        T_cam_lidar = result.atPose3(X(0))
        board_estimates = {fr.index: result.atPose3(B(fr.index)) for fr in ready}
    use_components = options.variance_factor and robust is None
    components = (1.0, 1.0)

    def fit(frames_: list[_Frame], comps: tuple[float, float]):
        """Optimise the graph of ``frames_`` with covariances scaled by ``comps``."""
        nonlocal iterations, T_cam_lidar, board_estimates
        t0 = time.perf_counter()
        scaled = _scaled(frames_, *comps) if comps != (1.0, 1.0) else list(frames_)
        g = _build(scaled)
        values = _initial(scaled, T_cam_lidar)
        for fr in scaled:
            if fr.index in board_estimates:
                values.update(B(fr.index), board_estimates[fr.index])
        t1 = time.perf_counter()
        res, n_it = _optimize(g, values, options)
        timings["build"] += t1 - t0
        timings["optimize"] += time.perf_counter() - t1
        iterations += n_it
        T_cam_lidar = res.atPose3(X(0))
        board_estimates = {fr.index: res.atPose3(B(fr.index)) for fr in scaled}
        return scaled, g, res

    def fit_components(frames_: list[_Frame], comps: tuple[float, float]):
        """``fit`` with the two variance components re-estimated until they settle (>= 1 each)."""
        scaled, g, res = fit(frames_, comps)
        for _ in range(8):
            s_prior, s_bearing = _component_ratios(g, res)
            new = (max(1.0, comps[0] * s_prior), max(1.0, comps[1] * s_bearing))
            if all(abs(n / c - 1.0) < 0.02 for n, c in zip(new, comps)):
                break
            comps = new
            scaled, g, res = fit(frames_, comps)
        return scaled, g, res, comps

    def gate(frames_: list[_Frame], comps: tuple[float, float]):
        """Drop the worst frame failing the chi-square gate until none fails (or the cap is hit)."""
        kept, gone = list(frames_), []
        while True:
            scaled, g, res = fit(kept, comps)
            st = {fr.name: _frame_stats(fr, res) for fr in scaled}
            if options.chi2_gate_prob is None:
                break
            scale = _gate_scale(st) if options.variance_factor else 1.0
            failing = _gate_failures(scaled, st, options.chi2_gate_prob, scale)
            if not failing:
                break
            if len(gone) >= allowed_drops or len(kept) == 1:
                logger.warning(
                    "chi-square gate fails for %d frame(s) (%s) but at most %d frames may be dropped; kept",
                    len(failing),
                    ", ".join(fr.name for _, fr, _ in failing),
                    allowed_drops,
                )
                break
            _, worst, reason = failing[0]
            logger.info("dropping frame %s: %s", worst.name, reason)
            gone.append((worst.name, reason))
            kept = [fr for fr in kept if fr.name != worst.name]
        return kept, gone, scaled, g, res, st

    kept, gone, scaled, graph, result, stats = gate(ready, components)
    if use_components:
        # Variance components on the kept frames only (an outlier would inflate what judges it);
        # then every frame is gated again under that noise, and the components re-estimated.
        *_, components = fit_components(kept, components)
        kept, gone, scaled, graph, result, stats = gate(ready, components)
        scaled, graph, result, components = fit_components(kept, components)
        stats = {fr.name: _frame_stats(fr, result) for fr in scaled}
    dropped.extend(gone)
    ready = scaled
    if len(ready) < MIN_FRAMES_ADVISED:
        logger.warning(
            "only %d usable frame(s) in the graph; at least %d are advised for a reliable extrinsic",
            len(ready),
            MIN_FRAMES_ADVISED,
        )
    if components != (1.0, 1.0):
        logger.info(
            "variance components: board priors x %.2f, bearings x %.2f (residuals against the stated noise)",
            *components,
        )
    t3 = time.perf_counter()
    covariance = _marginal_covariance(graph, result)
    factor = _variance_factor(stats) if options.variance_factor else 1.0
    if factor > 1.0:
        logger.info("the residuals are %.2f times the stated noise variance; covariance scaled by it", factor)
        covariance = covariance * factor
    timings["marginals"] = time.perf_counter() - t3
    timings["total"] = time.perf_counter() - t_start
    return GraphSolution(
        T_cam_lidar=np.asarray(T_cam_lidar.matrix(), dtype=np.float64),
        covariance=covariance,
        T_lidar_board={fr.name: np.asarray(board_estimates[fr.index].matrix()) for fr in ready},
        per_frame=stats,
        dropped=dropped,
        iterations=iterations,
        timings=timings,
        variance_factor=factor,
        variance_components=components,
    )
