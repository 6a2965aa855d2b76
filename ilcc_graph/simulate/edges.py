"""Returns at the board's outline as a real LiDAR gives them (``Systematics.edge_returns``).

A beam's footprint (diameter ``beam_aperture_m + beam_divergence_rad * range``) that straddles the
board's outline lights the board with part of it and what lies behind with the rest. A single-return
sensor then reports the board, the background, or a *mixed* return between the two (the "mixed
pixels" seen at every real board's edge). With ``f`` the share of the footprint on the board
(:data:`FOOTPRINT`'s points over the disc, slid along the beam onto the board's plane):

- ``f >= 0.85``: the board, at the beam's crossing of its plane (a beam whose centre just misses
  the board still returns from it: the board looks larger by up to the footprint's radius);
- ``f <= 0.15``: what lies behind (a beam whose centre just hits the board returns from behind);
- otherwise a mixed return at ``f t_board + (1 - f) t_behind``, off every surface (``SURF_EDGE``),
  with the range noise of other surfaces.

A beam that meets something before the board's plane (a person in front) keeps its hit.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..lidars.footprint import FOOTPRINT
from .scene import SURF_BOARD, SURF_BOARD_BACK, Hits, Scene, cast_rays

__all__ = ["FOOTPRINT", "SURF_EDGE", "edge_returns", "footprint_points"]

#: surface id of a mixed return (between the board's edge and what lies behind)
SURF_EDGE = 8
BOARD_SHARE, BEHIND_SHARE = 0.85, 0.15


def _plane_crossing(origin: np.ndarray, d: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t (N,), board-frame xy (N, 2)) where each ray crosses the board's plane (t NaN: never)."""
    R, c = T[:3, :3], T[:3, 3]
    o = R.T @ (origin - c)
    dz = d @ R[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(np.abs(dz) > 1e-9, -o[2] / dz, np.nan)
    t = np.where(t > 0, t, np.nan)
    return t, np.column_stack([o[0] + t * (d @ R[:, 0]), o[1] + t * (d @ R[:, 1])])


def footprint_points(db: np.ndarray, xy: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(K, N, 2) board-plane points of each beam's footprint (:data:`FOOTPRINT` scaled by its
    ``radius`` (N,), m, perpendicular to the beam, slid along the beam onto the plane z = 0).

    db: (N, 3) beam directions in the board frame; xy: (N, 2) where each beam's centre crosses the plane.
    """
    ref = np.where(np.abs(db[:, 2:3]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    e1 = np.cross(db, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(db, e1)
    off = radius[None, :, None] * (FOOTPRINT[:, 0, None, None] * e1 + FOOTPRINT[:, 1, None, None] * e2)
    return xy + off[..., :2] - (off[..., 2] / db[:, 2])[..., None] * db[:, :2]


def _share_on_board(
    d: np.ndarray, xy: np.ndarray, radius: np.ndarray, R: np.ndarray, extent: tuple[float, ...]
) -> np.ndarray:
    """(N,) share of each footprint (radius (N,), m) on the board's rectangle ``extent``."""
    q = footprint_points(d @ R, xy, radius)
    x0, x1, y0, y1 = extent
    on = (q[..., 0] >= x0) & (q[..., 0] <= x1) & (q[..., 1] >= y0) & (q[..., 1] <= y1)
    return on.mean(axis=0)


def edge_returns(
    scene: Scene, origin: np.ndarray, d: np.ndarray, hits: Hits, footprint: tuple[float, float]
) -> Hits:
    """``hits`` of the rays ``origin + t d`` (``cast_rays``'), the beams whose footprint straddles the
    board's outline returned as the module docstring says. footprint: (aperture m, divergence rad):
    the footprint's diameter at range t is ``aperture + divergence * t``."""
    if scene.board is None or scene.T_lidar_board is None:
        return hits
    board, T = scene.board, scene.T_lidar_board
    t_pl, xy = _plane_crossing(origin, d, T)
    radius = 0.5 * (footprint[0] + footprint[1] * np.nan_to_num(t_pl, nan=0.0))
    x0, x1, y0, y1 = board.extent()
    gap = np.maximum.reduce([x0 - xy[:, 0], xy[:, 0] - x1, y0 - xy[:, 1], xy[:, 1] - y1])  # > 0 outside
    inside = np.minimum.reduce([xy[:, 0] - x0, x1 - xy[:, 0], xy[:, 1] - y0, y1 - xy[:, 1]])
    near = np.isfinite(t_pl) & (np.where(gap > 0, gap, inside) < 3.0 * radius)
    on_board = np.isin(hits.surface, (SURF_BOARD, SURF_BOARD_BACK))
    near &= on_board | ~(hits.t < t_pl - 1e-6)  # nothing in front of the board's plane
    idx = np.flatnonzero(near)
    if idx.size == 0:
        return hits
    f = _share_on_board(d[idx], xy[idx], radius[idx], T[:3, :3], (x0, x1, y0, y1))
    behind = cast_rays(replace(scene, board=None, T_lidar_board=None), origin, d[idx])
    t, surf, normal, bxy = hits.t.copy(), hits.surface.copy(), hits.normal.copy(), hits.board_xy.copy()
    nz = T[:3, 2]
    front = (d[idx] @ nz) < 0
    to_board = idx[f >= BOARD_SHARE]
    fb = front[f >= BOARD_SHARE]
    t[to_board], bxy[to_board] = t_pl[to_board], xy[to_board]
    surf[to_board] = np.where(fb, SURF_BOARD, SURF_BOARD_BACK)
    normal[to_board] = np.where(fb[:, None], nz, -nz)
    back = f <= BEHIND_SHARE
    k = idx[back]
    t[k], surf[k], normal[k], bxy[k] = behind.t[back], behind.surface[back], behind.normal[back], np.nan
    mixed = ~back & (f < BOARD_SHARE)
    k, fm = idx[mixed], f[mixed]
    t_mix = fm * t_pl[k] + (1.0 - fm) * behind.t[mixed]
    finite = np.isfinite(t_mix)
    k, t_mix = k[finite], t_mix[finite]
    t[k], surf[k], normal[k], bxy[k] = t_mix, SURF_EDGE, nz, np.nan
    return Hits(t, surf, normal, bxy)
