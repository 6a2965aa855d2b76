"""The geometry of a board pose for the advice: the rig, a pose facing it, the LiDAR's beams on it,
whether the camera and the LiDAR see all of it."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.lidars import LidarModel

__all__ = [
    "IMAGE_BORDER",
    "MIN_BEAMS",
    "ROLL_DEG",
    "Rig",
    "beam_hits",
    "board_outline",
    "board_pose",
    "in_view",
]

MIN_BEAMS = 4
IMAGE_BORDER = 0.03
ROLL_DEG = 45.0


@dataclass(frozen=True)
class Rig:
    """The sensors as the advice sees them: camera model, current ``T_cam_lidar`` (4, 4), the LiDAR's
    beam table and the board."""

    camera: CameraModel
    T_cam_lidar: np.ndarray
    lidar: LidarModel
    board: Board

    @property
    def camera_centre(self) -> np.ndarray:
        """(3,) the camera centre in the LiDAR frame."""
        T = np.asarray(self.T_cam_lidar, dtype=np.float64)
        return -T[:3, :3].T @ T[:3, 3]


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def board_pose(
    centre: np.ndarray,
    board: Board,
    towards: np.ndarray,
    yaw_deg: float,
    pitch_deg: float,
    roll_deg: float = ROLL_DEG,
) -> np.ndarray:
    """(4, 4) ``T_lidar_board`` with the pattern centre at ``centre`` (LiDAR frame), the printed face
    towards ``towards``, then turned by ``yaw_deg`` about the vertical (positive: the face turns
    counter-clockwise seen from above), tilted by ``pitch_deg`` (positive: the face looks up) and
    turned ``roll_deg`` in its plane."""
    z0 = np.asarray(towards, dtype=np.float64) - centre
    z0 /= np.linalg.norm(z0)
    x0 = np.cross([0.0, 0.0, 1.0], z0)
    x0 /= np.linalg.norm(x0)
    y0 = np.cross(z0, x0)
    R = np.column_stack([x0, y0, z0]) @ _rot(1, math.radians(yaw_deg)) @ _rot(0, -math.radians(pitch_deg))
    R = R @ _rot(2, math.radians(roll_deg))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre - R @ board.pattern_centre
    return T


@functools.lru_cache(maxsize=8)
def _outline_cached(board: Board, n: int) -> np.ndarray:
    x0, x1, y0, y1 = board.extent()
    t = np.linspace(0.0, 1.0, n)
    xs = np.concatenate([x0 + (x1 - x0) * t, np.full(n, x1), x1 - (x1 - x0) * t, np.full(n, x0)])
    ys = np.concatenate([np.full(n, y0), y0 + (y1 - y0) * t, np.full(n, y1), y1 - (y1 - y0) * t])
    out = np.column_stack([xs, ys, np.zeros_like(xs)])
    out.setflags(write=False)
    return out


def board_outline(board: Board, n: int = 6) -> np.ndarray:
    """(4 n, 3) points along the board's physical edge, board frame."""
    return _outline_cached(board, n)


def beam_hits(T_lidar_board: np.ndarray, board: Board, lidar: LidarModel) -> tuple[np.ndarray, ...]:
    """The returns the LiDAR's beam table puts on the board: (b (M, 3) board frame, ring (M,),
    u (M, 3) unit ray directions in the board frame). Beams from the LiDAR origin at every
    ``horizontal_resolution_deg`` over the board's azimuth span; the board's physical face counts."""
    T = np.asarray(T_lidar_board, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    out = board_outline(board) @ R.T + t
    az = np.arctan2(out[:, 1], out[:, 0])
    ref = float(np.arctan2(t[1] + R[1] @ board.pattern_centre, t[0] + R[0] @ board.pattern_centre))
    daz = np.mod(az - ref + np.pi, 2 * np.pi) - np.pi
    step = math.radians(lidar.horizontal_resolution_deg)
    a = ref + np.arange(math.floor(daz.min() / step), math.ceil(daz.max() / step) + 1) * step
    origin = np.array([0.0, 0.0, lidar.beam_origin_z_m])
    el_out = np.arctan2(out[:, 2] - origin[2], np.hypot(out[:, 0], out[:, 1]))
    el_all = np.radians(lidar.vertical_angles_deg)
    rings = np.flatnonzero((el_all >= el_out.min() - 1e-3) & (el_all <= el_out.max() + 1e-3))
    E, A = np.meshgrid(el_all[rings], a, indexing="ij")
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1).reshape(-1, 3)
    ring = np.repeat(rings, len(a))
    n = R[:, 2]
    denom = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((t - origin) @ n) / denom
    ok = np.isfinite(s) & (s > 0)
    p = origin + s[ok, None] * d[ok]
    b = (p - t) @ R
    x0, x1, y0, y1 = board.extent()
    on = (b[:, 0] >= x0) & (b[:, 0] <= x1) & (b[:, 1] >= y0) & (b[:, 1] <= y1)
    return b[on], ring[ok][on], d[ok][on] @ R


def in_view(rig: Rig, T_lidar_board: np.ndarray) -> np.ndarray | None:
    """The corners' camera-frame points when every corner and the board's outline are imaged
    inside the picture (3 % border) and the outline lies in the LiDAR's vertical field; else None."""
    T = np.asarray(T_lidar_board, dtype=np.float64)
    out = board_outline(rig.board) @ T[:3, :3].T + T[:3, 3]
    el = np.degrees(np.arctan2(out[:, 2] - rig.lidar.beam_origin_z_m, np.hypot(out[:, 0], out[:, 1])))
    va = rig.lidar.vertical_angles_deg
    if el.min() < va[0] + 0.3 or el.max() > va[-1] - 0.3:
        return None
    Tc = np.asarray(rig.T_cam_lidar, dtype=np.float64) @ T
    pts = np.vstack([rig.board.corners_board(), board_outline(rig.board)]) @ Tc[:3, :3].T + Tc[:3, 3]
    uv = rig.camera.project(pts)
    if not np.all(np.isfinite(uv)) or not np.all(rig.camera.fov_contains(pts)):
        return None
    cam = rig.camera
    if not cam.periodic_u:
        bw = IMAGE_BORDER * cam.width
        if uv[:, 0].min() < bw or uv[:, 0].max() > cam.width - 1 - bw:
            return None
    bh = IMAGE_BORDER * cam.height
    if uv[:, 1].min() < bh or uv[:, 1].max() > cam.height - 1 - bh:
        return None
    return pts[: rig.board.n_corners]
