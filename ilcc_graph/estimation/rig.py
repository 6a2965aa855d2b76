"""Rig strategy: one LiDAR, several cameras; a board seen by several cameras is one variable.

One extrinsic ``X(c)`` = ``T_cam_lidar`` per camera, one board per placement with its LiDAR prior,
one grouped bearing factor per view (bearing noise group = the camera). Solved by the core's noise
policy; camera-to-camera transforms come with covariances from the joint marginal.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from ilcc_graph.cameras import CameraModel
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation.graphs import upnp_start
from ilcc_graph.estimation.keys import POSE3_DOF
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.noise import NoiseOptions, solve_problem
from ilcc_graph.estimation.problem import BoardPrior, Problem, View
from ilcc_graph.types import BoardReturns, Estimate, GraphFrame

__all__ = ["RigFrame", "RigOptions", "RigSolution", "RigView", "relative_pose", "solve_rig"]


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

    T_lidar_board (4, 4), board_cov (6, 6), points_board (K, 3), returns as ``types.GraphFrame``.
    """

    name: str
    T_lidar_board: np.ndarray
    board_cov: np.ndarray
    points_board: np.ndarray
    views: Sequence[RigView]
    returns: BoardReturns | None = None


@dataclass(frozen=True)
class RigOptions:
    """range_offset: estimate the LiDAR's range offset (weak prior ``range_offset_prior_sigma_m``);
    samples_board: (M, 3) board-face points for it (None: from the corners); noise: the noise policy;
    lidar_errors: the LiDAR's own errors to estimate from the boards' returns."""

    range_offset: bool = False
    range_offset_prior_sigma_m: float = 0.1
    samples_board: np.ndarray | None = None
    noise: NoiseOptions = NoiseOptions()
    lidar_errors: LidarErrorOptions | None = None


@dataclass(frozen=True)
class RigSolution:
    """The rig's answer.

    cameras: camera names in order. extrinsics: ``T_cam_lidar`` per camera. relative: for each
    ordered pair (a, b), a before b in ``cameras``, ``T_ca_cb`` (``p_ca = T_ca_cb p_cb``) with its
    covariance. joint_covariance: (6C, 6C) of the extrinsics in ``cameras`` order. range_offset:
    (value, sigma) metres when asked. T_lidar_board: refined board poses. dropped: frames the gate dropped.
    """

    cameras: tuple[str, ...]
    extrinsics: dict[str, Estimate]
    relative: dict[tuple[str, str], Estimate]
    joint_covariance: np.ndarray
    range_offset: tuple[float, float] | None
    T_lidar_board: dict[str, np.ndarray]
    iterations: int
    dropped: list[tuple[str, str]]


def relative_pose(T_a: np.ndarray, T_b: np.ndarray, joint_cov: np.ndarray) -> Estimate:
    """``T_a * T_b^-1`` with covariance from the 12x12 joint covariance of (``T_a``, ``T_b``).

    For extrinsics ``T_a = T_ca_lidar``, ``T_b = T_cb_lidar`` this is ``T_ca_cb`` (``p_ca = T_ca_cb p_cb``).
    Jacobians (right tangent): ``d/d a = Ad(T_b)``, ``d/d b = -Ad(T_b)``.
    """
    Ta, Tb = gtsam.Pose3(np.asarray(T_a, dtype=np.float64)), gtsam.Pose3(np.asarray(T_b, dtype=np.float64))
    Ad = Tb.AdjointMap()
    J = np.hstack([Ad, -Ad])
    C = J @ np.asarray(joint_cov, dtype=np.float64) @ J.T
    return Estimate(np.asarray(Ta.compose(Tb.inverse()).matrix()), 0.5 * (C + C.T))


def solve_rig(
    frames: Sequence[RigFrame],
    cameras: Mapping[str, CameraModel],
    T_init: Mapping[str, np.ndarray] | None = None,
    options: RigOptions = RigOptions(),
) -> RigSolution:
    """One extrinsic per camera; a board seen by several cameras is one variable.

    T_init: per camera (4, 4) ``T_cam_lidar`` start; missing cameras start from UPnP on their views.
    Raises CalibrationImpossible when a camera has no view of a board, IndeterminateSystem when the
    data do not determine an extrinsic.
    """
    names = tuple(cameras)
    index = {n: i for i, n in enumerate(names)}
    boards, views = [], []
    per_camera: dict[int, list[GraphFrame]] = {i: [] for i in range(len(names))}
    for f in frames:
        b = len(boards)
        boards.append(
            BoardPrior(f.name, f.T_lidar_board, f.board_cov, "", 0, options.samples_board, f.returns)
        )
        for v in f.views:
            if v.camera not in index:
                raise ValueError(
                    f"frame {f.name!r}: view of unknown camera {v.camera!r}; cameras: {list(names)}"
                )
            c = index[v.camera]
            p = f.points_board if v.corners is None else f.points_board[np.asarray(v.corners)]
            views.append(View(b, c, p, v.bearings, v.cov_px, cameras[v.camera], v.camera))
            per_camera[c].append(GraphFrame(f.name, f.T_lidar_board, f.board_cov, p, v.bearings, v.cov_px))
    init = {}
    for n, c in index.items():
        if not per_camera[c]:
            raise CalibrationImpossible(f"camera {n!r} has no usable view of a board")
        given = None if T_init is None else T_init.get(n)
        init[c] = upnp_start(per_camera[c]) if given is None else np.asarray(given, dtype=np.float64)
    sigma = options.range_offset_prior_sigma_m if options.range_offset else None
    problem = Problem(
        tuple(boards), tuple(views), init, range_offset_sigma_m=sigma, lidar_errors=options.lidar_errors
    )
    sol = solve_problem(problem, options.noise)
    ext = {n: sol.extrinsic(c) for n, c in index.items()}
    J = sol.joint_covariance(list(range(len(names))))
    rel: dict[tuple[str, str], Estimate] = {}
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            ia = np.r_[a * POSE3_DOF : (a + 1) * POSE3_DOF, b * POSE3_DOF : (b + 1) * POSE3_DOF]
            rel[(names[a], names[b])] = relative_pose(ext[names[a]].T, ext[names[b]].T, J[np.ix_(ia, ia)])
    return RigSolution(
        cameras=names,
        extrinsics=ext,
        relative=rel,
        joint_covariance=J,
        range_offset=sol.offset(0) if options.range_offset else None,
        T_lidar_board={boards[i].name: sol.board_pose(i) for i in sol.boards},
        iterations=sol.iterations,
        dropped=list(sol.dropped),
    )
