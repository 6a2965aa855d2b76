"""The simulated scene and vectorised ray casting, all in the LiDAR frame (x forward, y left, z up).

A :class:`Scene` is a ground plane, optionally a room (four walls and a ceiling), a few oriented
boxes (a person, the board's stand) and the chessboard, a thin rectangle of the physical board's
extent (margin included) in the board frame's z = 0 plane. :func:`cast_rays` intersects rays from one
origin with all of them and keeps the nearest hit; the result carries what shading needs (surface
id, hit point, normal, board-frame coordinates on the board).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..board import Board

__all__ = [
    "Box",
    "Scene",
    "Hits",
    "cast_rays",
    "SURF_NONE",
    "SURF_GROUND",
    "SURF_CEILING",
    "SURF_WALL",
    "SURF_BOARD",
    "SURF_BOARD_BACK",
    "SURF_PERSON",
    "SURF_POLE",
]

SURF_NONE, SURF_GROUND, SURF_CEILING, SURF_WALL = 0, 1, 2, 3
SURF_BOARD, SURF_BOARD_BACK, SURF_PERSON, SURF_POLE = 4, 5, 6, 7


@dataclass(frozen=True, eq=False)
class Box:
    """An oriented box: ``T_lidar_box`` (4, 4) places its centre and axes; ``half`` (3,) half sizes, m."""

    T_lidar_box: np.ndarray
    half: np.ndarray
    surface: int

    def corners(self) -> np.ndarray:
        """(8, 3) corners, LiDAR frame."""
        s = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
        return (s * self.half) @ self.T_lidar_box[:3, :3].T + self.T_lidar_box[:3, 3]

    def edge_samples(self, n: int = 12) -> np.ndarray:
        """(12 n, 3) points along the 12 edges, LiDAR frame."""
        c = self.corners()
        edges = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
        t = np.linspace(0.0, 1.0, n)[:, None]
        return np.concatenate([c[a] + t * (c[b] - c[a]) for a, b in edges])


@dataclass(frozen=True, eq=False)
class Scene:
    """Static surroundings plus one board placement.

    ground_z: height of the ground plane (LiDAR frame z, negative), or None for no ground.
    room: (xmin, xmax, ymin, ymax) of the walls or None (open: ground only).
    ceiling_z: ceiling height (LiDAR frame z) or None.
    board, T_lidar_board: the chessboard and its pose, or board None for the empty room.
    boxes: the person, the stand, ...
    """

    ground_z: float | None
    room: tuple[float, float, float, float] | None
    ceiling_z: float | None
    board: Board | None = None
    T_lidar_board: np.ndarray | None = None
    boxes: tuple[Box, ...] = ()

    def moving_parts(self) -> Scene:
        """The same scene without ground, walls and ceiling (what changes from frame to frame)."""
        return Scene(None, None, None, self.board, self.T_lidar_board, self.boxes)

    def placed_board(self) -> tuple[Board, np.ndarray]:
        """The board and its pose T_lidar_board; ValueError for a scene without a board."""
        if self.board is None or self.T_lidar_board is None:
            raise ValueError("the scene has no board")
        return self.board, self.T_lidar_board

    def board_outline_samples(self, n: int = 24) -> np.ndarray:
        """(4 n, 3) points along the physical board's outline, LiDAR frame (empty without a board)."""
        if self.board is None or self.T_lidar_board is None:
            return np.zeros((0, 3))
        o = self.board.outline()
        t = np.linspace(0.0, 1.0, n)[:, None]
        pts = np.concatenate([o[i] + t * (o[(i + 1) % 4] - o[i]) for i in range(4)])
        return pts @ self.T_lidar_board[:3, :3].T + self.T_lidar_board[:3, 3]


@dataclass
class Hits:
    """Nearest hit of each ray.

    t: (N,) distance along the (unit) ray, inf where nothing is hit.
    surface: (N,) int8 surface id (``SURF_*``).
    normal: (N, 3) unit normal of the hit surface facing the ray's origin side (0 where no hit).
    board_xy: (N, 2) board-frame coordinates where the board is hit, NaN elsewhere.
    """

    t: np.ndarray
    surface: np.ndarray
    normal: np.ndarray
    board_xy: np.ndarray


