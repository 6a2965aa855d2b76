"""Factor-graph helpers of the estimation core: the factors of one board or view, and helpers that
each return a ``NonlinearFactorGraph`` (board priors, views, ties, priors). ``assembly.Assembly``
puts them together for a problem."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence

import gtsam
import numpy as np

from factors import FrameBearingFactor, FramePixelFactor, sqrt_information, tangent_bases
from factors.board_points import BoardPointsFactor
from factors.grouped import MEstimator
from factors.range_offset import RangeOffsetBoardFactor
from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation.intrinsics import projection
from ilcc_graph.estimation.keys import POSE3_DOF, B, I, L, O, X
from ilcc_graph.estimation.lidar_errors import LidarLayout
from ilcc_graph.estimation.problem import BoardPrior, Tie
from ilcc_graph.estimation.solver import check_pose, gaussian
from ilcc_graph.init import upnp
from ilcc_graph.types import BoardReturns, GraphFrame

log = logging.getLogger(__name__)

__all__ = [
    "MIN_CORNERS",
    "Scales",
    "bearing_graph",
    "board_face_samples",
    "board_prior_graph",
    "frame_bearing_factor",
    "frame_pixel_factor",
    "intrinsics_prior_graph",
    "offset_prior_graph",
    "samples_from_corners",
    "tie_graph",
    "upnp_start",
]

MIN_CORNERS = 3
#: variance scale per (kind, group), kind "board" or "bearing"; absent means 1.
Scales = Mapping[tuple[str, str], float]


def _positive_definite(ok: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(K,) ``ok`` and the corner's covariance (K, 2, 2) finite and positive definite."""
    ok = ok & np.all(np.isfinite(cov), axis=(1, 2))
    good = np.flatnonzero(ok)
    if good.size:
        ok[good] = np.linalg.eigvalsh(cov[good]).min(axis=1) > 0
    return ok


def frame_bearing_factor(
    key_cam_lidar: int,
    key_lidar_board: int,
    points_board: np.ndarray,
    bearings: np.ndarray,
    cov_px: np.ndarray,
    camera: CameraModel,
    robust: MEstimator | None = None,
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
    ok = _positive_definite(ok, cov_t)
    n_ok = int(ok.sum())
    if n_ok < MIN_CORNERS:
        return None, n_ok
    return FrameBearingFactor(key_cam_lidar, key_lidar_board, p[ok], b[ok], cov_t[ok], robust), n_ok


def frame_pixel_factor(
    key_cam_lidar: int,
    key_lidar_board: int,
    key_intrinsics: int,
    points_board: np.ndarray,
    uv: np.ndarray,
    cov_px: np.ndarray,
    camera: CameraModel,
    robust: MEstimator | None = None,
) -> tuple[FramePixelFactor | None, int]:
    """One board seen by one camera as a grouped pixel factor with the camera's intrinsics ``I(c)``
    as a variable, and its number of usable corners (finite pixels, positive-definite covariances);
    None with fewer than ``MIN_CORNERS``."""
    p = np.asarray(points_board, dtype=np.float64)
    q = np.asarray(uv, dtype=np.float64)
    c = np.asarray(cov_px, dtype=np.float64)
    ok = _positive_definite(np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(p), axis=1), c)
    n_ok = int(ok.sum())
    if n_ok < MIN_CORNERS:
        return None, n_ok
    fac = FramePixelFactor(
        key_cam_lidar, key_lidar_board, key_intrinsics, p[ok], q[ok], c[ok], projection(camera), robust=robust
    )
    return fac, n_ok


def intrinsics_prior_graph(priors: Mapping[int, tuple[np.ndarray, np.ndarray]]) -> gtsam.NonlinearFactorGraph:
    """A prior on each camera's intrinsics ``I(c)``: (values, sigmas) per camera index."""
    graph = gtsam.NonlinearFactorGraph()
    for c, (theta, sigmas) in priors.items():
        graph.add(gtsam.PriorFactorVector(I(c), theta, gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
    return graph


def samples_from_corners(points_board: np.ndarray, n: int = 13) -> np.ndarray:
    """A grid over the corners' rectangle grown by one corner spacing (a board cut to its pattern)."""
    p = np.asarray(points_board, dtype=np.float64)
    xs, ys = np.unique(np.round(p[:, 0], 9)), np.unique(np.round(p[:, 1], 9))
    sx = float(np.median(np.diff(xs))) if len(xs) > 1 else 0.0
    sy = float(np.median(np.diff(ys))) if len(ys) > 1 else sx
    gx, gy = np.meshgrid(np.linspace(xs[0] - sx, xs[-1] + sx, n), np.linspace(ys[0] - sy, ys[-1] + sy, n))
    return np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])


def board_face_samples(board: Board, n_long: int = 17, n_short: int = 13) -> np.ndarray:
    """(n_long * n_short, 3) grid over the board's physical face (margin included), board frame."""
    x0, x1, y0, y1 = board.extent()
    gx, gy = np.meshgrid(np.linspace(x0, x1, n_long), np.linspace(y0, y1, n_short))
    return np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])


