"""Scanline-based segmentation of one LiDAR scan (after Wang et al. 2016/2017, Section 4.1).

1. Every ring is ordered by azimuth and cut into *scanline segments* where two successive
   points are farther apart than the spacing a surface at that range can produce
   (``jump_ratio * range * azimuth step``) plus an allowance for range noise.
2. Scanline segments of neighbouring rings (one or two rings apart) are *agglomerated* into
   objects when enough of their points are linked: closest in azimuth, and closer in 3-D than
   ``link_ratio * range * elevation step`` plus the noise allowance.

Everything is vectorised (a loop over rings only). The point-level links are kept so that an
over-merged object can later be split inside a plane (see detection.py).
Frames: the LiDAR frame, metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..lidars import LidarModel
from .options import LidarOptions

__all__ = ["Segmentation", "segment_scan", "estimate_range_noise", "components_of"]


@dataclass(frozen=True)
class Segmentation:
    """Result of :func:`segment_scan`.

    labels: (N,) int64 object id per input point, -1 for points ignored (too close, not finite).
    scanline: (N,) int64 scanline-segment id per point, -1 for ignored points.
    edges: (E, 2) int64 pairs of input-point indices linked along a ring or across rings.
    noise_sigma: range noise estimated from the scan (metres, one sigma).
    n_objects: number of objects (labels run 0 .. n_objects-1).
    """

    labels: np.ndarray
    scanline: np.ndarray
    edges: np.ndarray
    noise_sigma: float
    n_objects: int


def _ring_spacing_rad(model: LidarModel, n_rings: int) -> np.ndarray:
    """(n_rings,) elevation (rad) of each ring from the model's table, extended if the file has more rings."""
    el = model.vertical_angles_rad
    if el.size >= n_rings:
        return el
    step = float(np.median(np.diff(el))) if el.size > 1 else np.deg2rad(2.0)
    extra = el[-1] + step * np.arange(1, n_rings - el.size + 1)
    return np.concatenate([el, extra])


def estimate_range_noise(ranges: np.ndarray, ring: np.ndarray, azimuth: np.ndarray, step_rad: float) -> float:
    """Range noise (m, one sigma) from second differences of range along each ring.

    ranges, ring, azimuth: (M,) sorted by (ring, azimuth). On a smooth surface the second
    difference of successive ranges is noise only, with variance 6 sigma^2; the median absolute
    value makes jumps between objects irrelevant.
    """
    if ranges.size < 5:
        return 0.01
    same = (
        (ring[2:] == ring[:-2])
        & (np.diff(azimuth)[1:] < 1.5 * step_rad)
        & (np.diff(azimuth)[:-1] < 1.5 * step_rad)
    )
    d2 = ranges[2:] - 2.0 * ranges[1:-1] + ranges[:-2]
    d2 = d2[same]
    if d2.size < 20:
        return 0.01
    return max(float(1.4826 * np.median(np.abs(d2)) / np.sqrt(6.0)), 0.002)


