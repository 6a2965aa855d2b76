"""Hand the calibrated extrinsic to a user's GTSAM problem.

The calibration file (``calibration.yaml``, see ``shared/interface.md``) holds ``T_cam_lidar``
(4x4, ``p_cam = R @ p_lidar + t``) and its 6x6 covariance in GTSAM's Pose3 tangent convention
``T_true = T_est * Pose3.Expmap(xi)``, ``xi = (rx, ry, rz, tx, ty, tz)``, rotation first, radians
and metres. This module loads both as a ``gtsam.Pose3`` and a numpy array, builds the prior
factor a mapping graph needs, and converts the pair to the inverse direction (``T_lidar_cam``).
See ``docs/extrinsic_in_gtsam.md``.
"""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np

from ilcc_graph.errors import InputError
from ilcc_graph.io.stored import covariance_problem, read_stored
from ilcc_graph.types import Calibration, sigma_dict

__all__ = [
    "load_calibration", "extrinsic_prior", "invert_with_covariance", "check_rigid", "check_covariance",
    "to_pose3", "sigma_dict",
]  # fmt: skip

POSE3_DOF = 6
_RIGID_TOL = 1e-6  # max |R^T R - I| and |last row - [0 0 0 1]| accepted in a file


def check_rigid(T: np.ndarray, what: str = "T_cam_lidar") -> np.ndarray:
    """Return ``T`` (4, 4) as float64 with its rotation re-projected onto SO(3).

    Raises ``ValueError`` naming ``what`` when the shape is wrong, a number is not finite, the
    last row is not ``[0, 0, 0, 1]``, or the 3x3 block is further than 1e-6 from a rotation.
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"{what}: expected a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError(f"{what}: contains non-finite numbers")
    if np.max(np.abs(T[3] - [0.0, 0.0, 0.0, 1.0])) > _RIGID_TOL:
        raise ValueError(f"{what}: last row is {T[3].tolist()}, expected [0, 0, 0, 1]")
    R = T[:3, :3]
    off = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if off > _RIGID_TOL or np.linalg.det(R) <= 0.0:
        raise ValueError(
            f"{what}: not a rigid transform (max |R^T R - I| = {off:.3g}, det R = {np.linalg.det(R):.6g})"
        )
    U, _, Vt = np.linalg.svd(R)
    out = T.copy()
    out[:3, :3] = U @ Vt
    out[3] = [0.0, 0.0, 0.0, 1.0]
    return out


def check_covariance(cov: np.ndarray, what: str = "covariance") -> np.ndarray:
    """Return ``cov`` (6, 6) as a symmetric float64 array.

    Raises ``ValueError`` naming ``what`` when the shape is wrong, it is not symmetric (relative
    tolerance 1e-9) or not positive definite.
    """
    cov = np.asarray(cov, dtype=np.float64)
    if cov.shape != (POSE3_DOF, POSE3_DOF):
        raise ValueError(f"{what}: expected a 6x6 matrix, got shape {cov.shape}")
    problem = covariance_problem(cov)  # the one validation (io.stored), as a stored file's
    if problem is not None:
        raise ValueError(f"{what}: {problem}")
    return 0.5 * (cov + cov.T)


def to_pose3(T: gtsam.Pose3 | np.ndarray, what: str = "T_cam_lidar") -> gtsam.Pose3:
    """A ``gtsam.Pose3`` from a Pose3 or a 4x4 rigid matrix (checked with ``check_rigid``)."""
    if isinstance(T, gtsam.Pose3):
        return T
    return gtsam.Pose3(check_rigid(T, what))


def load_calibration(path: str | Path) -> tuple[gtsam.Pose3, np.ndarray]:
    """Load the extrinsic and its covariance from a ``calibration.yaml``.

    Parameters
    ----------
    path : the calibration file written by ``ilcc-graph calibrate`` (read with
        ``ilcc_graph.io.stored.read_stored``, the one reader and validation; only ``T_cam_lidar`` and
        ``covariance`` are used).

    Returns
    -------
    T_cam_lidar : gtsam.Pose3, ``p_cam = T_cam_lidar.transformFrom(p_lidar)``.
    covariance : (6, 6) float64, Pose3 tangent of ``T_cam_lidar`` (rotation first, rad and m).

    Raises
    ------
    InputError : naming the file and the problem (unreadable, missing key, non-rigid matrix,
        covariance not symmetric positive definite).
    """
    path = Path(path)
    cal = read_stored(path)  # the one reader and validation of a stored calibration (io.stored)
    if not isinstance(cal, Calibration):
        raise InputError(f"{path}: a rig's calibration: its poses go into a graph with handoff_rig.rig_prior")
    T, cov = cal.T_cam_lidar, cal.covariance
    try:
        return gtsam.Pose3(check_rigid(T, "T_cam_lidar")), check_covariance(cov, "covariance")
    except ValueError as e:
        raise InputError(f"{path}: {e}") from e


def extrinsic_prior(
    key: int,
    path_or_pose: str | Path | gtsam.Pose3 | np.ndarray,
    covariance: np.ndarray | None = None,
    inflate: float = 1.0,
) -> gtsam.PriorFactorPose3:
    """A ``PriorFactorPose3`` on the user's extrinsic variable ``key`` (which holds ``T_cam_lidar``).

    Parameters
    ----------
    key : the variable's key, e.g. ``gtsam.symbol('E', 0)``.
    path_or_pose : a calibration file, or the mean as ``gtsam.Pose3`` / (4, 4) matrix.
    covariance : (6, 6) Pose3-tangent covariance; required with a pose, and when given with a
        file it replaces the file's.
    inflate : factor on the sigmas (the covariance is multiplied by ``inflate**2``), e.g. to
        allow for a mount that may have moved since the calibration.

    The factor's noise model is ``noiseModel.Gaussian.Covariance``; its error is
    ``Logmap(mean^-1 * T)``, zero at the mean, with information ``inv(covariance) / inflate**2``.
    A variable holding ``T_lidar_cam`` needs ``invert_with_covariance`` first.
    """
    if not np.isfinite(inflate) or inflate <= 0.0:
        raise ValueError(f"inflate must be a positive number, got {inflate!r}")
    if isinstance(path_or_pose, (str, Path)):
        pose, file_cov = load_calibration(path_or_pose)
        cov = file_cov if covariance is None else check_covariance(covariance)
    else:
        if covariance is None:
            raise ValueError("extrinsic_prior: a covariance is required when the mean is given as a pose")
        pose, cov = to_pose3(path_or_pose), check_covariance(covariance)
    # smart=False keeps correlations below 1e-9 (rad^2, m^2), which GTSAM's default would drop
    noise = gtsam.noiseModel.Gaussian.Covariance(cov * float(inflate) ** 2, False)
    return gtsam.PriorFactorPose3(key, pose, noise)


def invert_with_covariance(pose: gtsam.Pose3 | np.ndarray, cov: np.ndarray) -> tuple[gtsam.Pose3, np.ndarray]:
    """The inverse pose and its covariance in the same right-perturbation convention.

    With ``T_true = T * Exp(xi)``: ``T_true^-1 = Exp(-xi) T^-1 = T^-1 * Exp(-Ad(T) xi)``, since
    ``T Exp(v) T^-1 = Exp(Ad(T) v)``. So the inverse's tangent error is ``xi' = -Ad(T) xi`` and
    ``cov' = Ad(T) cov Ad(T)^T`` with ``Ad(T)`` = ``T.AdjointMap()`` of the *original* pose (for
    ``T_cam_lidar``: ``[[R, 0], [[t]x R, R]]``, rotation first).

    Parameters
    ----------
    pose : ``T_a_b`` as Pose3 or (4, 4).
    cov : (6, 6) covariance of ``T_a_b``.

    Returns
    -------
    (``T_b_a`` as gtsam.Pose3, its (6, 6) covariance).
    """
    T = to_pose3(pose, "pose")
    cov = check_covariance(cov)
    Ad = T.AdjointMap()
    out = Ad @ cov @ Ad.T
    return T.inverse(), 0.5 * (out + out.T)
