"""A simulated rig at the observation level: what the stages would report, without rendering.

For studies that need many rigs (``scripts/bench_rig.py``): the boards are the rig simulator's
(``rig_placements``, the same ``RigSpec``, a moved mount applied as ``RigSpec.poses`` does), each
sensor that sees the whole board (``rig_placements.sees``) reports

- a camera: the inner corners projected by its true model, each moved by pixel noise drawn from a
  random 2x2 covariance of about ``sigma_px`` (stated as ``cov_px``), bearings through the model;
- a LiDAR: the board's pose in its frame times ``Exp(xi)``, ``xi ~ N(0, C)`` with ``C`` a random
  covariance in the board's tangent (rotation about the board's x, y, z; translation along them) of
  about ``lidar_sigmas`` (rad, m) scaled by ``sqrt(16 / beams)`` (a 64-beam LiDAR half a 16-beam's),
  stated as the fit's covariance.

The default sizes are those the rendered rigs' stages report (docs/bench_rig.md). Each sensor has
its own random streams (``RigSpec.sensor_seed``), so a moved capture gives every other sensor the
same observations as the unmoved one of the same seed. Corner orders are as listed (no half turn).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ilcc_graph.types import BoardFit, ImageCorners, MomentResult

from .placements import frame_rng
from .rig_placements import rig_placements, sees
from .rig_spec import RigSpec

__all__ = ["LIDAR_SIGMAS", "SIGMA_PX", "observe_spec"]

PURPOSE_RIG_OBSERVATION = 10  # stream key (placements.py: 0-2, rig_spec.py: 7, 8, intrinsics.py: 9)
#: a 16-beam LiDAR's board fit: rotation about the board's x, y, z (rad), translation along them (m)
LIDAR_SIGMAS = (np.radians(0.35), np.radians(0.3), np.radians(0.1), 0.7e-3, 0.7e-3, 2.2e-3)
#: a corner's pixel sigma
SIGMA_PX = 0.1


def _spd(rng: np.random.Generator, sigmas: np.ndarray, mix: float) -> np.ndarray:
    """A covariance of about ``sigmas``, each scaled by 0.7-1.3, axes turned by up to ``mix`` rad."""
    s = np.asarray(sigmas) * rng.uniform(0.7, 1.3, len(sigmas))
    n = len(s)
    A = rng.normal(0.0, mix, (n, n))
    Q = np.linalg.qr(np.eye(n) + 0.5 * (A - A.T))[0]
    return Q @ np.diag(s**2) @ Q.T


def _pose_exp(xi: np.ndarray) -> np.ndarray:
    """(4, 4) ``Exp(xi)`` to first order in the translation (xi: rotation then translation)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(xi[:3]).as_matrix()
    T[:3, 3] = xi[3:]
    return T


def observe_spec(
    spec: RigSpec,
    sigma_px: float = SIGMA_PX,
    lidar_sigmas: tuple[float, ...] = LIDAR_SIGMAS,
) -> list[MomentResult]:
    """Per moment of ``spec`` what its stages would report (module docstring); moment names as
    ``simulate_moments``'s (``0001``...)."""
    poses = spec.poses()
    boards = rig_placements(spec, spec.with_(moved=None).poses())
    corners_board = spec.board.corners_board()
    sym = spec.board.half_turn_symmetric
    out = []
    for i, T_body_board in enumerate(boards):
        fits: dict[str, BoardFit] = {}
        views: dict[str, ImageCorners] = {}
        for s in spec.sensors:
            if not sees(s, poses[s.name], T_body_board, spec):
                continue
            rng = frame_rng(spec.sensor_seed(s.name), PURPOSE_RIG_OBSERVATION, i)
            T_s_board = np.linalg.solve(poses[s.name], T_body_board)
            p = corners_board @ T_s_board[:3, :3].T + T_s_board[:3, 3]
            if s.camera is not None:
                cam = s.camera
                cov = np.stack([_spd(rng, np.full(2, sigma_px), 1.0) for _ in p])
                uv = cam.project(p) + np.einsum(
                    "kij,kj->ki", np.linalg.cholesky(cov), rng.standard_normal(p.shape[:1] + (2,))
                )
                b = cam.bearing(uv)
                if np.all(np.isfinite(b)):
                    views[s.name] = ImageCorners(uv, b, cov, sym)
            else:
                beams = len(s.lidar.vertical_angles_deg)  # type: ignore[union-attr]
                C = _spd(rng, np.asarray(lidar_sigmas) * np.sqrt(16.0 / beams), 0.3)
                T = T_s_board @ _pose_exp(rng.multivariate_normal(np.zeros(6), C))
                c = corners_board @ T[:3, :3].T + T[:3, 3]
                fits[s.name] = BoardFit(T, C, c, np.zeros((0, 3)), np.zeros(0), sym)
        out.append(MomentResult(f"{i + 1:04d}", fits, views))
    return out
