"""Pixel reprojection factor of a chessboard view, with the camera intrinsics as a variable.

A corner ``p_board`` (board frame, metres) measured at pixel ``uv_meas`` predicts

    p_cam = T_cam_lidar * T_lidar_board * p_board,     e = project(p_cam; theta) - uv_meas   (2,) px

``theta`` (a GTSAM Vector) holds the camera's refinable intrinsics. This module knows no camera
model (``factors/`` never imports ilcc_graph): the caller passes the projection as a callable

    project(p_cam (K, 3), theta (n,)) -> (uv (K, 2), J_p (K, 2, 3), J_theta (K, 2, n))

with analytic Jacobians, NaN where a point cannot be imaged. With ilcc_graph's cameras it is
``lambda p, theta: camera.with_intrinsics(theta).project_with_intrinsics_jacobian(p)``.

Whitening, robust weighting and grouping follow ``FrameBearingFactor``: one factor per view, each
corner whitened with its own 2x2 pixel covariance, a unit noise model of dimension 2K, an optional
m-estimator applied per corner. The pose Jacobians are chained in closed form:
``d p_cam / d T_cam_lidar = [-R_cl [p_lidar]x, R_cl]``,
``d p_cam / d T_lidar_board = R_cl [-R_lb [p_board]x, R_lb]`` (GTSAM's ``transformFrom``).

A corner the camera cannot image at some estimate (a trial step that moves it behind a pinhole or
beyond a fisheye's largest angle) returns the whitened residual ``UNIMAGED_RESIDUAL`` on both
components with zero Jacobian rows, so Levenberg-Marquardt rejects such steps instead of meeting a
NaN. A panorama's pixel residual would wrap at the seam and degenerate at the poles, and it has no
intrinsics to refine: equirectangular cameras use the bearing factor (a theta of dimension 0 works
here all the same).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import gtsam
import numpy as np

from factors.grouped import CornerGroupFactor, MEstimator, pose_chain, sqrt_information

PIXEL_DOF = 2
#: Whitened residual (per component) of a corner that cannot be imaged at the current estimate.
UNIMAGED_RESIDUAL = 1e6

#: ``project(p_cam (K, 3), theta (n,)) -> (uv (K, 2), J_p (K, 2, 3), J_theta (K, 2, n))``.
Projection = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]

__all__ = ["PIXEL_DOF", "UNIMAGED_RESIDUAL", "FramePixelFactor", "Projection"]


class FramePixelFactor(CornerGroupFactor[gtsam.Pose3, gtsam.Pose3, np.ndarray | None]):
    """All corners of one view as one factor on (``T_cam_lidar``, ``T_lidar_board``, ``theta``).

    Parameters
    ----------
    key_cam_lidar, key_lidar_board : GTSAM keys of the two Pose3 variables.
    key_intrinsics : GTSAM key of the intrinsics Vector ``theta`` (n,), or None to hold them fixed
        at ``intrinsics`` (the factor then has the two pose keys only).
    points_board : (K, 3) corners in the board frame, metres.
    uv : (K, 2) measured pixels.
    cov_px : (K, 2, 2) pixel covariances, px^2.
    project : the camera's projection with Jacobians (module docstring).
    intrinsics : (n,) the fixed theta when ``key_intrinsics`` is None; else ignored (may be None).
    robust : optional ``gtsam.noiseModel.mEstimator`` applied per corner (as FrameBearingFactor).
    """

    def __init__(
        self,
        key_cam_lidar: int,
        key_lidar_board: int,
        key_intrinsics: int | None,
        points_board: np.ndarray,
        uv: np.ndarray,
        cov_px: np.ndarray,
        project: Projection,
        intrinsics: np.ndarray | None = None,
        robust: MEstimator | None = None,
    ) -> None:
        p = np.asarray(points_board, dtype=np.float64)
        q = np.asarray(uv, dtype=np.float64)
        c = np.asarray(cov_px, dtype=np.float64)
        K = len(p)
        if p.shape != (K, 3) or q.shape != (K, 2) or c.shape != (K, 2, 2) or K == 0:
            raise ValueError(
                "FramePixelFactor: need points_board (K,3), uv (K,2), cov_px (K,2,2) with K>0, "
                f"got {p.shape}, {q.shape}, {c.shape}"
            )
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
            raise ValueError("FramePixelFactor: points_board and uv must be finite")
        if key_intrinsics is None:
            if intrinsics is None:
                raise ValueError("FramePixelFactor: fixed intrinsics (key_intrinsics None) need `intrinsics`")
            theta = np.array(intrinsics, dtype=np.float64).ravel()
            self.keys: tuple[int, ...] = (int(key_cam_lidar), int(key_lidar_board))
        else:
            theta = None
            self.keys = (int(key_cam_lidar), int(key_lidar_board), int(key_intrinsics))
        self.fixed_intrinsics = theta
        self.points_board = p.copy()
        self.uv = q.copy()
        self.sqrt_info = sqrt_information(c)  # (K, 2, 2)
        self.project = project
        self.robust = robust
        self.n_corners = K

    def _variables(
        self, values: gtsam.Values, keys: Sequence[int]
    ) -> tuple[gtsam.Pose3, gtsam.Pose3, np.ndarray | None]:
        theta = values.atVector(keys[2]) if len(keys) == 3 else None
        return values.atPose3(keys[0]), values.atPose3(keys[1]), theta

    def _theta(self, theta: np.ndarray | None) -> np.ndarray:
        if self.fixed_intrinsics is not None:
            return self.fixed_intrinsics
        if theta is None:
            raise ValueError("FramePixelFactor: theta is a variable here; pass its value")
        return np.asarray(theta, dtype=np.float64).ravel()

    # -- the math, no GTSAM objects involved beyond the two poses
    def unwhitened(
        self,
        T_cam_lidar: gtsam.Pose3,
        T_lidar_board: gtsam.Pose3,
        theta: np.ndarray | None = None,
        jacobians: bool = False,
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """Pixel errors (K, 2) (predicted minus measured; NaN where not imaged) and, when asked,
        their Jacobians (K, 2, 6), (K, 2, 6), (K, 2, n) w.r.t. each pose and ``theta``.

        ``theta``: the intrinsics (n,); ignored when the factor holds them fixed.
        """
        th = self._theta(theta)
        R_cl, t_cl = T_cam_lidar.rotation().matrix(), T_cam_lidar.translation()
        R_lb, t_lb = T_lidar_board.rotation().matrix(), T_lidar_board.translation()
        p_lidar = self.points_board @ R_lb.T + t_lb
        p_cam = p_lidar @ R_cl.T + t_cl
        uv, J_p, J_t = self.project(p_cam, th)
        e = np.asarray(uv, dtype=np.float64) - self.uv
        if not jacobians:
            return e, None, None, None
        H_cam, H_board = pose_chain(
            np.asarray(J_p, dtype=np.float64) @ R_cl, R_lb, p_lidar, self.points_board
        )
        H_theta = np.asarray(J_t, dtype=np.float64).reshape(self.n_corners, 2, th.size)
        return e, H_cam, H_board, H_theta

    def whitened(
        self, T_cam_lidar: gtsam.Pose3, T_lidar_board: gtsam.Pose3, theta: np.ndarray | None = None
    ) -> np.ndarray:
        """Whitened errors (K, 2), no robust weighting (NaN where not imaged): ``|.|^2`` summed is the
        view's pixel chi-square."""
        e = self.unwhitened(T_cam_lidar, T_lidar_board, theta)[0]
        return np.einsum("kij,kj->ki", self.sqrt_info, e)

    def evaluate(
        self,
        T_cam_lidar: gtsam.Pose3,
        T_lidar_board: gtsam.Pose3,
        theta: np.ndarray | None,
        jacobians: bool,
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """What the CustomFactor returns: error (2K,) and ``order="F"`` Jacobians (2K, 6), (2K, 6),
        (2K, n) w.r.t. ``T_cam_lidar``, ``T_lidar_board``, ``theta`` (or None).

        Without Jacobians (cost evaluation) a robust factor scales ``r_k`` to ``sqrt(2 rho(|r_k|))``;
        with them (linearisation) it scales ``r_k`` and its rows by ``sqrt(w(|r_k|))``. A corner not
        imaged gives ``UNIMAGED_RESIDUAL`` on both rows (before robust scaling) and zero Jacobian rows.
        """
        e, H_cam, H_board, H_theta = self.unwhitened(T_cam_lidar, T_lidar_board, theta, jacobians)
        r = np.einsum("kij,kj->ki", self.sqrt_info, e)
        bad = ~np.all(np.isfinite(r), axis=1)
        if H_cam is not None and H_theta is not None:  # with jacobians
            bad |= ~(np.all(np.isfinite(H_cam), axis=(1, 2)) & np.all(np.isfinite(H_theta), axis=(1, 2)))
        r[bad] = UNIMAGED_RESIDUAL
        s = self._robust_scales(r, jacobians)
        if s is None:
            s = np.ones(self.n_corners)
        else:
            r = r * s[:, None]
        if H_cam is None or H_board is None or H_theta is None:  # without jacobians
            return r.reshape(-1), None, None, None
        Wt = self.sqrt_info * s[:, None, None]
        Wt[bad] = 0.0
        blocks = []
        for H in (H_cam, H_board, H_theta):
            H = np.where(bad[:, None, None], 0.0, H)
            blocks.append(np.asfortranarray((Wt @ H).reshape(self.dim, -1)))
        return r.reshape(-1), blocks[0], blocks[1], blocks[2]
