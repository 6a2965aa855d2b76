"""Incremental calibration with iSAM2: frames one at a time, the estimate and its sigmas after each.

The graph is the batch strategy's (``X(0)`` = ``T_cam_lidar``, ``B(i)`` = ``T_lidar_board`` of
frame i, the LiDAR prior and one grouped bearing factor per frame, built by ``graphs``), grown by
``gtsam.ISAM2``. Each frame adds one variable and two factors; iSAM2 re-eliminates only the cliques
they touch (``X(0)`` sits at the root) and relinearises only variables that moved more than
``relinearize_threshold``. While frames arrive, the sigmas come from the stated noise times the
variance factor the frames so far show (their graph's chi-square over its redundancy, at least 1: a
real LiDAR whose boards disagree beyond their stated noise, e.g. by its per-beam range offsets, is
not claimed to be better known than the frames show). ``finish()``
solves every frame offered with the batch strategy (the core's noise policy: gate, variance
components, final factor) from the current estimate, so its answer is the batch answer.

Half turns: with a symmetric board the image corner order is known only up to the half turn. The
first ``init_frames`` frames are ordered together with ``init.resolve_half_turns`` (and give the
UPnP start unless ``T_init`` is given); every later frame takes the order whose bearing residual at
the current estimate is smaller.

A frame whose chi-square (its board re-fitted with the extrinsic held at the current estimate)
exceeds the ``gate_prob`` quantile times that variance factor is rejected with the reason and changes
nothing while frames arrive; ``finish()`` judges every frame again, as the batch strategy does. (With
the stated noise alone, 16 of the 19 frames of the recorded VLP-16 set were rejected after the first
three: chi-square 190-500 for 70 dof, the variance factor of those three frames about 4.)
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, X

from factors import POSE3_DOF, FrameBearingFactor
from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation.batch import BatchSolution, solve
from ilcc_graph.estimation.graphs import frame_bearing_factor, upnp_start
from ilcc_graph.estimation.innovation import innovation_gate
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.noise import NoiseOptions
from ilcc_graph.estimation.solver import gaussian
from ilcc_graph.init import resolve_half_turns
from ilcc_graph.types import FrameResult, GraphFrame, reaches

log = logging.getLogger(__name__)

__all__ = ["FrameUpdate", "IncrementalCalibrator", "calibrate_incrementally"]


@dataclass(frozen=True)
class FrameUpdate:
    """The state after one ``add_frame``; unpacks as ``(T_cam_lidar, sigmas, reached_target)``.

    T_cam_lidar: (4, 4) current estimate, None while waiting for the first ``init_frames`` frames.
    sigmas: (6,) per-axis sigmas (rad, rad, rad, m, m, m); inf before the first estimate.
    reached_target: the largest 1-sigma in any direction within the target (``types.reaches``).
    covariance: (6, 6) interface.md convention (NaN before the first estimate).
    name: the frame's name. accepted: False when the frame was rejected (``reason`` says why).
    n_frames: frames in the graph. seconds: wall time of this update (iSAM2 + marginal).
    solution: after ``finish()``, the batch strategy's answer on every frame offered.
    variance_factor: the factor on the stated noise that ``covariance`` carries (the frames so far:
    their chi-square over its redundancy, at least 1; the batch's own after ``finish()``).
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
    solution: BatchSolution | None = None
    variance_factor: float = 1.0

    def __iter__(self) -> Iterator[np.ndarray | bool | None]:  # unpacks as its three main fields
        return iter((self.T_cam_lidar, self.sigmas, self.reached_target))


@dataclass
class _Pending:
    frame: GraphFrame
    flippable: bool


@dataclass
class IncrementalCalibrator:
    """Frames in, ``T_cam_lidar`` and sigmas out, one frame at a time (iSAM2).

    While frames arrive the sigmas come from the stated noise alone; ``finish()`` gives the batch
    strategy's answer (noise policy included) on every frame offered.

    Parameters
    ----------
    camera : the camera model (pixel covariances -> bearing covariances).
    board : the chessboard (corner grid; its half-turn symmetry).
    T_init : (4, 4) start; None: UPnP on the first ``init_frames`` frames.
    target_sigma : (rotation deg, translation mm): reached when every axis's sigma is at most these.
    init_frames : frames buffered before the first estimate when ``T_init`` is None (>= 1).
    relinearize_threshold : iSAM2's per-variable relinearisation threshold (rad / m).
    gate_prob : chi-square quantile above which a frame is rejected; None: never.
    noise : the noise policy of ``finish()``'s batch solve; lidar_errors: the LiDAR's own errors it estimates.
    models : the sensor models ``finish()`` chooses among (``estimation.selection``; None: as
        ``batch.solve``, ``beams`` with ``lidar_errors``, else ``none``); intrinsics_choice: ``auto``
        to refine the intrinsics when the boards support it (``batch.solve``).
    """

    camera: CameraModel
    board: Board
    T_init: np.ndarray | None = None
    target_sigma: tuple[float, float] | None = None
    init_frames: int = 3
    relinearize_threshold: float = 1e-3
    gate_prob: float | None = 0.999
    noise: NoiseOptions = NoiseOptions()
    lidar_errors: LidarErrorOptions | None = None
    intrinsics: IntrinsicsOptions | None = None
    models: tuple[str, ...] | None = None
    intrinsics_choice: str = "stated"
    _isam: gtsam.ISAM2 = field(init=False, repr=False)
    _pending: list[_Pending] = field(init=False, repr=False, default_factory=list)
    _frames: list[GraphFrame] = field(init=False, repr=False, default_factory=list)
    _offered: list[GraphFrame] = field(init=False, repr=False, default_factory=list)
    _flipped_names: set[str] = field(init=False, repr=False, default_factory=set)
    _names: set[str] = field(init=False, repr=False, default_factory=set)
    _T: gtsam.Pose3 | None = field(init=False, repr=False, default=None)
    _cov: np.ndarray | None = field(init=False, repr=False, default=None)
    _cov_stated: np.ndarray | None = field(init=False, repr=False, default=None)
    _scale: float = field(init=False, repr=False, default=1.0)
    _rows: int = field(init=False, repr=False, default=0)  # the bearing rows of the frames in the graph
    _scale_frames: int = field(init=False, repr=False, default=0)  # the frames when _scale was computed

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
    def offered(self) -> list[GraphFrame]:
        """Every frame offered, accepted or not, with the corner order chosen for it."""
        return list(self._offered)

    @property
    def flipped(self) -> set[str]:
        """Names of the offered frames whose image corners were half-turned (``bearings[perm]``)."""
        return set(self._flipped_names)

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
            frame.board.returns,
            frame.corners.uv,
        )
        flippable = self.board.half_turn_symmetric and (
            frame.board.half_turn_ambiguous or frame.corners.half_turn_ambiguous
        )
        return gf, flippable

    def _flipped(self, f: GraphFrame) -> GraphFrame:
        perm = self.board.half_turn_permutation()
        uv = None if f.uv is None else f.uv[perm]
        return dataclasses.replace(f, bearings=f.bearings[perm], cov_px=f.cov_px[perm], uv=uv)

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
        ready = self._better_order(gf) if flippable else (gf, self._factor(gf))
        self._offered.append(ready[0])
        ok, reason = self._gate(*ready)
        if not ok:
            return self._update(gf.name, t0, False, reason)
        self._insert([ready[0]], first=False)
        return self._update(gf.name, t0, True, None)

    def _initialise(self, name: str, t0: float) -> FrameUpdate:
        """First estimate from the buffered frames; frames the ordering could not place are retried."""
        frames = [p.frame for p in self._pending]
        flips = [p.flippable for p in self._pending]
        self._pending = []
        retry: list[GraphFrame] = []
        if self.T_init is not None:
            self._T = gtsam.Pose3(np.asarray(self.T_init, dtype=np.float64))
            kept = [self._better_order(f)[0] if fl else f for f, fl in zip(frames, flips)]
        else:
            chosen = frames
            if self.board.half_turn_symmetric and len(frames) > 1:
                lidar = [f.points_board @ f.T_lidar_board[:3, :3].T + f.T_lidar_board[:3, 3] for f in frames]
                order = resolve_half_turns(
                    lidar,
                    [f.bearings for f in frames],
                    self.board.half_turn_permutation(),
                    [f.name for f in frames],
                    flippable=flips,
                )
                chosen = [
                    self._flipped(f) if order.flip[f.name] else f for f in frames if f.name in order.flip
                ]
                self._flipped_names |= {n for n, fl in order.flip.items() if fl}
                retry = [f for f in frames if f.name not in order.flip]
                if not chosen:
                    raise CalibrationImpossible("no frame left to initialise the extrinsic")
            self._T = gtsam.Pose3(upnp_start(chosen))
            kept = chosen
        self._offered.extend(kept)
        self._insert(kept, first=True)
        if retry:
            self._update(name, t0, True, None)  # the covariance the gate needs
            for f in retry:
                ready = self._better_order(f)
                self._offered.append(ready[0])
                ok, reason = self._gate(*ready)
                if ok:
                    self._insert([ready[0]], first=False)
                    self._update(name, t0, True, None)
                else:
                    log.info("frame %s rejected at initialisation: %s", f.name, reason)
        return self._update(name, t0, True, None)

    @property
    def _pose(self) -> gtsam.Pose3:
        """The current extrinsic (there is one once the first frames initialised it)."""
        if self._T is None:
            raise RuntimeError("the extrinsic is not initialised yet")
        return self._T

    def _factor(self, f: GraphFrame, board: int = 0) -> FrameBearingFactor | None:
        """The frame's grouped bearing factor on (X(0), B(board))."""
        return frame_bearing_factor(X(0), B(board), f.points_board, f.bearings, f.cov_px, self.camera)[0]

    def _better_order(self, f: GraphFrame) -> tuple[GraphFrame, FrameBearingFactor | None]:
        """The corner order (as given or half-turned) with the smaller bearing chi-square at the current
        extrinsic and the board's prior pose (a wrong order is off by up to the board's size)."""
        fac = self._factor(f)
        if not self.board.half_turn_symmetric or self._T is None:
            return f, fac
        g = self._flipped(f)
        gfac = self._factor(g)
        prior = gtsam.Pose3(np.asarray(f.T_lidar_board, dtype=np.float64))
        T = self._T

        def cost(fc: FrameBearingFactor | None) -> float:
            return math.inf if fc is None else float(np.sum(fc.evaluate(T, prior, False)[0] ** 2))

        if cost(gfac) < cost(fac):
            self._flipped_names.add(f.name)
            return g, gfac
        return f, fac

    def _gate(self, f: GraphFrame, fac: FrameBearingFactor | None) -> tuple[bool, str | None]:
        return innovation_gate(f, fac, self._pose, self._cov_stated, self.gate_prob, self._scale)

    def _variance_factor(self) -> float:
        """The frames in the graph: their chi-square under the stated noise over its redundancy (the
        bearing rows less the extrinsic's 6; each board's prior and pose cancel), at least 1. It
        takes every frame's estimate, so it is computed again only when the frames have grown by a
        tenth since it last was (every frame up to 20): a constant cost per frame on average."""
        n = len(self._frames)
        if n > 20 and n < 1.1 * self._scale_frames:
            return self._scale
        self._scale_frames = n
        rows = self._rows - 6
        if rows <= 0:
            return 1.0
        chi2 = 2.0 * float(self._isam.getFactorsUnsafe().error(self._isam.calculateEstimate()))
        return max(1.0, chi2 / rows)

    def _insert(self, frames: Iterable[GraphFrame], first: bool) -> None:
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        if first:
            values.insert(X(0), self._pose)
        n = 0
        for f in frames:
            i = len(self._frames)
            fac = self._factor(f, i)
            if fac is None:
                log.info("frame %s skipped: fewer than 3 usable corners", f.name)
                continue
            prior = gtsam.Pose3(np.asarray(f.T_lidar_board, dtype=np.float64))
            graph.add(gtsam.PriorFactorPose3(B(i), prior, gaussian(f.board_cov)))
            graph.add(fac.factor())
            self._rows += fac.dim
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

    def finish(self) -> FrameUpdate:
        """The batch strategy on every frame offered, from the current estimate (its noise policy
        judges every frame again); iSAM2 restarts from that answer with the frames it kept, so
        frames may still be added afterwards."""
        t0 = time.perf_counter()
        if self._T is None:
            if not self._pending:
                raise CalibrationImpossible("no frame was added")
            self._initialise(self._pending[-1].frame.name, t0)
        T = np.asarray(self._pose.matrix())
        sol = solve(
            self._offered, self.camera, T, self.noise, self.lidar_errors, self.intrinsics,
            models=self.models, intrinsics_choice=self.intrinsics_choice,
        )  # fmt: skip
        kept = [f for f in self._offered if f.name in sol.per_frame]
        self._isam = gtsam.ISAM2(self._isam.params())
        self._frames, self._rows = [], 0
        self._T = gtsam.Pose3(sol.T_cam_lidar)
        self._insert(kept, first=True)
        self._T = gtsam.Pose3(sol.T_cam_lidar)
        self._cov = sol.covariance
        self._cov_stated = self._marginal()
        self._scale_frames = 0  # the frames kept: the factor afresh
        self._scale = self._variance_factor()
        return self._result("", t0, sol)

    # -------------------------------------------------------------------------------- results
    def _result(self, name: str, t0: float, sol: BatchSolution) -> FrameUpdate:
        sig = np.sqrt(np.diag(sol.covariance))
        n, dt = len(sol.per_frame), time.perf_counter() - t0
        return FrameUpdate(
            sol.T_cam_lidar, sig, self._reached(sol.covariance), sol.covariance, name, True, None, n, dt, sol,
            sol.variance_factor,
        )

    def _marginal(self) -> np.ndarray:
        """(6, 6) the extrinsic's marginal covariance under the stated noise."""
        cov = np.asarray(self._isam.marginalCovariance(X(0)), dtype=np.float64)
        return 0.5 * (cov + cov.T)

    def _reached(self, cov: np.ndarray) -> bool:
        """The target reached in every direction, as the verdict judges it (``types.reaches``)."""
        return reaches(cov, self.target_sigma)

    def _update(self, name: str, t0: float, accepted: bool, reason: str | None) -> FrameUpdate:
        if self._T is None:
            nan = np.full((6, 6), np.nan)
            return FrameUpdate(
                None, np.full(6, np.inf), False, nan, name, accepted, reason, 0, time.perf_counter() - t0
            )
        self._cov_stated = self._marginal()
        self._scale = self._variance_factor()
        cov = self._cov = self._scale * self._cov_stated
        sig = np.sqrt(np.diag(cov))
        T, n, dt = np.asarray(self._T.matrix()), len(self._frames), time.perf_counter() - t0
        return FrameUpdate(T, sig, self._reached(cov), cov, name, accepted, reason, n, dt, None, self._scale)


