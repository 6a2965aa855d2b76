"""What a scanline-free scan offers instead of scanlines: neighbours in direction.

- :func:`density_map`: the pattern's returns per steradian (measured from the scan) and the local
  mean spacing ``delta = 1 / sqrt(density)``;
- :func:`link_edges` / :func:`link_components`: links between neighbouring returns, the scanline
  stage's jump rule with ``delta`` for the azimuth step, and the objects they make;
- :func:`estimate_noise`: range noise from local planes;
- :func:`pseudo_rings`: elevation bands for the fit's ring-grouped covariance;
- :func:`area_weights`: the board area each return stands for; :func:`trim_in_plane`: an opening in
  a piece's own plane against poles and arms.

Used by ``ringless.py``. Frames: the LiDAR frame, metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .segmentation import components_of

__all__ = [
    "DensityMap", "density_map", "estimate_noise", "link_edges", "link_components", "pseudo_rings",
    "area_weights", "trim_in_plane",
]  # fmt: skip

_CELL_DEG = 1.0
_SMOOTH_CELLS = 5
_NEIGHBOURS = 32


@dataclass(frozen=True)
class DensityMap:
    """Returns per steradian on 1 deg cells: ``density[el_cell, az_cell]``, 0 outside the field."""

    density: np.ndarray

    def at(self, u: np.ndarray) -> np.ndarray:
        """(N,) returns per steradian at unit directions u (N, 3); the nearest non-zero cell's."""
        i, j = _cells(u)
        return self.density[i, j]

    def spacing(self, u: np.ndarray) -> np.ndarray:
        """(N,) local mean angular spacing (rad) of the returns at directions u (N, 3)."""
        return 1.0 / np.sqrt(np.maximum(self.at(u), 1.0))


