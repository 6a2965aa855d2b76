"""Spherical bearing factors for LiDAR-camera extrinsic calibration with a chessboard.

A chessboard corner ``p_board`` (board frame, metres) seen by the camera along the unit bearing
``b_meas`` (camera frame) predicts ``p_cam = T_cam_lidar * T_lidar_board * p_board``. The residual
lives on the tangent plane of the *measured* bearing::

    e = Unit3(b_meas).errorVector(Unit3(p_cam))  = B(b_meas)^T p_cam / |p_cam|      (2,)

with ``B(b)`` GTSAM's tangent basis ``Unit3(b).basis()`` (3, 2). It has no wrap at +-180 deg
azimuth and no singularity at the poles; it is the sine of the angle between the two bearings
split along ``B``, so a bearing covariance given in the basis ``B(b_meas)`` whitens it directly.

Jacobians are analytic. The single-corner functions chain GTSAM's own derivatives
(``Pose3.transformFrom``, ``Unit3.FromPoint3``, ``Unit3.errorVector``); the per-frame grouped
factor evaluates the same chain in closed form with numpy for all corners at once and is tested
against the single-corner chain.

Variables (GTSAM Pose3 retraction ``T * Expmap(xi)``, ``xi = (rx, ry, rz, tx, ty, tz)``):
``T_cam_lidar`` (Pose3), ``T_lidar_board`` (Pose3), or a corner ``p_lidar`` (Point3).

Why grouped: a Python ``CustomFactor`` called from inside GTSAM's optimizers receives a *copy* of
the whole ``Values`` per call (pybind11 copies a ``const Values&`` that Python does not own), so one
iteration costs O(factors x variables). One factor per frame keeps both small (see docs/factors.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, overload

import gtsam
import numpy as np

from factors.grouped import POSE3_DOF, CornerGroupFactor, MEstimator, pose_chain, sqrt_information

BEARING_DOF = 2

__all__ = [
    "BEARING_DOF",
    "FrameBearingFactor",
    "bearing_error",
    "bearing_factor",
    "bearing_point_factor",
    "board_bearing_error",
    "tangent_bases",
]


# ----------------------------------------------------------------------------- single corner
def bearing_error(
    T_cam_lidar: gtsam.Pose3,
    p_lidar: np.ndarray,
    b_meas: gtsam.Unit3,
    H_T: np.ndarray | None = None,
    H_p: np.ndarray | None = None,
) -> np.ndarray:
    """Tangent-plane bearing error of one LiDAR-frame point.

    Parameters
    ----------
    T_cam_lidar : extrinsic, ``p_cam = T_cam_lidar * p_lidar``.
    p_lidar : (3,) point, LiDAR frame, metres.
    b_meas : measured bearing, camera frame.
    H_T, H_p : optional preallocated ``order="F"`` arrays (2, 6) and (2, 3), filled in place with
        the derivatives w.r.t. ``T_cam_lidar`` (GTSAM Pose3 tangent) and ``p_lidar``.

    Returns
    -------
    (2,) ``b_meas.errorVector(Unit3(p_cam))``, in the basis ``b_meas.basis()``.
    """
    D_pc_T = np.zeros((3, POSE3_DOF), order="F")
    D_pc_p = np.zeros((3, 3), order="F")
    D_u_pc = np.zeros((2, 3), order="F")
    D_e_u = np.zeros((2, 2), order="F")
    p_cam = T_cam_lidar.transformFrom(np.asarray(p_lidar, dtype=np.float64), D_pc_T, D_pc_p)
    e = b_meas.errorVector(gtsam.Unit3.FromPoint3(p_cam, D_u_pc), None, D_e_u)
    if H_T is not None or H_p is not None:
        D_e_pc = D_e_u @ D_u_pc
        if H_T is not None:
            H_T[:] = D_e_pc @ D_pc_T
        if H_p is not None:
            H_p[:] = D_e_pc @ D_pc_p
    return np.asarray(e, dtype=np.float64).reshape(BEARING_DOF)


def board_bearing_error(
    T_cam_lidar: gtsam.Pose3,
    T_lidar_board: gtsam.Pose3,
    p_board: np.ndarray,
    b_meas: gtsam.Unit3,
    H_cam: np.ndarray | None = None,
    H_board: np.ndarray | None = None,
) -> np.ndarray:
    """Tangent-plane bearing error of one board corner.

    Parameters
    ----------
    T_cam_lidar, T_lidar_board : the extrinsic and the board pose (``p_lidar = T_lidar_board * p_board``).
    p_board : (3,) corner in the board frame, metres (known grid, not a variable).
    b_meas : measured bearing, camera frame.
    H_cam, H_board : optional ``order="F"`` (2, 6) arrays filled with the derivatives w.r.t.
        ``T_cam_lidar`` and ``T_lidar_board`` (GTSAM Pose3 tangents).

    Returns
    -------
    (2,) error in the basis ``b_meas.basis()``.
    """
    D_pl_Tb = np.zeros((3, POSE3_DOF), order="F")
    p_lidar = T_lidar_board.transformFrom(np.asarray(p_board, dtype=np.float64), D_pl_Tb)
    if H_board is None:
        return bearing_error(T_cam_lidar, p_lidar, b_meas, H_cam, None)
    D_e_pl = np.zeros((2, 3), order="F")
    e = bearing_error(T_cam_lidar, p_lidar, b_meas, H_cam, D_e_pl)
    H_board[:] = D_e_pl @ D_pl_Tb
    return e


def _noise_or_unit(noise: gtsam.noiseModel.Base | None, dim: int) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Unit.Create(dim) if noise is None else noise


def bearing_factor(
    key_cam_lidar: int,
    key_lidar_board: int,
    p_board: np.ndarray,
    b_meas: np.ndarray | gtsam.Unit3,
    noise: gtsam.noiseModel.Base | None = None,
) -> gtsam.CustomFactor:
    """One corner; keys (``T_cam_lidar``, ``T_lidar_board``); error (2,) of ``board_bearing_error``.

    ``noise``: a 2-dim model in the basis ``Unit3(b_meas).basis()``, optionally wrapped in
    ``Robust``; None means unit. Build it with ``Gaussian.Covariance(cov, False)``: GTSAM's default
    ``smart=True`` zeroes off-diagonals below 1e-9, i.e. the real correlations of a bearing
    covariance in rad^2.
    """
    b = b_meas if isinstance(b_meas, gtsam.Unit3) else gtsam.Unit3(np.asarray(b_meas, dtype=np.float64))
    p = np.array(p_board, dtype=np.float64).reshape(3)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: gtsam.JacobianVector | None) -> np.ndarray:
        keys = this.keys()
        T_cl, T_lb = values.atPose3(keys[0]), values.atPose3(keys[1])
        if H is None:
            return board_bearing_error(T_cl, T_lb, p, b)
        H0 = np.zeros((BEARING_DOF, POSE3_DOF), order="F")
        H1 = np.zeros((BEARING_DOF, POSE3_DOF), order="F")
        e = board_bearing_error(T_cl, T_lb, p, b, H0, H1)
        H[0], H[1] = H0, H1
        return e

    return gtsam.CustomFactor(_noise_or_unit(noise, BEARING_DOF), [key_cam_lidar, key_lidar_board], error)


def bearing_point_factor(
    key_cam_lidar: int,
    key_point: int,
    b_meas: np.ndarray | gtsam.Unit3,
    noise: gtsam.noiseModel.Base | None = None,
) -> gtsam.CustomFactor:
    """One corner as a LiDAR-frame Point3 variable: keys (``T_cam_lidar`` Pose3, ``p_lidar`` Point3).

    The same residual as ``GeneralSFMFactorSphericalCamera`` with the camera pose
    ``T_lidar_cam = T_cam_lidar.inverse()``.
    """
    b = b_meas if isinstance(b_meas, gtsam.Unit3) else gtsam.Unit3(np.asarray(b_meas, dtype=np.float64))

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: gtsam.JacobianVector | None) -> np.ndarray:
        keys = this.keys()
        T_cl, p = values.atPose3(keys[0]), values.atPoint3(keys[1])
        if H is None:
            return bearing_error(T_cl, p, b)
        H0 = np.zeros((BEARING_DOF, POSE3_DOF), order="F")
        H1 = np.zeros((BEARING_DOF, 3), order="F")
        e = bearing_error(T_cl, p, b, H0, H1)
        H[0], H[1] = H0, H1
        return e

    return gtsam.CustomFactor(_noise_or_unit(noise, BEARING_DOF), [key_cam_lidar, key_point], error)


# ------------------------------------------------------------------------ helpers (vectorised)
def tangent_bases(bearings: np.ndarray | Sequence[gtsam.Unit3]) -> np.ndarray:
    """GTSAM tangent bases ``Unit3(b).basis()`` of bearings (K, 3) or a list of Unit3 -> (K, 3, 2)."""
    units = [
        b if isinstance(b, gtsam.Unit3) else gtsam.Unit3(np.asarray(b, dtype=np.float64)) for b in bearings
    ]
    if not units:
        return np.zeros((0, 3, BEARING_DOF))
    return np.stack([u.basis() for u in units])


# ------------------------------------------------------------------------- per-frame group
class FrameBearingFactor(CornerGroupFactor[gtsam.Pose3, gtsam.Pose3]):
    """All corners of one frame as one factor on (``T_cam_lidar``, ``T_lidar_board``).

    Each corner k has its own 2x2 bearing covariance ``cov_tangent[k]`` in the basis
    ``Unit3(bearings[k]).basis()``; the factor whitens inside (``R_k e_k`` with
    ``R_k^T R_k = inv(cov_tangent[k])``) and carries a unit noise model of dimension 2K, so that
    ``0.5 * |error|^2`` is half the frame's chi-square. An optional GTSAM m-estimator is applied per
    corner to the whitened 2-vector, exactly as ``noiseModel.Robust`` would do for a single-corner
    factor: linearisation is scaled by ``sqrt(w(|r_k|))`` and the cost is ``sum_k rho(|r_k|)``.

    Parameters
    ----------
    key_cam_lidar, key_lidar_board : GTSAM keys of the two Pose3 variables.
    points_board : (K, 3) corners in the board frame, metres.
    bearings : (K, 3) measured unit bearings, camera frame (normalised here).
    cov_tangent : (K, 2, 2) bearing covariances in the bases ``tangent_bases(bearings)``, rad^2.
    robust : optional ``gtsam.noiseModel.mEstimator`` (Huber, Cauchy, Tukey, ...).
    """

    def __init__(
        self,
        key_cam_lidar: int,
        key_lidar_board: int,
        points_board: np.ndarray,
        bearings: np.ndarray,
        cov_tangent: np.ndarray,
        robust: MEstimator | None = None,
    ) -> None:
        p = np.asarray(points_board, dtype=np.float64)
        b = np.asarray(bearings, dtype=np.float64)
        c = np.asarray(cov_tangent, dtype=np.float64)
        K = len(p)
        if p.shape != (K, 3) or b.shape != (K, 3) or c.shape != (K, 2, 2) or K == 0:
            raise ValueError(
                "FrameBearingFactor: need points_board (K,3), bearings (K,3), cov_tangent (K,2,2) with K>0, "
                f"got {p.shape}, {b.shape}, {c.shape}"
            )
        norms = np.linalg.norm(b, axis=1)
        if not np.all(np.isfinite(norms)) or np.any(norms == 0):
            raise ValueError("FrameBearingFactor: bearings must be finite and non-zero")
        self.keys = (int(key_cam_lidar), int(key_lidar_board))
        self.points_board = p.copy()
        self.units = [gtsam.Unit3(bk) for bk in b]
        self.bases = tangent_bases(self.units)  # (K, 3, 2)
        self.sqrt_info = sqrt_information(c)  # (K, 2, 2)
        self.robust = robust
        self.n_corners = K

    def _variables(self, values: gtsam.Values, keys: Sequence[int]) -> tuple[gtsam.Pose3, gtsam.Pose3]:
        return values.atPose3(keys[0]), values.atPose3(keys[1])

    # -- the math, no GTSAM objects involved beyond the two poses
    def unwhitened(
        self, T_cam_lidar: gtsam.Pose3, T_lidar_board: gtsam.Pose3, jacobians: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Tangent errors (K, 2) and, when asked, their Jacobians (K, 2, 6) w.r.t. each pose.

        Closed form of the chain in ``board_bearing_error``:
        ``d e / d p_cam = B^T (I - u u^T) / |p_cam|``, ``d p_cam / d T_cam_lidar = [-R_cl [p_lidar]x, R_cl]``,
        ``d p_cam / d T_lidar_board = R_cl [-R_lb [p_board]x, R_lb]``.
        """
        R_cl, t_cl = T_cam_lidar.rotation().matrix(), T_cam_lidar.translation()
        R_lb, t_lb = T_lidar_board.rotation().matrix(), T_lidar_board.translation()
        p_lidar = self.points_board @ R_lb.T + t_lb
        p_cam = p_lidar @ R_cl.T + t_cl
        r = np.linalg.norm(p_cam, axis=1)
        u = p_cam / r[:, None]
        e = np.einsum("kij,ki->kj", self.bases, u)  # B^T u
        if not jacobians:
            return e, None, None
        Bt = np.swapaxes(self.bases, 1, 2)  # (K, 2, 3)
        D_e_pc = (Bt - np.einsum("kj,ki->kji", e, u)) / r[:, None, None]  # B^T (I - u u^T) / r
        H_cam, H_board = pose_chain(D_e_pc @ R_cl, R_lb, p_lidar, self.points_board)
        return e, H_cam, H_board

    def whitened(self, T_cam_lidar: gtsam.Pose3, T_lidar_board: gtsam.Pose3) -> np.ndarray:
        """Whitened errors (K, 2), no robust weighting: ``|.|^2`` summed is the frame's bearing chi-square."""
        e = self.unwhitened(T_cam_lidar, T_lidar_board)[0]
        return np.einsum("kij,kj->ki", self.sqrt_info, e)

    @overload
    def evaluate(
        self, T_cam_lidar: gtsam.Pose3, T_lidar_board: gtsam.Pose3, jacobians: Literal[True]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...
    @overload
    def evaluate(
        self, T_cam_lidar: gtsam.Pose3, T_lidar_board: gtsam.Pose3, jacobians: bool
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]: ...
    def evaluate(
        self, T_cam_lidar: gtsam.Pose3, T_lidar_board: gtsam.Pose3, jacobians: bool
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """What the CustomFactor returns: error (2K,) and ``order="F"`` Jacobians (2K, 6) or None.

        Without Jacobians (cost evaluation) a robust factor scales ``r_k`` to ``sqrt(2 rho(|r_k|))``;
        with them (linearisation) it scales ``r_k`` and its rows by ``sqrt(w(|r_k|))``.
        """
        e, H_cam, H_board = self.unwhitened(T_cam_lidar, T_lidar_board, jacobians)
        r = np.einsum("kij,kj->ki", self.sqrt_info, e)
        s = self._robust_scales(r, jacobians)
        if s is not None:
            r = r * s[:, None]
        if H_cam is None or H_board is None:  # without jacobians
            return r.reshape(-1), None, None
        Wt = self.sqrt_info if s is None else self.sqrt_info * s[:, None, None]
        A_cam = np.asfortranarray((Wt @ H_cam).reshape(-1, POSE3_DOF))
        A_board = np.asfortranarray((Wt @ H_board).reshape(-1, POSE3_DOF))
        return r.reshape(-1), A_cam, A_board
