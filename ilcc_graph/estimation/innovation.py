"""A new frame judged against the current state (the incremental strategy's gate).

The frame's chi-square: Gauss-Newton over its board pose and the extrinsic, the board held by its
LiDAR prior, the extrinsic by a prior with its current marginal covariance (held fixed before the
first covariance). A right frame gives about 2K (its bearing rows); a wrong one far more.
"""

from __future__ import annotations

import gtsam
import numpy as np

from factors import FrameBearingFactor
from ilcc_graph.types import GraphFrame

from . import chi2 as chi2_dist

__all__ = ["innovation_chi2", "innovation_gate"]


def innovation_chi2(
    f: GraphFrame, fac: FrameBearingFactor, T_cam_lidar: gtsam.Pose3, cov_cam_lidar: np.ndarray | None
) -> float:
    """The frame's chi-square against the state ``T_cam_lidar`` with its (6, 6) marginal covariance
    ``cov_cam_lidar`` (Pose3 tangent; None: the extrinsic held fixed). ``fac``: the frame's bearing
    factor on (extrinsic, board)."""
    prior = gtsam.Pose3(np.asarray(f.T_lidar_board, dtype=np.float64))
    Lb = np.linalg.cholesky(np.linalg.inv(np.asarray(f.board_cov, dtype=np.float64))).T
    Lx = None if cov_cam_lidar is None else np.linalg.cholesky(np.linalg.inv(cov_cam_lidar)).T
    T_cl, T_lb = T_cam_lidar, prior

    def residuals(T_cl: gtsam.Pose3, T_lb: gtsam.Pose3) -> np.ndarray:
        parts = [fac.evaluate(T_cl, T_lb, False)[0], Lb @ np.asarray(prior.localCoordinates(T_lb))]
        if Lx is not None:
            parts.append(Lx @ np.asarray(T_cam_lidar.localCoordinates(T_cl)))
        return np.concatenate(parts)

    for _ in range(6):
        r, A_cam, A_board = fac.evaluate(T_cl, T_lb, True)
        xb = Lb @ np.asarray(prior.localCoordinates(T_lb))
        # normal equations; the priors' Jacobians to first order (identity in the tangent)
        Hbb = A_board.T @ A_board + Lb.T @ Lb
        gb = A_board.T @ r + Lb.T @ xb
        if Lx is None:
            step_b = -np.linalg.solve(Hbb, gb)
            T_lb = T_lb.retract(step_b)
            step = step_b
        else:
            xx = Lx @ np.asarray(T_cam_lidar.localCoordinates(T_cl))
            H = np.zeros((12, 12))
            H[:6, :6] = A_cam.T @ A_cam + Lx.T @ Lx
            H[:6, 6:] = A_cam.T @ A_board
            H[6:, :6] = H[:6, 6:].T
            H[6:, 6:] = Hbb
            step = -np.linalg.solve(H, np.concatenate([A_cam.T @ r + Lx.T @ xx, gb]))
            T_cl, T_lb = T_cl.retract(step[:6]), T_lb.retract(step[6:])
        if np.abs(step).max() < 1e-9:
            break
    r = residuals(T_cl, T_lb)
    return float(r @ r)


def innovation_gate(
    f: GraphFrame,
    fac: FrameBearingFactor | None,
    T_cam_lidar: gtsam.Pose3,
    cov_cam_lidar: np.ndarray | None,
    gate_prob: float | None,
    scale: float = 1.0,
) -> tuple[bool, str | None]:
    """(accepted, reason): the frame passes when its chi-square is at most the ``gate_prob`` quantile
    of its dof (None: always) times ``scale`` (the variance factor of the noise the frames so far
    show); a frame without a factor (too few usable corners) never does."""
    if fac is None:
        return False, "fewer than 3 corners with a usable bearing covariance"
    if gate_prob is None:
        return True, None
    c2, dof = innovation_chi2(f, fac, T_cam_lidar, cov_cam_lidar), fac.dim
    bound = float(chi2_dist.ppf(gate_prob, dof)) * scale
    if c2 > bound:
        times = f"; noise {scale:.2f} x stated, as the frames so far show" if scale != 1.0 else ""
        return False, f"chi-square gate: {c2:.1f} > {bound:.1f} ({dof} dof, p={gate_prob}{times})"
    return True, None
