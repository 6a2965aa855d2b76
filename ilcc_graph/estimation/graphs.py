"""Factor-graph helpers of the estimation core: each returns a ``NonlinearFactorGraph``.

``Assembly`` turns a ``Problem`` into factors once (bearing covariances mapped from pixels through
the camera models, square-root informations, Unit3 bases) and then builds the graph of any subset
of its boards with any variance scaling, plus the ``Term`` bookkeeping the noise policy needs
(which factor belongs to which board and noise group). Factor order in a graph: the board priors,
then the views, then the ties, then the offset priors.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from factors import FrameBearingFactor, sqrt_information, tangent_bases
from factors.board_points import BoardPointsFactor
from factors.range_offset import RangeOffsetBoardFactor
from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation.keys import POSE3_DOF, B, L, O, X, key_dim
from ilcc_graph.estimation.lidar_errors import LidarLayout, layout_for
from ilcc_graph.estimation.problem import BoardPrior, Problem, Tie
from ilcc_graph.estimation.solver import check_covariance, check_pose, gaussian
from ilcc_graph.init import upnp
from ilcc_graph.types import BoardReturns, GraphFrame

log = logging.getLogger(__name__)

__all__ = [
    "MIN_CORNERS",
    "Assembly",
    "Scales",
    "Term",
    "bearing_graph",
    "board_face_samples",
    "board_prior_graph",
    "frame_bearing_factor",
    "offset_prior_graph",
    "samples_from_corners",
    "tie_graph",
    "upnp_start",
]

MIN_CORNERS = 3
#: variance scale per (kind, group), kind "board" or "bearing"; absent means 1.
Scales = Mapping[tuple[str, str], float]


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


def bearing_graph(views: Sequence[FrameBearingFactor]) -> gtsam.NonlinearFactorGraph:
    """The grouped bearing factors as GTSAM factors."""
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
    index: int, board: BoardPrior, layout: LidarLayout, max_points: int
) -> BoardPointsFactor:
    """The board's returns on (``B(index)``, ``L(board.lidar)``) with the terms of ``layout``.

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


# ------------------------------------------------------------------------------ the assembly
@dataclass(frozen=True)
class Term:
    """What one factor of an assembled graph is: ``kind`` board / bearing / tie / offset, its noise
    ``group`` (scaled by the variance components of board and bearing terms) and its board (or None)."""

    kind: str
    group: str
    board: int | None
    dim: int
    parts: tuple[tuple[str, int, int], ...] = ()  # (kind, first row, end row) when rows differ in kind


