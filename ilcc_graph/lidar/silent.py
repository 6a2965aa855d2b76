"""Rays a spinning LiDAR fired near the board that returned nothing: the outline's evidence where
nothing lies behind the board (the sky, an open scene), and the LiDAR's own loss of returns.

``silent_rays(D, on, T, o, board, model, grow) -> (directions, lost share)`` (shape.py's samples take
them as rays that passed the board's plane); ``azimuth_noise`` the returns' azimuth noise that decides
when a beam's step holds no return. Frames: directions in the board frame of ``T``; radians, metres.
"""

from __future__ import annotations

import numpy as np

from ..board import Board
from ..lidars import CROPPED_BELOW_DEG, LidarModel

__all__ = ["azimuth_noise", "scan_window", "silent_rays"]


def azimuth_noise(az: np.ndarray, ring: np.ndarray, step: float) -> float:
    """The azimuth noise (rad) of returns (azimuths (M,), beams (M,)) on one surface, from the steps
    between successive returns of each beam: ``step + n_i+1 - n_i`` has variance ``2 sigma^2`` (the
    median absolute deviation of those within 0.3-1.7 steps, over sqrt 2; 0 for exact encoders)."""
    order = np.lexsort((az, ring))
    a, r = az[order], ring[order]
    d = np.diff(a)[np.diff(r) == 0]
    d = d[(d > 0.3 * step) & (d < 1.7 * step)]
    return 1.4826 * float(np.median(np.abs(d - step))) / np.sqrt(2.0) if d.size >= 10 else 0.0


def scan_window(az: np.ndarray, tol: float) -> tuple[float, float]:
    """The azimuths (rad, about the board's, (N,)) of a scan's returns: (lo, hi) of the window a
    cropped scan covers (``lidars.CROPPED_BELOW_DEG``), less ``tol``; (-inf, inf) for a whole turn.
    A step beyond a crop's window was cut, not silent."""
    if azimuth_coverage_deg_of(az) >= CROPPED_BELOW_DEG:
        return -np.inf, np.inf
    return float(az.min()) + tol, float(az.max()) - tol


def azimuth_coverage_deg_of(az: np.ndarray) -> float:
    """360 less the longest run of empty whole degrees (circular) of azimuths az (rad, (N,)): the
    window they cover, to a degree (``lidars.azimuth_coverage_deg`` without sorting)."""
    full = np.bincount(np.floor(np.degrees(az) % 360.0).astype(np.int64) % 360, minlength=360) > 0
    if not full.any():
        return 0.0
    run, longest = 0, 0
    for f in np.concatenate([full, full]):  # twice round: a run across 0 deg
        run = 0 if f else run + 1
        longest = max(longest, run)
    return float(360 - min(longest, 360))


