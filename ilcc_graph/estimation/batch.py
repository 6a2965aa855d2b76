"""Batch strategy: one data set, one extrinsic, every frame at once.

Variables ``X(0)`` = ``T_cam_lidar`` and ``B(i)`` = ``T_lidar_board`` of frame i; per frame the LiDAR
stage's prior on ``B(i)`` and one grouped bearing factor. Solved by the core's noise policy
(``noise.solve_problem``); the covariance is ``gtsam.Marginals``'s of ``X(0)`` times the final
variance factor, in interface.md's convention.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from ilcc_graph.cameras import CameraModel
from ilcc_graph.estimation.effects import Effect, ScaleEffect, sensor_effects, square_size_effect
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions, LidarLayout
from ilcc_graph.estimation.next_board import SolvedGlobals, solved_globals
from ilcc_graph.estimation.noise import BoardStats, NoiseOptions, Solution
from ilcc_graph.estimation.plane import BoardPlane
from ilcc_graph.estimation.problem import frames_problem
from ilcc_graph.estimation.selection import MODELS, Selection, SensorModel, averaged_covariance
from ilcc_graph.estimation.solver import check_pose
from ilcc_graph.estimation.sources import solve_sources
from ilcc_graph.types import Estimate, GraphFrame

__all__ = ["BatchSolution", "batch_solution", "sensor_models", "solve"]


@dataclass(frozen=True)
class BatchSolution:
    """The batch answer.

    T_cam_lidar: (4, 4). covariance: (6, 6) of ``T_cam_lidar`` (interface.md convention).
    T_lidar_board: refined board poses of the used frames. per_frame: their residual statistics.
    dropped: ``(name, reason)`` in the order dropped. variance_components: (board priors, bearings).
    lidar: the LiDAR's own errors (names, values, sigmas) when estimated; lidar_layout: which terms
    entered and which were left out (``layout.excluded``); lidar_covariance: their (n, n) marginal
    covariance. intrinsics: the camera's refined intrinsics (names, values, sigmas) when refined.
    effects: per group of sensor terms what holding it at the stated values moves the extrinsic
    (``effects.sensor_effects``). board_plane: the boards' plane sigmas used (estimated or
    configured; ``plane.BoardPlane``), None without the board-plane term. square_size: what a print
    0.1 % larger than the board's model would move (``effects.square_size_effect``; with ``effects``).
    selection: which sensor model was chosen and the evidence (``selection.Selection``); with
    candidates the boards could not tell apart, ``covariance`` is averaged over them. solved: the
    chosen model's globals a new board would touch (``next_board``: what one more board promises).
    failing: ``(name, reason)`` of used frames that fail the gate though it may drop no more.
    """

    T_cam_lidar: np.ndarray
    covariance: np.ndarray
    T_lidar_board: dict[str, np.ndarray]
    per_frame: dict[str, BoardStats]
    dropped: list[tuple[str, str]]
    iterations: int
    timings: dict[str, float] = field(default_factory=dict)
    variance_factor: float = 1.0
    variance_components: tuple[float, float] = (1.0, 1.0)
    lidar: tuple[list[str], np.ndarray, np.ndarray] | None = None
    lidar_layout: LidarLayout | None = None
    intrinsics: tuple[list[str], np.ndarray, np.ndarray] | None = None
    lidar_covariance: np.ndarray | None = None
    effects: dict[str, Effect] = field(default_factory=dict)
    board_plane: BoardPlane | None = None
    square_size: ScaleEffect | None = None
    selection: Selection | None = None
    solved: SolvedGlobals | None = None
    failing: list[tuple[str, str]] = field(default_factory=list)

    @property
    def extrinsic(self) -> Estimate:
        return Estimate(self.T_cam_lidar, self.covariance)

    @property
    def pose(self) -> gtsam.Pose3:
        """``T_cam_lidar`` as a ``gtsam.Pose3``."""
        return self.extrinsic.pose


def batch_solution(
    sol: Solution,
    e: int = 0,
    group: str = "",
    effects: dict[str, Effect] | None = None,
    square_size: ScaleEffect | None = None,
) -> BatchSolution:
    """The ``BatchSolution`` view of a solved problem (extrinsic ``e``, noise ``group``)."""
    est = sol.extrinsic(e)
    names = [b.name for b in sol.problem.boards]
    return BatchSolution(
        T_cam_lidar=est.T,
        covariance=est.covariance,
        T_lidar_board={names[i]: sol.board_pose(i) for i in sol.boards},
        per_frame={names[i]: sol.stats[i] for i in sol.boards},
        dropped=list(sol.dropped),
        iterations=sol.iterations,
        timings=sol.timings,
        variance_factor=sol.variance_factor,
        variance_components=sol.components(group),
        lidar=sol.lidar(0),
        lidar_layout=sol.assembly.layouts.get(0),
        intrinsics=sol.intrinsics(0),
        lidar_covariance=sol.lidar_covariance(0),
        effects=dict(effects or {}),
        square_size=square_size,
        board_plane=sol.board_plane(group) if sol.assembly.point_lidars(sol.boards) else None,
        failing=list(sol.failing),
    )


def sensor_models(names: Sequence[str] | None, lidar_errors: LidarErrorOptions | None) -> list[SensorModel]:
    """The candidate models: ``names`` (``selection.MODELS``), the ``beams`` one with ``lidar_errors``
    when given; None: ``beams`` alone with ``lidar_errors`` given, else ``none`` alone."""
    if names is None:
        names = ["beams"] if lidar_errors is not None else ["none"]
    out = []
    for n in names:
        if n not in MODELS:
            raise ValueError(f"unknown sensor model {n!r}; known: {', '.join(MODELS)}")
        m = MODELS[n]
        out.append(
            replace(m, lidar_errors=lidar_errors) if m.lidar_errors is not None and lidar_errors else m
        )
    return out


def solve(
    frames: Sequence[GraphFrame],
    camera: CameraModel,
    T_init: np.ndarray,
    options: NoiseOptions = NoiseOptions(),
    lidar_errors: LidarErrorOptions | None = None,
    intrinsics: IntrinsicsOptions | None = None,
    effects: bool = False,
    models: Sequence[str] | None = None,
    intrinsics_choice: str = "stated",
) -> BatchSolution:
    """Refine ``T_cam_lidar`` over all frames and return it with its marginal covariance.

    frames: the frames (``types.GraphFrame``), bearings in the camera frame of ``camera``.
    models: the sensor models to choose among (``selection.MODELS`` names, e.g. ``selection.AUTO``);
        one name forces it. None: ``beams`` when ``lidar_errors`` is given, else ``none``.
    lidar_errors: the options of the ``beams`` model (the LiDAR's own errors estimated from the
        frames' returns).
    intrinsics: refine the camera's intrinsics (frames need ``uv``), or propagate their stated sigmas.
    intrinsics_choice: ``stated`` (as ``intrinsics`` says) or ``auto``: with the LiDAR model chosen,
        refine the intrinsics when the boards support it (``camera_choice``; not with
        ``intrinsics.refine``).
    effects: also solve with the sensor terms taken back, to say what they moved (``BatchSolution.effects``),
        and say what the board's square size moves (``BatchSolution.square_size``).
    T_init: (4, 4) start (e.g. UPnP's). Raises CalibrationImpossible (no usable frame),
    IndeterminateSystem (the data do not determine ``T_cam_lidar``), ValueError (malformed input).
    """
    check_pose(T_init, "T_init")
    cands = sensor_models(models, lidar_errors)
    got = solve_sources(
        [frames_problem(frames, camera, T_init)], cands, options, intrinsics, intrinsics_choice
    )
    sol, selection = got.chosen[0], got.selection
    moved = sensor_effects(sol, options) if effects else None
    square = square_size_effect(sol) if effects else None
    out = replace(batch_solution(sol, effects=moved, square_size=square), selection=selection)
    out = replace(out, solved=solved_globals(sol))
    if got.refined:  # refined: its covariance, times the model's held-out factor
        out = replace(out, covariance=selection.factor * out.covariance)
    elif not selection.forced:
        out = replace(out, covariance=averaged_covariance(got.sols[0], selection))
    return out
