"""The paper's extrinsic refinement (Wang et al. 2017, Sec. 4.2), kept as a baseline for the graph.

The 3D corners are taken as given: ``p_lidar = T_lidar_board @ p_board`` with the LiDAR stage's
board poses held fixed. The extrinsic minimises, over all corners of all frames, the squared
differences of inclination and azimuth between the predicted bearing ``R p_lidar + t`` and the
measured one, both expressed in the paper's panoramic frame (x forward, y left, z up). The
azimuth difference is wrapped into (-pi, pi]. Unweighted, no covariance. scipy's
``least_squares`` over ``T = T_init * Expmap(xi)``, ``xi`` in R^6 (rotation first).
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np
from scipy.optimize import least_squares

from ilcc_graph.types import GraphFrame


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles (any shape, rad) wrapped into (-pi, pi]."""
    a = np.asarray(a, dtype=np.float64)
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def inclination_azimuth(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inclination (angle from +z, [0, pi]) and azimuth (atan2(y, x), (-pi, pi]) of vectors (N, 3)."""
    v = np.asarray(v, dtype=np.float64)
    incl = np.arctan2(np.hypot(v[:, 0], v[:, 1]), v[:, 2])
    az = wrap_angle(np.arctan2(v[:, 1], v[:, 0]))
    return incl, az


def paper_residuals(
    T_cam_lidar: np.ndarray, p_lidar: np.ndarray, b_pano: np.ndarray, R_pano_cam: np.ndarray
) -> np.ndarray:
    """Stacked residuals (2N,): inclination then wrapped azimuth differences (predicted - measured), rad.

    T_cam_lidar: (4, 4); p_lidar: (N, 3) LiDAR frame; b_pano: (N, 3) measured bearings already in the
    panoramic frame; R_pano_cam: (3, 3) camera frame -> panoramic frame.
    """
    p_cam = p_lidar @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]
    inc_p, az_p = inclination_azimuth(p_cam @ R_pano_cam.T)
    inc_m, az_m = inclination_azimuth(b_pano)
    return np.concatenate([inc_p - inc_m, wrap_angle(az_p - az_m)])


def refine_paper(
    frames: Sequence[GraphFrame],
    T_init: np.ndarray,
    R_pano_cam: np.ndarray | None = None,
    max_nfev: int = 200,
) -> np.ndarray:
    """The paper's refinement of ``T_cam_lidar`` (4, 4) from ``T_init`` (4, 4), board poses fixed.

    Parameters
    ----------
    frames : ``GraphFrame``s; only ``T_lidar_board``, ``points_board`` and ``bearings`` are used.
    T_init : (4, 4) starting ``T_cam_lidar``.
    R_pano_cam : (3, 3) rotation from the camera frame to the panoramic frame (x forward, y left,
        z up) in which inclination and azimuth are measured: the camera model's ``R_flu_cam``;
        None = identity (an equirectangular camera's).
    max_nfev : function-evaluation budget of ``least_squares``.

    Returns
    -------
    (4, 4) refined ``T_cam_lidar``.
    """
    T0 = np.asarray(T_init, dtype=np.float64)
    if T0.shape != (4, 4) or not np.all(np.isfinite(T0)):
        raise ValueError(f"refine_paper: T_init must be a finite (4, 4) transform, got shape {T0.shape}")
    if not frames:
        raise ValueError("refine_paper: no frames")
    R_pc = np.eye(3) if R_pano_cam is None else np.asarray(R_pano_cam, dtype=np.float64)
    if R_pc.shape != (3, 3) or np.abs(R_pc.T @ R_pc - np.eye(3)).max() > 1e-9:
        raise ValueError("refine_paper: R_pano_cam must be a (3, 3) rotation")
    p_lidar, b_pano = [], []
    for f in frames:
        T_lb = np.asarray(f.T_lidar_board, dtype=np.float64)
        p = np.asarray(f.points_board, dtype=np.float64) @ T_lb[:3, :3].T + T_lb[:3, 3]
        b = np.asarray(f.bearings, dtype=np.float64) @ R_pc.T
        ok = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(b), axis=1)
        p_lidar.append(p[ok])
        b_pano.append(b[ok])
    P, Bm = np.concatenate(p_lidar), np.concatenate(b_pano)
    if len(P) < 3:
        raise ValueError(f"refine_paper: need at least 3 corners, got {len(P)}")
    start = gtsam.Pose3(T0)

    def fun(xi: np.ndarray) -> np.ndarray:
        return paper_residuals((start * gtsam.Pose3.Expmap(xi)).matrix(), P, Bm, R_pc)

    result = least_squares(fun, np.zeros(6), method="lm", max_nfev=max_nfev)
    return (start * gtsam.Pose3.Expmap(result.x)).matrix()


def rms_bearing_mrad(T_cam_lidar: np.ndarray, f: GraphFrame) -> float:
    """RMS angle (mrad) between measured bearings and the corners predicted through T."""
    T = T_cam_lidar @ f.T_lidar_board
    p = f.points_board @ T[:3, :3].T + T[:3, 3]
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    ang = np.arctan2(np.linalg.norm(np.cross(p, f.bearings), axis=1), np.sum(p * f.bearings, axis=1))
    return float(1e3 * np.sqrt(np.mean(ang**2)))
