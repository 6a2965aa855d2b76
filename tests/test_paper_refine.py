"""Tests of the paper's refinement baseline (inclination/azimuth residuals, boards fixed)."""

from __future__ import annotations

import gtsam
import numpy as np

from factors.testing import sample_bearing
from ilcc_graph.cameras import R_FLU_OPENCV as R_PANO_OPENCV
from ilcc_graph.estimation.paper import (
    inclination_azimuth,
    paper_residuals,
    refine_paper,
    wrap_angle,
)
from ilcc_graph.types import GraphFrame

T_TRUE = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.05, -0.02, 0.3), np.array([0.06, -0.1, -0.2]))
GRID = np.array([[(j + 1) * 0.075, (i + 1) * 0.075, 0.0] for i in range(5) for j in range(7)])


def _frames(rng, n, T_cam_lidar=T_TRUE, azimuths=None, noise_rad=0.0, R_pano_cam=np.eye(3)):
    """Boards facing the LiDAR at the given azimuths in the camera's panoramic frame."""
    frames = []
    T_lc = T_cam_lidar.inverse()
    for i in range(n):
        az = rng.uniform(-np.pi, np.pi) if azimuths is None else azimuths[i]
        el = rng.uniform(-0.3, 0.3)
        d = rng.uniform(2.0, 4.0)
        c_pano = d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        c_lidar = T_lc.transformFrom(R_pano_cam.T @ c_pano)
        z = -c_lidar / np.linalg.norm(c_lidar)
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z])
        T_lb = np.eye(4)
        T_lb[:3, :3], T_lb[:3, 3] = R, c_lidar - R @ GRID.mean(axis=0)
        p_lidar = GRID @ R.T + T_lb[:3, 3]
        p_cam = np.array([T_cam_lidar.transformFrom(p) for p in p_lidar])
        b = p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
        if noise_rad > 0:
            b = sample_bearing(rng, b, np.tile(np.eye(2) * noise_rad**2, (len(b), 1, 1)))
        frames.append(
            GraphFrame(f"{i:04d}", T_lb, np.eye(6) * 1e-6, GRID, b, np.tile(np.eye(2), (len(b), 1, 1)))
        )
    return frames


def _start(rng) -> np.ndarray:
    return (T_TRUE * gtsam.Pose3.Expmap(np.r_[rng.normal(0, 0.02, 3), rng.normal(0, 0.03, 3)])).matrix()


def test_wrap_angle_range() -> None:
    a = np.array([np.pi, -np.pi, 3 * np.pi / 2, -3 * np.pi / 2, 0.1, 2 * np.pi + 0.2, -7.0])
    w = wrap_angle(a)
    assert np.all((w > -np.pi) & (w <= np.pi))
    assert np.isclose(w[0], np.pi) and np.isclose(w[1], np.pi)
    assert np.allclose(np.exp(1j * w), np.exp(1j * a))
    incl, az = inclination_azimuth(np.array([[1.0, 0, 0], [0, 0, 1.0], [-1.0, -1e-12, 0]]))
    assert (
        np.allclose(incl, [np.pi / 2, 0, np.pi / 2])
        and np.isclose(az[0], 0)
        and np.isclose(abs(az[2]), np.pi)
    )


def test_noise_free_recovery_across_the_seam() -> None:
    """Boards straddling azimuth +-pi: the wrapped residual is zero at the truth, and LM converges."""
    rng = np.random.default_rng(0)
    frames = _frames(rng, 6, azimuths=[np.pi, -np.pi + 0.01, np.pi - 0.02, 0.5, -1.5, 2.0])
    P = np.concatenate([f.points_board @ f.T_lidar_board[:3, :3].T + f.T_lidar_board[:3, 3] for f in frames])
    Bm = np.concatenate([f.bearings for f in frames])
    assert np.abs(paper_residuals(T_TRUE.matrix(), P, Bm, np.eye(3))).max() < 1e-12
    # the unwrapped azimuth difference of seam corners jumps by 2 pi for a tiny rotation
    T_small = (T_TRUE * gtsam.Pose3.Expmap(np.r_[0, 0, 1e-3, 0, 0, 0])).matrix()
    assert np.abs(paper_residuals(T_small, P, Bm, np.eye(3))).max() < 0.01
    T = refine_paper(frames, _start(rng))
    assert np.allclose(gtsam.Pose3(T).localCoordinates(T_TRUE), 0, atol=1e-8)


def test_noisy_recovery_close_to_truth() -> None:
    rng = np.random.default_rng(1)
    frames = _frames(rng, 10, noise_rad=5e-4)
    T = refine_paper(frames, _start(rng))
    xi = gtsam.Pose3(T).localCoordinates(T_TRUE)
    assert np.degrees(np.linalg.norm(xi[:3])) < 0.05 and np.linalg.norm(xi[3:]) < 0.01
    # it minimises its cost: the truth is not better
    P = np.concatenate([f.points_board @ f.T_lidar_board[:3, :3].T + f.T_lidar_board[:3, 3] for f in frames])
    Bm = np.concatenate([f.bearings for f in frames])
    assert np.sum(paper_residuals(T, P, Bm, np.eye(3)) ** 2) <= np.sum(
        paper_residuals(T_TRUE.matrix(), P, Bm, np.eye(3)) ** 2
    )


def test_opencv_camera_frame() -> None:
    """Pinhole/fisheye bearings (z forward) are turned into the panoramic frame before the angles."""
    rng = np.random.default_rng(2)
    T_cv = gtsam.Pose3(gtsam.Rot3(R_PANO_OPENCV.T), np.zeros(3)) * T_TRUE
    frames = _frames(rng, 5, T_cam_lidar=T_cv, azimuths=rng.uniform(-0.6, 0.6, 5), R_pano_cam=R_PANO_OPENCV)
    assert np.all(np.concatenate([f.bearings[:, 2] for f in frames]) > 0.5)  # in front of the camera
    start = (T_cv * gtsam.Pose3.Expmap(np.r_[0.01, -0.02, 0.01, 0.02, 0.01, -0.02])).matrix()
    T = refine_paper(frames, start, R_pano_cam=R_PANO_OPENCV)
    assert np.allclose(gtsam.Pose3(T).localCoordinates(T_cv), 0, atol=1e-8)