class Assembly:
    """A ``Problem`` turned into factors once; graphs of board subsets with any variance scaling.

    robust: m-estimator applied per corner to the bearing factors (None: least squares).
    Views with fewer than ``MIN_CORNERS`` usable corners are left out; ``unusable`` names their
    boards with the reason (a board without any usable view cannot be estimated). With
    ``problem.lidar_errors``, each board that carries its returns enters through a
    ``BoardPointsFactor`` on its LiDAR's parameters ``L(l)`` (``layouts`` per LiDAR, default from
    the returns: ``lidar_errors.layout_for``); the others through their LiDAR prior.
    """

    def __init__(
        self,
        problem: Problem,
        robust: gtsam.noiseModel.mEstimator.Base | None = None,
        layouts: Mapping[int, LidarLayout] | None = None,
    ) -> None:
        self.problem = problem
        self.robust = robust
        self.priors = [
            check_covariance(b.covariance, POSE3_DOF, f"board {b.name!r} covariance") for b in problem.boards
        ]
        for b in problem.boards:
            check_pose(b.T_lidar_board, f"board {b.name!r} T_lidar_board")
        self.views: list[tuple[int, FrameBearingFactor]] = []  # (view index, factor)
        seen: set[int] = set()
        reasons: dict[int, str] = {}
        for j, v in enumerate(problem.views):
            name = problem.boards[v.board].name
            fac, n_ok = frame_bearing_factor(
                X(v.extrinsic), B(v.board), v.points_board, v.bearings, v.cov_px, v.camera, robust, name
            )
            if fac is None:
                reasons.setdefault(v.board, f"only {n_ok} corners with a usable bearing and covariance")
                continue
            if n_ok < len(v.points_board):
                log.info(
                    "%s: %d of %d corners without a usable bearing covariance skipped",
                    name,
                    len(v.points_board) - n_ok,
                    len(v.points_board),
                )
            self.views.append((j, fac))
            seen.add(v.board)
        self.unusable = {
            i: reasons.get(i, "no view of it") for i in range(len(problem.boards)) if i not in seen
        }
        self.samples: dict[int, np.ndarray] = {}
        if problem.range_offset_sigma_m is not None:
            for i, b in enumerate(problem.boards):
                if b.samples_board is not None:
                    self.samples[i] = np.asarray(b.samples_board, dtype=np.float64)
                else:
                    pts = next(v.points_board for v in problem.views if v.board == i)
                    self.samples[i] = samples_from_corners(pts)
        self.layouts: dict[int, LidarLayout] = {}
        self.points: dict[int, BoardPointsFactor] = {}
        opts = problem.lidar_errors
        if opts is not None and opts.any:
            by_lidar: dict[int, list[int]] = {}
            for i, b in enumerate(problem.boards):
                if b.returns is not None:
                    by_lidar.setdefault(b.lidar, []).append(i)
            for lid, idx in by_lidar.items():
                lay = (layouts or {}).get(lid) or layout_for([problem.boards[i].returns for i in idx], opts)
                self.layouts[lid] = lay
                if lay.dim == 0:
                    continue  # nothing left to estimate: the boards enter through their priors
                for i in idx:
                    self.points[i] = board_points_factor(i, problem.boards[i], lay, opts.max_points_per_board)

    @property
    def usable(self) -> list[int]:
        """Boards with at least one usable view, in problem order."""
        return [i for i in range(len(self.problem.boards)) if i not in self.unusable]

    def graph(
        self, boards: Sequence[int], scales: Scales | None = None, plain: bool = False
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        """The graph of ``boards`` (their priors and views, the ties, the offset priors) and its terms.

        scales: variance scale per (kind, group). plain: without the robust kernel (least squares).
        """
        pr = self.problem
        scales = scales or {}
        keep = set(boards)
        order = [i for i in range(len(pr.boards)) if i in keep]
        with_offset = pr.range_offset_sigma_m is not None
        plain_boards = [i for i in order if i not in self.points]
        priors = [
            (i, pr.boards[i], self.priors[i] * scales.get(("board", pr.boards[i].group), 1.0))
            for i in plain_boards
        ]
        graph = board_prior_graph(priors, with_offset, self.samples)
        terms = [Term("board", pr.boards[i].group, i, POSE3_DOF) for i in plain_boards]
        for i in order:
            if i in self.points:
                g = pr.boards[i].group
                f = self.points[i].scaled(scales.get(("points", g), 1.0), scales.get(("inplane", g), 1.0))
                graph.add(f.factor())
                m = f.n_points
                terms.append(Term("board", g, i, f.dim, (("points", 0, m), ("inplane", m, m + 3))))
        facs = []
        for j, fac in self.views:
            v = pr.views[j]
            if v.board not in keep:
                continue
            s = scales.get(("bearing", v.group), 1.0)
            fac = fac.scaled(s) if s != 1.0 else fac
            facs.append(fac.with_robust(None) if plain else fac)
            terms.append(Term("bearing", v.group, v.board, fac.dim))
        graph.push_back(bearing_graph(facs))
        exts = self.extrinsics(order)
        ties = [t for t in pr.ties if t.a in exts and t.b in exts]
        graph.push_back(tie_graph(ties))
        terms += [Term("tie", "", None, POSE3_DOF) for _ in ties]
        if with_offset:
            lidars = self.lidars(order)
            graph.push_back(offset_prior_graph(lidars, float(pr.range_offset_sigma_m)))
            terms += [Term("offset", "", None, 1) for _ in lidars]
        layouts = {lid: self.layouts[lid] for lid in self.point_lidars(order)}
        graph.push_back(lidar_prior_graph(layouts))
        terms += [Term("lidar", "", None, lay.dim) for lay in layouts.values()]
        return graph, terms

    def point_lidars(self, boards: Sequence[int]) -> list[int]:
        """LiDARs whose parameters ``L(l)`` the boards' returns enter."""
        return sorted({self.problem.boards[i].lidar for i in boards if i in self.points})

    def dim(self, key: int) -> int:
        """Tangent dimension of the variable behind ``key``."""
        sym = gtsam.Symbol(key)
        if chr(sym.chr()).lower() == "l":
            return self.layouts[int(sym.index())].dim
        return key_dim(key)

    def extrinsics(self, boards: Sequence[int]) -> list[int]:
        """Extrinsic indices seen by the views of ``boards`` (and those tied to them), ascending."""
        keep = set(boards)
        used = {self.problem.views[j].extrinsic for j, _ in self.views if self.problem.views[j].board in keep}
        for _ in range(len(self.problem.ties) + 1):  # ties may chain extrinsics that no view sees
            more = {i for t in self.problem.ties for i in (t.a, t.b) if t.a in used or t.b in used}
            if more <= used:
                break
            used |= more
        return sorted(used)

    def lidars(self, boards: Sequence[int]) -> list[int]:
        return sorted({self.problem.boards[i].lidar for i in boards})

    def bearing_factors(self, board: int) -> list[FrameBearingFactor]:
        """The (unscaled) bearing factors of one board's views."""
        return [fac for j, fac in self.views if self.problem.views[j].board == board]

    def values(
        self,
        boards: Sequence[int],
        extrinsics: Mapping[int, gtsam.Pose3],
        board_poses: Mapping[int, gtsam.Pose3] | None = None,
        offsets: Mapping[int, float] | None = None,
        lidar: Mapping[int, np.ndarray] | None = None,
    ) -> gtsam.Values:
        """Initial values: the extrinsics given, each board at ``board_poses`` or its LiDAR prior,
        each range offset at ``offsets`` or 0, each LiDAR's parameters at ``lidar`` or 0."""
        values = gtsam.Values()
        for e in self.extrinsics(boards):
            T = extrinsics.get(e)
            values.insert(X(e), T if T is not None else check_pose(self.problem.T_init[e], f"T_init[{e}]"))
        for i in boards:
            bp = (board_poses or {}).get(i)
            values.insert(
                B(i), bp if bp is not None else check_pose(self.problem.boards[i].T_lidar_board, "")
            )
        if self.problem.range_offset_sigma_m is not None:
            for lid in self.lidars(boards):
                values.insert(O(lid), np.array([(offsets or {}).get(lid, 0.0)]))
        for lid in self.point_lidars(boards):
            v = (lidar or {}).get(lid)
            values.insert(
                L(lid),
                v if v is not None and len(v) == self.layouts[lid].dim else np.zeros(self.layouts[lid].dim),
            )
        return values