def upnp_start(frames: Sequence[GraphFrame]) -> np.ndarray:
    """(4, 4) ``T_cam_lidar`` by UPnP on every corner of ``frames`` (LiDAR corners and bearings)."""
    P = np.vstack([f.points_board @ f.T_lidar_board[:3, :3].T + f.T_lidar_board[:3, 3] for f in frames])
    F = np.vstack([f.bearings for f in frames])
    with np.errstate(invalid="ignore", divide="ignore"):
        F = F / np.linalg.norm(F, axis=1, keepdims=True)
    ok = np.all(np.isfinite(P), axis=1) & np.all(np.isfinite(F), axis=1)
    if ok.sum() < 4:
        raise CalibrationImpossible("fewer than 4 usable corners to initialise an extrinsic")
    return upnp(P[ok], F[ok], prefer_front=True)[0].T_cam_points  # corners lie ahead along their rays


# ----------------------------------------------------------------------------- graph helpers
def board_prior_graph(
    boards: Sequence[tuple[int, BoardPrior, np.ndarray]],
    range_offset: bool,
    samples: Mapping[int, np.ndarray],
) -> gtsam.NonlinearFactorGraph:
    """One prior per board ``(index, board, covariance)`` on ``B(index)``.

    Without a range offset a ``PriorFactorPose3``; with one, ``RangeOffsetBoardFactor`` on
    ``(B(index), O(board.lidar))`` over the board-face ``samples[index]``.
    """
    graph = gtsam.NonlinearFactorGraph()
    for i, bd, cov in boards:
        if range_offset:
            f = RangeOffsetBoardFactor(B(i), O(bd.lidar), bd.T_lidar_board, cov, samples[i])
            graph.add(f.factor())
        else:
            graph.add(gtsam.PriorFactorPose3(B(i), check_pose(bd.T_lidar_board, bd.name), gaussian(cov)))
    return graph


def bearing_graph(views: Sequence[FrameBearingFactor | FramePixelFactor]) -> gtsam.NonlinearFactorGraph:
    """The grouped view factors (bearing or pixel) as GTSAM factors."""
    graph = gtsam.NonlinearFactorGraph()
    for v in views:
        graph.add(v.factor())
    return graph


def tie_graph(ties: Sequence[Tie]) -> gtsam.NonlinearFactorGraph:
    """``BetweenFactorPose3(X(a), X(b), identity)`` per tie."""
    graph = gtsam.NonlinearFactorGraph()
    for t in ties:
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(t.sigmas, dtype=np.float64))
        graph.add(gtsam.BetweenFactorPose3(X(t.a), X(t.b), gtsam.Pose3(), noise))
    return graph


def offset_prior_graph(lidars: Sequence[int], sigma_m: float) -> gtsam.NonlinearFactorGraph:
    """A weak zero-mean prior on each LiDAR's range offset ``O(l)`` (Vector1, metres)."""
    graph = gtsam.NonlinearFactorGraph()
    for lid in lidars:
        graph.add(gtsam.PriorFactorVector(O(lid), np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, sigma_m)))
    return graph


def board_points_factor(
    index: int,
    board: BoardPrior,
    layout: LidarLayout,
    max_points: int,
    plane_sigma: tuple[float, float] | None = None,
    beam_sigma: float | None = None,
) -> BoardPointsFactor:
    """The board's returns on (``B(index)``, ``L(board.lidar)``) with the terms of ``layout`` (and
    the board's own random plane of ``plane_sigma`` and beam offsets of ``beam_sigma``, see
    ``BoardPointsFactor``).

    At most ``max_points`` returns (evenly spread over the list) enter. The in-plane prior is the
    LiDAR stage's intensity fit: ``W (xi_in - K xi_out)``, ``xi = Logmap(T_measured^-1 T)``.
    """
    r: BoardReturns = board.returns  # type: ignore[assignment]
    P = np.asarray(r.points, dtype=np.float64)
    keep = np.arange(len(P)) if len(P) <= max_points else np.linspace(0, len(P) - 1, max_points).astype(int)
    rho = np.linalg.norm(P[keep], axis=1)
    range_index, range_coef, e_idx, e_coef = layout.terms(r, rho, keep)
    S = np.zeros((3, POSE3_DOF))
    S[:, [2, 3, 4]] = np.eye(3)
    S[:, [0, 1, 5]] = -np.asarray(r.inplane_coupling, dtype=np.float64)
    return BoardPointsFactor(
        B(index), L(board.lidar), P[keep], float(r.sigma_m), range_index, range_coef, layout.dim,
        board.T_lidar_board, S, sqrt_information(np.asarray(r.inplane_cov, dtype=np.float64)), e_idx, e_coef,
        plane_sigma, beam_sigma, np.asarray(r.ring)[keep] if beam_sigma is not None else None,
    )  # fmt: skip


def lidar_prior_graph(layouts: Mapping[int, LidarLayout]) -> gtsam.NonlinearFactorGraph:
    """A weak zero-mean prior on each LiDAR's parameter vector ``L(l)`` (the layout's sigmas)."""
    graph = gtsam.NonlinearFactorGraph()
    for lid, lay in layouts.items():
        graph.add(
            gtsam.PriorFactorVector(
                L(lid), np.zeros(lay.dim), gtsam.noiseModel.Diagonal.Sigmas(lay.prior_sigmas())
            )
        )
    return graph