def _room_exit(origin: np.ndarray, d: np.ndarray, scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance, surface id and normal where rays leave the room (or hit ground / ceiling)."""
    n = d.shape[0]
    t = np.full(n, np.inf)
    surf = np.zeros(n, dtype=np.int8)
    normal = np.zeros((n, 3))
    if scene.ground_z is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            tg = (scene.ground_z - origin[2]) / d[:, 2]
        hit = (d[:, 2] < 0) & (tg > 0)
        t[hit], surf[hit], normal[hit, 2] = tg[hit], SURF_GROUND, 1.0
    if scene.ceiling_z is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            tc = (scene.ceiling_z - origin[2]) / d[:, 2]
        hit = (d[:, 2] > 0) & (tc > 0) & (tc < t)
        t[hit], surf[hit], normal[hit, 2] = tc[hit], SURF_CEILING, -1.0
    if scene.room is not None:
        xmin, xmax, ymin, ymax = scene.room
        for axis, lo, hi in ((0, xmin, xmax), (1, ymin, ymax)):
            da = d[:, axis]
            with np.errstate(divide="ignore", invalid="ignore"):
                tw = np.where(da > 0, (hi - origin[axis]) / da, (lo - origin[axis]) / da)
            hit = (da != 0) & (tw > 0) & (tw < t)
            t[hit], surf[hit] = tw[hit], SURF_WALL
            normal[hit] = 0.0
            normal[hit, axis] = -np.sign(da[hit])
    return t, surf, normal


def _box_entry(origin: np.ndarray, d: np.ndarray, box: Box) -> tuple[np.ndarray, np.ndarray]:
    """Distance to where rays enter a box (inf for a miss) and the entry face's normal (LiDAR frame).

    Slab test; a zero direction component gives +-inf bounds, which is right inside and outside
    the slab (a ray starting exactly on a face and parallel to it counts as a miss).
    """
    R, c = box.T_lidar_box[:3, :3], box.T_lidar_box[:3, 3]
    o = R.T @ (origin - c)
    db = R.T @ d.T  # (3, N): directions in the box frame, one row per axis
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / db
        t1 = (-box.half - o)[:, None] * inv
        t2 = (box.half - o)[:, None] * inv
    tlo = np.minimum(t1, t2)
    thi = np.maximum(t1, t2, out=t1)
    t_in = np.maximum(np.maximum(tlo[0], tlo[1]), tlo[2])
    t_out = np.minimum(np.minimum(thi[0], thi[1]), thi[2])
    hit = (t_in <= t_out) & (t_in > 0)
    normal = np.zeros_like(d)
    rows = np.flatnonzero(hit)
    if rows.size:
        axis = np.argmax(tlo[:, rows], axis=0)
        n_box = np.zeros((rows.size, 3))
        n_box[np.arange(rows.size), axis] = -np.sign(db[axis, rows])
        normal[rows] = n_box @ R.T
    return np.where(hit, t_in, np.inf), normal


def _board_hit(
    origin: np.ndarray, d: np.ndarray, board: Board, T: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance to the board rectangle (inf for a miss), front flag and board-frame xy (N, 2)."""
    R, c = T[:3, :3], T[:3, 3]
    o = R.T @ (origin - c)
    dz = d @ R[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / dz
    x = o[0] + t * (d @ R[:, 0])
    y = o[1] + t * (d @ R[:, 1])
    x0, x1, y0, y1 = board.extent()
    hit = (t > 0) & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    return np.where(hit, t, np.inf), dz < 0, np.column_stack([x, y])


def _near_sphere(origin: np.ndarray, d: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Indices of the rays that pass within ``radius`` of ``centre`` ahead of the origin (a cheap cull)."""
    oc = centre - origin
    along = d @ oc
    miss2 = oc @ oc - along * along
    return np.flatnonzero((miss2 < radius * radius) & (along > -radius))


def cast_rays(scene: Scene, origin: np.ndarray, d: np.ndarray) -> Hits:
    """Nearest hit of rays ``origin + t d`` (LiDAR frame).

    origin: (3,) ray origin, metres. d: (N, 3) unit directions (NaN rows never hit).
    """
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
    t, surf, normal = _room_exit(origin, d, scene)
    for box in scene.boxes:
        idx = _near_sphere(origin, d, box.T_lidar_box[:3, 3], float(np.linalg.norm(box.half)))
        if idx.size == 0:
            continue
        tb, nb = _box_entry(origin, d[idx], box)
        closer = tb < t[idx]
        sel = idx[closer]
        t[sel], surf[sel], normal[sel] = tb[closer], box.surface, nb[closer]
    board_xy = np.full((d.shape[0], 2), np.nan)
    if scene.board is not None and scene.T_lidar_board is not None:
        tb, front, xy = _board_hit(origin, d, scene.board, scene.T_lidar_board)
        closer = tb < t
        t[closer] = tb[closer]
        surf[closer] = np.where(front[closer], SURF_BOARD, SURF_BOARD_BACK)
        nz = scene.T_lidar_board[:3, 2]
        normal[closer] = np.where(front[closer, None], nz, -nz)
        board_xy[closer] = xy[closer]
    return Hits(t, surf, normal, board_xy)
