"""How much the sensors' own error terms moved the extrinsic.

A solved problem is solved once more with a group of terms taken back to what the user stated, on the
same boards (no gate), its variance components estimated again (the residuals change with the terms):

- ``lidar_errors``: the LiDAR's own errors (``L(l)``: per-beam offsets, dark print, ...) held at zero
  (their prior tightened to ``HOLD_SIGMA``), the boards' returns still in the graph, each board's
  plane at the sigmas the solution used (estimated ones held: else they would absorb the terms);
- ``camera_intrinsics``: the refined cameras' intrinsics at the config's values (the views as bearings
  through the stated camera).

The difference ``T_with^-1 T_without`` of ``T_cam_lidar`` is reported as a rotation (deg), a
translation (mm, of the camera's position in the LiDAR frame) and in sigmas of the estimate
(Mahalanobis distance under its covariance).

``square_size_effect``: what a print ``SCALE_STEP`` (0.1 %) larger than ``board.square_size`` would
move, to first order: the views' board points scaled about the pattern's centre (the LiDAR stage
centres the pattern in the returns, so its poses stay), one Gauss-Newton step of that graph from
the solution. The extrinsic and the beams' common range level move with the print's scale
(docs/bench_lidar_errors.md, finding 13: the LiDAR's range is measured against the print's size).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import gtsam
import numpy as np

from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem
from ilcc_graph.estimation.assembly import Assembly
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.keys import L, X
from ilcc_graph.estimation.noise import NoiseOptions, Solution, solve_problem

log = logging.getLogger(__name__)

__all__ = [
    "HOLD_SIGMA",
    "SCALE_STEP",
    "SQUARE_SIZE_KEY",
    "Effect",
    "ScaleEffect",
    "sensor_effects",
    "square_size_effect",
]

#: prior sigma that holds a LiDAR error term at zero (metres, -, rad as the term's unit)
HOLD_SIGMA = 1e-8
#: the relative error of the square size the sensitivity is given for (0.1 %)
SCALE_STEP = 1e-3
#: prefix of ``Calibration.diagnostics``' keys saying what such a print moves
SQUARE_SIZE_KEY = "square_size_0p1pct"


@dataclass(frozen=True)
class Effect:
    """What a group of terms changed in extrinsic ``T_cam_lidar``.

    rotation_deg: angle of ``T_with^-1 T_without``. translation_mm: distance between the camera's
    positions in the LiDAR frame. mahalanobis: ``sqrt(xi^T C^-1 xi)`` with ``xi = Logmap(T_with^-1
    T_without)`` and C the estimate's covariance (how many sigma the terms moved it).
    """

    rotation_deg: float
    translation_mm: float
    mahalanobis: float


def _effect(T_with: np.ndarray, T_without: np.ndarray, cov: np.ndarray) -> Effect:
    xi = np.asarray(gtsam.Pose3(T_with).localCoordinates(gtsam.Pose3(T_without)), dtype=np.float64)
    c_with = -T_with[:3, :3].T @ T_with[:3, 3]
    c_without = -T_without[:3, :3].T @ T_without[:3, 3]
    try:
        m = float(np.sqrt(max(float(xi @ np.linalg.solve(cov, xi)), 0.0)))
    except np.linalg.LinAlgError:
        m = float("nan")
    return Effect(
        float(np.degrees(np.linalg.norm(xi[:3]))), float(1e3 * np.linalg.norm(c_with - c_without)), m
    )


def sensor_effects(sol: Solution, options: NoiseOptions = NoiseOptions(), e: int = 0) -> dict[str, Effect]:
    """Per group of sensor terms the solution estimated (``lidar_errors``, ``camera_intrinsics``), what
    taking it back moves extrinsic ``e`` (module docstring). Empty when it estimated none; a group
    whose re-solve fails is left out (and logged)."""
    out: dict[str, Effect] = {}
    problem = sol.problem
    names = [problem.boards[i].name for i in sol.boards]
    start = {x: sol.values.atPose3(X(x)) for x in sol.assembly.extrinsics(sol.boards)}
    T = np.asarray(sol.values.atPose3(X(e)).matrix(), dtype=np.float64)
    cov = None
    variants = {}
    lidars = sol.assembly.point_lidars(sol.boards)
    if lidars:
        held = {
            lid: replace(lay, priors=(HOLD_SIGMA,) * 4) if lid in lidars else lay
            for lid, lay in sol.assembly.layouts.items()
        }
        bp, lo = sol.board_plane(), problem.lidar_errors
        if bp is not None and lo is not None and lo.board_plane_estimate:
            lo = replace(
                lo,
                board_plane=None if lo.board_plane is None else (bp.offset_m, bp.tilt_rad),
                board_beam=None if lo.board_beam is None else bp.beam_m,
                board_plane_estimate=False,
            )
        variants["lidar_errors"] = (replace(problem, lidar_errors=lo), held)
    if sol.assembly.view_cameras(sol.boards):
        stated = replace(problem, intrinsics=IntrinsicsOptions(refine=False, propagate=False))
        variants["camera_intrinsics"] = (stated, dict(sol.assembly.layouts))
    for group, (pr, layouts) in variants.items():
        try:
            re = solve_problem(
                pr, options, boards=names, gate=False, start=start, layouts=layouts,
            )  # fmt: skip
        except (CalibrationImpossible, IndeterminateSystem, ValueError) as err:
            log.info("the extrinsic without the %s terms could not be solved: %s", group, err)
            continue
        if cov is None:
            cov = sol.extrinsic(e).covariance
        out[group] = _effect(T, np.asarray(re.values.atPose3(X(e)).matrix(), dtype=np.float64), cov)
    return out


@dataclass(frozen=True)
class ScaleEffect:
    """What a print ``SCALE_STEP`` larger than ``board.square_size`` would move (module docstring).

    extrinsic: the extrinsic's move. beams_mm: the mean move of the beams' range offsets (their
    common level), mm; None when the LiDAR's beam offsets are not estimated.
    """

    extrinsic: Effect
    beams_mm: float | None = None


def square_size_effect(sol: Solution, e: int = 0) -> ScaleEffect:
    """What a print 0.1 % larger than the boards' model would move in ``sol`` (first order). The
    pattern's centre is the middle of the corners the views saw (board frame)."""
    problem = sol.problem
    pts = np.concatenate([v.points_board for v in problem.views])
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    k = 1.0 + SCALE_STEP
    views = tuple(replace(v, points_board=centre + k * (v.points_board - centre)) for v in problem.views)
    asm = sol.assembly
    bigger = Assembly(replace(problem, views=views), asm.robust, asm.layouts, per_view=asm.per_view)

    base = asm.newton_step(sol.boards, sol.scales, sol.values)
    moved = bigger.newton_step(sol.boards, sol.scales, sol.values)
    xi = np.asarray(moved.at(X(e)) - base.at(X(e)), dtype=np.float64)
    T = sol.values.atPose3(X(e))
    T_moved = np.asarray(T.retract(xi).matrix(), dtype=np.float64)
    effect = _effect(np.asarray(T.matrix(), dtype=np.float64), T_moved, sol.extrinsic(e).covariance)
    beams = None
    for lid in asm.point_lidars(sol.boards):
        idx = [k for k, n in enumerate(asm.layouts[lid].names) if n.startswith("offset")]
        if idx:
            d = np.asarray(moved.at(L(lid)) - base.at(L(lid)), dtype=np.float64)
            beams = float(1e3 * np.mean(d[idx]))
            break
    return ScaleEffect(effect, beams)