def components_of(n: int, edges: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected components of the graph on ``n`` nodes with (E, 2) ``edges``: (count, (n,) labels)."""
    if edges.size == 0:
        return n, np.arange(n)
    g = coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return connected_components(g, directed=False)


def segment_scan(
    points: np.ndarray,
    ring: np.ndarray,
    model: LidarModel,
    options: LidarOptions = LidarOptions(),
    valid: np.ndarray | None = None,
) -> Segmentation:
    """Segment one scan into objects along and across scanlines.

    points: (N, 3) LiDAR frame, metres. ring: (N,) int beam index (0 = lowest).
    valid: optional (N,) bool mask of points to consider (e.g. the region of interest).
    """
    p = np.asarray(points, dtype=np.float64)
    n = p.shape[0]
    rng = np.linalg.norm(p, axis=1)
    ok = np.isfinite(rng) & (rng > options.min_range_m)
    if valid is not None:
        ok &= valid
    idx = np.flatnonzero(ok)
    labels = np.full(n, -1, np.int64)
    scanline = np.full(n, -1, np.int64)
    if idx.size == 0:
        return Segmentation(labels, scanline, np.zeros((0, 2), np.int64), 0.01, 0)

    ring_i = np.asarray(ring, dtype=np.int64)[idx]
    az = np.arctan2(p[idx, 1], p[idx, 0])
    order = np.lexsort((az, ring_i))
    sidx = idx[order]
    P, R, A, G = p[sidx], rng[sidx], az[order], ring_i[order]
    m = sidx.size
    step = np.deg2rad(model.horizontal_resolution_deg)
    sigma = estimate_range_noise(R, G, A, step)
    allow = options.noise_sigmas * sigma

    # 1. scanline segments: break on ring change, azimuth gap or 3-D jump
    d = np.linalg.norm(P[1:] - P[:-1], axis=1)
    dphi = A[1:] - A[:-1]
    thr = options.jump_ratio * np.minimum(R[1:], R[:-1]) * np.clip(dphi, step, 3 * step) + allow
    link_h = (G[1:] == G[:-1]) & (dphi < 5 * step) & (d < thr)
    seg = np.concatenate([[0], np.cumsum(~link_h)])
    h_pairs = np.flatnonzero(link_h)
    edges_h = np.stack([h_pairs, h_pairs + 1], axis=1)

    # ring boundaries (sorted order) and the wrap-around join at azimuth +-pi
    ring_vals, starts = np.unique(G, return_index=True)
    ends = np.append(starts[1:], m) - 1
    wrap_a, wrap_b = starts, ends
    dwrap = np.linalg.norm(P[wrap_a] - P[wrap_b], axis=1)
    phiw = A[wrap_a] + 2 * np.pi - A[wrap_b]
    wthr = options.jump_ratio * np.minimum(R[wrap_a], R[wrap_b]) * np.clip(phiw, step, 3 * step) + allow
    wok = (ends > starts) & (phiw < 5 * step) & (dwrap < wthr)
    edges_w = np.stack([wrap_a[wok], wrap_b[wok]], axis=1)

    # 2. links between neighbouring rings (1 and 2 apart), nearest in azimuth
    ring_slices = {int(g): (s, e + 1) for g, s, e in zip(ring_vals, starts, ends, strict=True)}
    edges_v = _ring_links(
        P, R, A, ring_slices, _ring_spacing_rad(model, int(G.max()) + 3), step, allow, options
    )
    # merge scanline segments: wrap joins always, vertical links when numerous enough
    n_obj, obj_of_seg = _merged(seg, edges_v, edges_w, options.min_links)

    labels[sidx] = obj_of_seg[seg]
    scanline[sidx] = seg
    all_edges = np.concatenate([edges_h, edges_w, edges_v]) if m > 1 else np.zeros((0, 2), np.int64)
    return Segmentation(labels, scanline, sidx[all_edges].astype(np.int64), sigma, int(n_obj))


def _ring_links(
    P: np.ndarray,
    R: np.ndarray,
    A: np.ndarray,
    ring_slices: dict[int, tuple[int, int]],
    elev: np.ndarray,
    step: float,
    allow: float,
    options: LidarOptions,
) -> np.ndarray:
    """(E, 2) links (indices in ring-then-azimuth order) between each return and the nearest in
    azimuth on the rings 1 and 2 above, when close enough in azimuth and in 3-D. P, R, A: the
    returns' points, ranges, azimuths in that order; ring_slices: each ring's [start, end);
    elev: the rings' elevation (rad)."""
    v_edges = []
    for g, (s0, e0) in ring_slices.items():
        for dg in (1, 2):
            if g + dg not in ring_slices:
                continue
            s1, e1 = ring_slices[g + dg]
            a1 = A[s1:e1]
            j = np.searchsorted(a1, A[s0:e0])
            j0 = np.clip(j - 1, 0, a1.size - 1)
            j1 = np.clip(j, 0, a1.size - 1)
            pick = np.where(np.abs(a1[j0] - A[s0:e0]) <= np.abs(a1[j1] - A[s0:e0]), j0, j1)
            dphi_v = np.abs(a1[pick] - A[s0:e0])
            dist = np.linalg.norm(P[s0:e0] - P[s1 + pick], axis=1)
            del_el = abs(elev[g + dg] - elev[g]) if g + dg < elev.size else dg * np.deg2rad(2.0)
            vthr = options.link_ratio * R[s0:e0] * del_el + allow
            good = (dphi_v < 2.5 * step) & (dist < vthr)
            if np.any(good):
                v_edges.append(np.stack([np.flatnonzero(good) + s0, pick[good] + s1], axis=1))
    return np.concatenate(v_edges) if v_edges else np.zeros((0, 2), np.int64)


def _merged(
    seg: np.ndarray, edges_v: np.ndarray, edges_w: np.ndarray, min_links: int
) -> tuple[int, np.ndarray]:
    """(number of objects, object of each scanline segment): segments joined by a wrap-around link,
    or by at least ``min_links`` links between rings (fewer when a segment is smaller)."""
    n_seg = int(seg[-1]) + 1
    seg_size = np.bincount(seg, minlength=n_seg)
    if edges_v.size:
        sa, sb = seg[edges_v[:, 0]], seg[edges_v[:, 1]]
        key = np.minimum(sa, sb) * n_seg + np.maximum(sa, sb)
        ukey, cnt = np.unique(key, return_counts=True)
        ua, ub = ukey // n_seg, ukey % n_seg
        need = np.minimum(min_links, np.minimum(seg_size[ua], seg_size[ub]))
        keep = cnt >= need
        seg_edges = np.stack([ua[keep], ub[keep]], axis=1)
    else:
        seg_edges = np.zeros((0, 2), np.int64)
    if edges_w.size:
        seg_edges = np.concatenate([seg_edges, np.stack([seg[edges_w[:, 0]], seg[edges_w[:, 1]]], axis=1)])
    return components_of(n_seg, seg_edges)