def _cells(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    el = np.degrees(np.arcsin(np.clip(u[:, 2], -1.0, 1.0)))
    az = np.degrees(np.arctan2(u[:, 1], u[:, 0]))
    i = np.clip(((el + 90.0) / _CELL_DEG).astype(np.int64), 0, int(180 / _CELL_DEG) - 1)
    j = np.clip(((az + 180.0) / _CELL_DEG).astype(np.int64), 0, int(360 / _CELL_DEG) - 1)
    return i, j


def density_map(u: np.ndarray) -> DensityMap:
    """The pattern's density from the directions u (N, 3) of a scan's returns.

    Counts per cell over the cell's solid angle, smoothed by a normalised box filter over the cells
    of the field (a cell with returns, or one whose 5 x 5 neighbourhood is at least 40 % such cells:
    the gaps between a short integration's petals count, the sky beyond the rim does not). Cells
    outside get the density of the nearest cell of the field.
    """
    n_el, n_az = int(180 / _CELL_DEG), int(360 / _CELL_DEG)
    i, j = _cells(u)
    counts = np.bincount(i * n_az + j, minlength=n_el * n_az).reshape(n_el, n_az).astype(np.float64)
    el_c = np.deg2rad(-90.0 + _CELL_DEG * (np.arange(n_el) + 0.5))
    area = np.cos(el_c)[:, None] * np.deg2rad(_CELL_DEG) ** 2 * np.ones((1, n_az))
    modes = ("nearest", "wrap")
    occupied = counts > 0
    field = occupied | (ndimage.uniform_filter(occupied.astype(np.float64), _SMOOTH_CELLS, mode=modes) >= 0.4)
    if not occupied.any():
        return DensityMap(np.full((n_el, n_az), 1.0))
    num = ndimage.uniform_filter(counts, _SMOOTH_CELLS, mode=modes)
    den = ndimage.uniform_filter(area * field, _SMOOTH_CELLS, mode=modes)
    dens = np.where(field, num / np.maximum(den, 1e-12), 0.0)
    # outside the field: the nearest cell's value inside it
    _, (ii, jj) = ndimage.distance_transform_edt(~field, return_indices=True)
    return DensityMap(dens[ii, jj])


def estimate_noise(p: np.ndarray, rng: np.random.Generator, k: int = 24, n: int = 2000) -> float:
    """Range noise (m, one sigma) from local planes: the median smallest PCA spread of the k nearest
    returns of up to n random returns (floor 2 mm)."""
    if p.shape[0] < k + 1:
        return 0.01
    sub = p[rng.choice(p.shape[0], min(n, p.shape[0]), replace=False)]
    _, nb = cKDTree(p).query(sub, k)
    Q = p[nb] - p[nb].mean(axis=1, keepdims=True)
    w = np.linalg.eigvalsh(np.einsum("nki,nkj->nij", Q, Q) / (k - 3))[:, 0]
    return max(float(np.sqrt(np.median(np.maximum(w, 0.0)))), 0.002)


def link_edges(
    p: np.ndarray, u: np.ndarray, delta: np.ndarray, jump_ratio: float, allow: float, k: int = _NEIGHBOURS
) -> np.ndarray:
    """(E, 2) pairs of returns linked as neighbours (see the module docstring, step 2).

    p: (N, 3) points, u: (N, 3) their unit directions, delta: (N,) local spacing (rad). Each return
    is paired with its ``k`` nearest in direction (a radius of ``jump_ratio`` spacings holds ~80 on
    average; 32 nearest bridge the gaps between a 0.1 s rosette's petals as well as the radius does
    and cost a quarter), of which those within both limits are links.
    """
    n = p.shape[0]
    if n < 2:
        return np.zeros((0, 2), np.int64)
    k = min(k, n)
    ang, nb = cKDTree(u).query(u, k)
    a = np.repeat(np.arange(n), k - 1)
    b = nb[:, 1:].ravel()
    ang = ang[:, 1:].ravel()
    d_loc = np.maximum(delta[a], delta[b])
    r = np.linalg.norm(p, axis=1)
    dist = np.linalg.norm(p[a] - p[b], axis=1)
    keep = (ang < jump_ratio * d_loc) & (dist < jump_ratio * np.minimum(r[a], r[b]) * d_loc + allow)
    return np.stack([a[keep], b[keep]], axis=1).astype(np.int64)


def link_components(
    p: np.ndarray, u: np.ndarray, delta: np.ndarray, jump_ratio: float, allow: float
) -> np.ndarray:
    """(N,) object label of each return: connected components of :func:`link_edges`."""
    return components_of(p.shape[0], link_edges(p, u, delta, jump_ratio, allow))[1]


def pseudo_rings(points: np.ndarray) -> np.ndarray:
    """(N,) int elevation band of each return, one median local spacing high (0 = lowest band).

    What the intensity fit groups returns by when a scan has no rings: its sampling covariance
    pairs neighbours within a band and with the next one up, and counts the pairs crossing one
    grid line between the same two bands once; its plane fit takes a delete-one-band jackknife.
    Bands one spacing high give the boards' in-plane errors z-scores of 0.8-1.0, one band for all
    returns 0.4-0.6 (too cautious; docs/lidar_ringless.md).
    """
    p = np.asarray(points, dtype=np.float64)
    if p.shape[0] == 0:
        return np.zeros(0, np.int64)
    r = np.linalg.norm(p, axis=1)
    u = p / np.maximum(r, 1e-9)[:, None]
    step = float(np.median(density_map(u).spacing(u)))
    band = np.floor(np.arcsin(np.clip(u[:, 2], -1.0, 1.0)) / step).astype(np.int64)
    return band - band.min()


def trim_in_plane(q: np.ndarray, normal: np.ndarray, cell: float, width: float) -> np.ndarray:
    """Indices of the largest compact blob of the planar piece q (M, 3): drops thin attachments.

    The returns are rasterised in their plane (``normal``) on cells of ``cell`` metres (closed once
    against holes between returns); an opening by a square ``width`` metres wide removes poles and
    arms; the largest block left, grown back, is kept.
    """
    ref = np.array([0.0, 0.0, 1.0]) if abs(normal[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(normal, ref)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    xy = np.column_stack([q @ e1, q @ e2])
    ij = np.floor((xy - xy.min(axis=0)) / cell).astype(np.int64)
    k = max(3, int(np.ceil(width / cell)))
    shape = ij.max(axis=0) + 1 + 2 * k
    if shape[0] * shape[1] > 4_000_000:
        return np.arange(q.shape[0])
    occ = np.zeros(shape, bool)
    occ[ij[:, 0] + k, ij[:, 1] + k] = True
    occ = ndimage.binary_closing(occ, structure=np.ones((3, 3), bool))
    box = np.ones((k, k), bool)
    lab, n = ndimage.label(ndimage.binary_erosion(occ, structure=box))
    if n == 0:
        return np.arange(q.shape[0])
    big = np.argmax(np.bincount(lab.ravel())[1:]) + 1
    keep = ndimage.binary_dilation(lab == big, structure=box)
    return np.flatnonzero(keep[ij[:, 0] + k, ij[:, 1] + k])


def area_weights(q: np.ndarray, spacing_m: float, reach: float = 3.0) -> np.ndarray:
    """(M,) board area (m^2) each return of the planar piece q (M, 3) stands for: the part of the
    piece's plane nearer to it than to any other return, up to ``reach`` mean spacings away.

    A rosette crosses a board along a few petals in a short integration: counted per return, the
    quadrants of a whole board look uneven; weighted by the area each return covers they do not,
    while a piece with a real hole (larger than ``reach`` spacings) still does.
    spacing_m: the mean spacing of the returns on the piece (m).
    """
    mu = q.mean(axis=0)
    _, _, vt = np.linalg.svd(q - mu, full_matrices=False)
    xy = (q - mu) @ vt[:2].T
    cell = max(spacing_m / 3.0, 1e-3)
    pad = int(np.ceil(reach * spacing_m / cell)) + 1
    ij = np.floor((xy - xy.min(axis=0)) / cell).astype(np.int64) + pad
    shape = ij.max(axis=0) + 1 + pad
    if shape[0] * shape[1] > 4_000_000:
        return np.full(q.shape[0], 1.0)
    owner = np.full(shape, -1, np.int64)
    owner[ij[:, 0], ij[:, 1]] = np.arange(q.shape[0])  # one return per occupied cell owns it
    dist, (ii, jj) = ndimage.distance_transform_edt(owner < 0, return_indices=True)
    near = owner[ii, jj][dist * cell <= reach * spacing_m]
    cells = np.bincount(near, minlength=q.shape[0]).astype(np.float64)
    # returns sharing a cell share its area
    key = ij[:, 0] * shape[1] + ij[:, 1]
    _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    per_cell = np.bincount(inv, weights=cells) / cnt
    return per_cell[inv] * cell**2
