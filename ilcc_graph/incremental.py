"""Incremental calibration with iSAM2: frames one at a time, the estimate and its sigmas after each.

The graph is the one of ``graph.solve`` (``X(0)`` = ``T_cam_lidar``, ``B(i)`` = ``T_lidar_board`` of
frame i, a ``PriorFactorPose3`` and one grouped bearing factor per frame), grown by ``gtsam.ISAM2``.
Each frame adds one variable and two factors; iSAM2 re-eliminates only the cliques they touch
(``X(0)`` sits at the root) and relinearises only variables that moved more than
``relinearize_threshold``. ``finish()`` relinearises everything and iterates to convergence, so its
answer is the batch solution (``graph.solve`` without the gate) to solver precision.

Half turns: with a symmetric board the image corner order is known only up to the half turn. The
first ``init_frames`` frames are ordered together with ``init.resolve_half_turns`` (and give the
UPnP start unless ``T_init`` is given); every later frame takes the order whose bearing residual at
the current estimate is smaller.

A frame whose chi-square (its board re-fitted with the extrinsic held at the current estimate)
exceeds the ``gate_prob`` quantile is rejected with the reason and changes nothing.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, X
from scipy.stats import chi2 as chi2_dist

from ilcc_graph.board import Board
from ilcc_graph.camera_models import CameraModel
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.graph import GraphFrame
from ilcc_graph.init import resolve_half_turns, upnp
from ilcc_graph.joint import view_factor
from ilcc_graph.types import FrameResult

log = logging.getLogger(__name__)

__all__ = ["FrameUpdate", "IncrementalCalibrator", "calibrate_incrementally", "format_update"]


@dataclass(frozen=True)
class FrameUpdate:
    """The state after one ``add_frame``; unpacks as ``(T_cam_lidar, sigmas, reached_target)``.

    T_cam_lidar: (4, 4) current estimate, None while waiting for the first ``init_frames`` frames.
    sigmas: (6,) per-axis sigmas (rad, rad, rad, m, m, m); inf before the first estimate.
    reached_target: every rotation sigma <= target deg and every translation sigma <= target mm.
    covariance: (6, 6) interface.md convention (NaN before the first estimate).
    name: the frame's name. accepted: False when the frame was rejected (``reason`` says why).
    n_frames: frames in the graph. seconds: wall time of this update (iSAM2 + marginal).
    """

    T_cam_lidar: np.ndarray | None
    sigmas: np.ndarray
    reached_target: bool
    covariance: np.ndarray
    name: str = ""
    accepted: bool = True
    reason: str | None = None
    n_frames: int = 0
    seconds: float = 0.0

    def __iter__(self):  # noqa: ANN204 - tuple-like unpacking of the three main fields
        return iter((self.T_cam_lidar, self.sigmas, self.reached_target))


@dataclass
class _Pending:
    frame: GraphFrame
    flippable: bool


@dataclass
class IncrementalCalibrator:
    """Frames in, ``T_cam_lidar`` and sigmas out, one frame at a time (iSAM2).

    Parameters
    ----------
    camera : the camera model (pixel covariances -> bearing covariances).
    board : the chessboard (corner grid; its half-turn symmetry).
    T_init : (4, 4) start; None: UPnP on the first ``init_frames`` frames.
    target_sigma : (rotation deg, translation mm): reached when every axis's sigma is at most these.
    init_frames : frames buffered before the first estimate when ``T_init`` is None (>= 1).
    relinearize_threshold : iSAM2's per-variable relinearisation threshold (rad / m).
    gate_prob : chi-square quantile above which a frame is rejected; None: never.
    """

    camera: CameraModel
    board: Board
    T_init: np.ndarray | None = None
    target_sigma: tuple[float, float] | None = None
    init_frames: int = 3
    relinearize_threshold: float = 1e-3
    gate_prob: float | None = 0.999
    _isam: gtsam.ISAM2 = field(init=False, repr=False)
    _pending: list[_Pending] = field(init=False, repr=False, default_factory=list)
    _frames: list[GraphFrame] = field(init=False, repr=False, default_factory=list)
    _names: set[str] = field(init=False, repr=False, default_factory=set)
    _T: gtsam.Pose3 | None = field(init=False, repr=False, default=None)
    _cov: np.ndarray | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        if self.init_frames < 1:
            raise ValueError(f"init_frames must be >= 1, got {self.init_frames!r}")
        if self.target_sigma is not None:
            ts = tuple(float(v) for v in self.target_sigma)
            if len(ts) != 2 or min(ts) <= 0:
                raise ValueError(f"target_sigma must be (rotation deg > 0, translation mm > 0), got {ts!r}")
            self.target_sigma = ts
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(float(self.relinearize_threshold))
        params.relinearizeSkip = 1
        self._isam = gtsam.ISAM2(params)

    # ------------------------------------------------------------------------------ properties
    @property
    def frames(self) -> list[GraphFrame]:
        """The frames in the graph, in the order added (with the corner order used)."""
        return list(self._frames)

    @property
    def estimate(self) -> np.ndarray | None:
        """(4, 4) current ``T_cam_lidar`` or None."""
        return None if self._T is None else np.asarray(self._T.matrix())

    # ------------------------------------------------------------------------------- frames in
    def _as_graph_frame(self, frame: GraphFrame | FrameResult) -> tuple[GraphFrame, bool]:
        if isinstance(frame, GraphFrame):
            return frame, self.board.half_turn_symmetric
        if frame.board is None or frame.corners is None or not frame.used:
            raise ValueError(f"frame {frame.name!r} has no board in both sensors ({frame.reason})")
        gf = GraphFrame(
            frame.name,
            frame.board.T_lidar_board,
            frame.board.covariance,
            self.board.corners_board(),
            frame.corners.bearings,
            frame.corners.cov_px,
        )
        flippable = self.board.half_turn_symmetric and (
            frame.board.half_turn_ambiguous or frame.corners.half_turn_ambiguous
        )
        return gf, flippable

    def _flipped(self, f: GraphFrame) -> GraphFrame:
        perm = self.board.half_turn_permutation()
        return GraphFrame(f.name, f.T_lidar_board, f.board_cov, f.points_board, f.bearings[perm], f.cov_px[perm])

    def add_frame(self, frame: GraphFrame | FrameResult) -> FrameUpdate:
        """Add one frame (a ``GraphFrame``, or the pipeline's ``FrameResult`` with board and corners).

        Returns the state after the update; ``FrameUpdate`` unpacks as ``(T_cam_lidar, sigmas, reached)``.
        """
        t0 = time.perf_counter()
        gf, flippable = self._as_graph_frame(frame)
        if gf.name in self._names:
            raise ValueError(f"frame name {gf.name!r} added twice")
        self._names.add(gf.name)
        if self._T is None:
            self._pending.append(_Pending(gf, flippable))
            if self.T_init is None and len(self._pending) < self.init_frames:
                return self._update(gf.name, t0, True, f"waiting for {self.init_frames} frames to initialise")
            return self._initialise(gf.name, t0)
        if flippable:
            gf = self._better_order(gf)
        ok, reason = self._gate(gf)
        if not ok:
            return self._update(gf.name, t0, False, reason)
        self._insert([gf], first=False)
        return self._update(gf.name, t0, True, None)

    def _initialise(self, name: str, t0: float) -> FrameUpdate:
        frames = [p.frame for p in self._pending]
        flips = [p.flippable for p in self._pending]
        self._pending = []
        lidar = [f.points_board @ f.T_lidar_board[:3, :3].T + f.T_lidar_board[:3, 3] for f in frames]
        perm = self.board.half_turn_permutation() if self.board.half_turn_symmetric else None
        if self.T_init is None:
            order = resolve_half_turns(lidar, [f.bearings for f in frames], perm, [f.name for f in frames],
                                       flippable=flips)
            kept = [
                self._flipped(f) if order.flip.get(f.name, False) else f
                for f in frames
                if f.name in order.flip
            ]
            for n, why in order.dropped:
                log.info("frame %s dropped at initialisation: %s", n, why)
            if not kept:
                raise CalibrationImpossible("no frame left to initialise the extrinsic")
            P = np.vstack([f.points_board @ f.T_lidar_board[:3, :3].T + f.T_lidar_board[:3, 3] for f in kept])
            F = np.vstack([f.bearings / np.linalg.norm(f.bearings, axis=1, keepdims=True) for f in kept])
            T0 = gtsam.Pose3(upnp(P, F, prefer_front=True)[0].T_cam_points)
        else:
            T0 = gtsam.Pose3(np.asarray(self.T_init, dtype=np.float64))
            kept = frames
        self._T = T0
        if self.T_init is not None:
            kept = [self._better_order(f) if fl else f for f, fl in zip(frames, flips)]
        self._insert(kept, first=True)
        return self._update(name, t0, True, None)

    def _better_order(self, f: GraphFrame) -> GraphFrame:
        """The corner order (as given or half-turned) with the smaller bearing chi-square at the estimate."""
        if not self.board.half_turn_symmetric or self._T is None:
            return f
        g = self._flipped(f)
        return g if self._frame_chi2(g)[0] < self._frame_chi2(f)[0] else f

    def _frame_chi2(self, f: GraphFrame) -> tuple[float, int]:
        """Chi-square of a frame with its board re-fitted (Gauss-Newton) and the extrinsic held fixed."""
        fac = view_factor(X(0), B(0), f.points_board, f.bearings, f.cov_px, self.camera)
        if fac is None:
            return math.inf, 0
        prior = gtsam.Pose3(np.asarray(f.T_lidar_board, dtype=np.float64))
        L = np.linalg.cholesky(np.linalg.inv(np.asarray(f.board_cov, dtype=np.float64)))
        T_lb = prior
        for _ in range(5):
            r, _, A = fac.evaluate(self._T, T_lb, True)
            xi = np.asarray(prior.localCoordinates(T_lb))
            # prior residual L^T xi; its Jacobian ~ L^T (right-invariant error, first order)
            Aall = np.vstack([A, L.T])
            rall = np.concatenate([r, L.T @ xi])
            step = np.linalg.lstsq(Aall, -rall, rcond=None)[0]
            T_lb = T_lb.retract(step)
            if np.linalg.norm(step) < 1e-10:
                break
        r = fac.evaluate(self._T, T_lb, False)[0]
        xi = np.asarray(prior.localCoordinates(T_lb))
        return float(r @ r + xi @ np.linalg.solve(f.board_cov, xi)), fac.dim

    def _gate(self, f: GraphFrame) -> tuple[bool, str | None]:
        if self.gate_prob is None:
            return True, None
        c2, dof = self._frame_chi2(f)
        if dof == 0:
            return False, "fewer than 3 corners with a usable bearing covariance"
        bound = float(chi2_dist.ppf(self.gate_prob, dof))
        if c2 > bound:
            return False, f"chi-square gate: {c2:.1f} > {bound:.1f} ({dof} dof, p={self.gate_prob})"
        return True, None

    def _insert(self, frames: Iterable[GraphFrame], first: bool) -> None:
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        if first:
            values.insert(X(0), self._T)
        n = 0
        for f in frames:
            i = len(self._frames)
            fac = view_factor(X(0), B(i), f.points_board, f.bearings, f.cov_px, self.camera)
            if fac is None:
                log.info("frame %s skipped: fewer than 3 usable corners", f.name)
                continue
            prior = gtsam.Pose3(np.asarray(f.T_lidar_board, dtype=np.float64))
            graph.add(gtsam.PriorFactorPose3(B(i), prior, gtsam.noiseModel.Gaussian.Covariance(f.board_cov)))
            graph.add(fac.factor())
            values.insert(B(i), prior)
            self._frames.append(f)
            n += 1
        if first and n == 0:
            raise CalibrationImpossible("no usable frame to start the incremental graph")
        self._isam.update(graph, values)
        if first:
            for _ in range(10):  # converge from the start before the first answer
                before = self._isam.calculateEstimatePose3(X(0))
                self._isam.update()
                after = self._isam.calculateEstimatePose3(X(0))
                if np.abs(before.localCoordinates(after)).max() < 1e-9:
                    break
        self._T = self._isam.calculateEstimatePose3(X(0))
        self._cov = None

    def finish(self, max_iterations: int = 20, tol: float = 1e-10) -> FrameUpdate:
        """Relinearise every variable and iterate until ``T_cam_lidar`` stops moving: the batch optimum."""
        t0 = time.perf_counter()
        if self._T is None:
            if not self._pending:
                raise CalibrationImpossible("no frame was added")
            return self._initialise(self._pending[-1].frame.name, t0)
        params = gtsam.ISAM2UpdateParams()
        params.force_relinearize = True
        for _ in range(max_iterations):
            before = self._isam.calculateEstimatePose3(X(0))
            self._isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), params)
            after = self._isam.calculateEstimatePose3(X(0))
            if np.abs(before.localCoordinates(after)).max() < tol:
                break
        self._T = self._isam.calculateEstimatePose3(X(0))
        return self._update("", t0, True, None)

    # -------------------------------------------------------------------------------- results
    def _update(self, name: str, t0: float, accepted: bool, reason: str | None) -> FrameUpdate:
        if self._T is None:
            return FrameUpdate(None, np.full(6, np.inf), False, np.full((6, 6), np.nan), name, accepted, reason,
                               0, time.perf_counter() - t0)
        cov = np.asarray(self._isam.marginalCovariance(X(0)), dtype=np.float64)
        cov = 0.5 * (cov + cov.T)
        self._cov = cov
        sig = np.sqrt(np.diag(cov))
        reached = False
        if self.target_sigma is not None:
            rot_deg, trans_mm = self.target_sigma
            reached = bool(np.degrees(sig[:3]).max() <= rot_deg and 1e3 * sig[3:].max() <= trans_mm)
        return FrameUpdate(np.asarray(self._T.matrix()), sig, reached, cov, name, accepted, reason,
                           len(self._frames), time.perf_counter() - t0)


def format_update(u: FrameUpdate, target_sigma: tuple[float, float] | None = None) -> str:
    """One line for the command line: frame, count, sigmas in deg / mm, time, target status."""
    head = f"{u.name or '(final)':>10s}  n={u.n_frames:<4d}"
    if not u.accepted:
        return f"{head}  rejected: {u.reason}"
    if u.T_cam_lidar is None:
        return f"{head}  {u.reason or 'waiting'}"
    s = u.sigmas
    body = (
        f"sigma rot [deg] {np.degrees(s[0]):.3f} {np.degrees(s[1]):.3f} {np.degrees(s[2]):.3f}  "
        f"trans [mm] {1e3 * s[3]:.2f} {1e3 * s[4]:.2f} {1e3 * s[5]:.2f}  ({1e3 * u.seconds:.0f} ms)"
    )
    if target_sigma is not None:
        body += "  target reached" if u.reached_target else "  target not yet reached"
    return f"{head}  {body}"


def calibrate_incrementally(
    frames: Iterable[GraphFrame | FrameResult],
    camera: CameraModel,
    board: Board,
    T_init: np.ndarray | None = None,
    target_sigma: tuple[float, float] | None = None,
    report: Callable[[FrameUpdate], None] | None = None,
    stop_at_target: bool = False,
) -> tuple[IncrementalCalibrator, FrameUpdate]:
    """Feed ``frames`` one by one, calling ``report(update)`` after each (e.g. ``print(format_update(u))``).

    Frames without a board in both sensors are skipped. With ``stop_at_target`` it stops at the first
    frame that reaches ``target_sigma``. Returns the calibrator and the final update (after ``finish()``).
    """
    cal = IncrementalCalibrator(camera, board, T_init, target_sigma)
    for f in frames:
        if isinstance(f, FrameResult) and (not f.used or f.board is None or f.corners is None):
            continue
        u = cal.add_frame(f)
        if report is not None:
            report(u)
        if stop_at_target and u.reached_target:
            break
    final = cal.finish()
    if report is not None:
        report(final)
    return cal, final