def silent_rays(
    D: np.ndarray, on: np.ndarray, T: np.ndarray, o: np.ndarray, board: Board, model: LidarModel, grow: float
) -> tuple[np.ndarray, float]:
    """The rays the beams fired near the board that returned nothing, and the share of rays lost.

    A spinning LiDAR fires every beam at every azimuth step; where a beam's step near the board holds
    no return at any range (nothing behind the board: the sky, an open scene), its ray passed the
    board's plane without hitting the board, or was lost. Such rays are the outline's evidence as a
    ray that returned from behind is: without them an edge with nothing behind it is bounded only by
    the returns on the board, which any noise pushes outwards (the outline then grows, and its
    translation follows the edges that are seen: 17 mm at 30 mm of noise, in-plane NEES 7.8 for 3).
    A step is silent when no return of its beam lies within ``max(step / 2, 3 sigma_a)`` of its
    azimuth, ``sigma_a`` the azimuth noise of the returns on the board (``azimuth_noise``: none for
    pure range noise; noise off the ray moves a return's azimuth). D: (N, 3) every return from the
    beams' origin ``o``; on: (N,) the returns on the board's plane. Returns the silent rays' unit
    directions (K, 3) in the board frame of ``T`` that cross the plane within ``grow`` of the board, and
    the share of silent steps within each beam's run of returns on the plane (the LiDAR's own loss
    there: the chance that a silent ray is a lost return). None for a scanline-free LiDAR. A cropped
    scan's steps beyond its azimuth window (``scan_window``) are no rays: a board the crop cuts is
    unknown beyond the cut, not absent."""
    el_tab = np.sort(np.asarray(model.vertical_angles_rad, np.float64))
    empty = np.zeros((0, 3))
    if model.ringless or el_tab.size < 2 or on.sum() < 2:
        return empty, 0.0
    step = np.deg2rad(model.horizontal_resolution_deg)
    R, t = T[:3, :3], T[:3, 3]
    centre = D[on].mean(axis=0)
    dist = float(np.linalg.norm(centre))
    az_c = float(np.arctan2(centre[1], centre[0]))
    az = (np.arctan2(D[:, 1], D[:, 0]) - az_c + np.pi) % (2 * np.pi) - np.pi  # about the board's azimuth

    def beams(sel: np.ndarray) -> np.ndarray:
        """The beam (nearest elevation of the table) of each return ``sel`` picks."""
        el = np.arctan2(D[sel, 2], np.hypot(D[sel, 0], D[sel, 1]))
        ring = np.clip(np.searchsorted(el_tab, el), 1, el_tab.size - 1)
        return ring - ((el - el_tab[ring - 1]) < (el_tab[ring] - el))

    tol = max(0.5 * step, 3.0 * azimuth_noise(az[on], beams(on), step))
    half = float(np.abs(az[on]).max()) + grow / dist + 2 * tol  # the azimuths about the board
    lo, hi = scan_window(az, tol)
    near = np.abs(az) < half + 3 * step  # the returns about the board, those on its plane among them
    az_n, ring_n, on_n = az[near], beams(near), on[near]
    rays_a, rays_e, lost, runs = [], [], 0, 0
    for k in range(el_tab.size):
        mine = ring_n == k
        a_k = np.sort(az_n[mine])
        if a_k.size == 0:  # a beam without any return near the board: not known to fire there
            continue
        w = 2 * np.pi * a_k / step
        ph = float(np.angle(np.mean(np.exp(1j * w)))) * step / (2 * np.pi)
        g = ph + step * np.arange(-int(half / step) - 1, int(half / step) + 2)
        g = g[(g >= lo) & (g <= hi)]  # a cropped scan: beyond its window nothing is known
        if g.size == 0:
            continue
        j = np.clip(np.searchsorted(a_k, g), 1, a_k.size - 1)
        near_k = np.minimum(np.abs(g - a_k[j - 1]), np.abs(g - a_k[np.minimum(j, a_k.size - 1)]))
        quiet = np.where(a_k.size > 1, near_k, np.abs(g - a_k[0])) > tol
        a_on = az_n[mine & on_n]
        if a_on.size:
            span = (g >= a_on.min()) & (g <= a_on.max())
            runs, lost = runs + int(span.sum()), lost + int((quiet & span).sum())
        rays_a.append(g[quiet])
        rays_e.append(np.full(int(quiet.sum()), el_tab[k]))
    if sum(r.size for r in rays_a) == 0:
        return empty, lost / max(runs, 1)
    a, e = np.concatenate(rays_a), np.concatenate(rays_e)
    a = a + az_c
    d = np.column_stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]) @ R  # board frame
    ob = (o - t) @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(d[:, 2] < -0.1, -ob[2] / d[:, 2], -1.0)
    cx, cy = ob[0] + lam * d[:, 0], ob[1] + lam * d[:, 1]
    x0, x1, y0, y1 = board.extent()
    keep = (lam > 0.3) & (cx > x0 - grow) & (cx < x1 + grow) & (cy > y0 - grow) & (cy < y1 + grow)
    return (d[keep] if keep.any() else empty), lost / max(runs, 1)