def calibrate_incrementally(
    frames: Iterable[GraphFrame | FrameResult],
    camera: CameraModel,
    board: Board,
    T_init: np.ndarray | None = None,
    target_sigma: tuple[float, float] | None = None,
    report: Callable[[FrameUpdate], None] | None = None,
    stop_at_target: bool = False,
) -> tuple[IncrementalCalibrator, FrameUpdate]:
    """Feed ``frames`` one by one, calling ``report(update)`` after each (e.g. printing
    ``run.strategies.solve_incremental.format_update(u)``).

    Frames without a board in both sensors are skipped (reported as not accepted, with their reason).
    With ``stop_at_target`` it stops at the first frame that reaches ``target_sigma`` (``frames`` may be
    a lazy iterator, so the rest are then never produced). Returns the calibrator and the final
    update (after ``finish()``).
    """
    cal = IncrementalCalibrator(camera, board, T_init, target_sigma)
    for f in frames:
        if isinstance(f, FrameResult) and (not f.used or f.board is None or f.corners is None):
            if report is not None:
                nan6, nan66 = np.full(POSE3_DOF, np.nan), np.full((POSE3_DOF, POSE3_DOF), np.nan)
                report(
                    FrameUpdate(cal.estimate, nan6, False, nan66, f.name, False, f.reason, len(cal.frames))
                )
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
