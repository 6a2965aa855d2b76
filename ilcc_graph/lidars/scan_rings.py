"""What a scan's returns say about its beams before any table: elevations from the beams' origin
height that makes them sharpest, the azimuth window a cropped scan covers, an intensity that is the
ring number.

Frames: the LiDAR frame (x forward, y left, z up), metres; elevations and azimuths in degrees.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..types import Scan

__all__ = [
    "CROPPED_BELOW_DEG", "azimuth_coverage_deg", "intensity_ring", "with_intensity_ring",
]  # fmt: skip

#: a scan whose returns cover less azimuth than this (deg) was cut to a region (a spinning LiDAR's
#: turn leaves no empty sector that wide: its floor and near returns surround it)
CROPPED_BELOW_DEG = 300.0


def elevation_deg(p: np.ndarray, h: float = 0.0) -> np.ndarray:
    """Elevation (deg) of points (N, 3) seen from the height ``h`` (m) above their origin."""
    return np.degrees(np.arctan2(p[:, 2] - h, np.hypot(p[:, 0], p[:, 1])))


def group_medians(values: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(distinct group ids, median of ``values`` per group, count per group)."""
    order = np.argsort(groups, kind="stable")
    g, v = groups[order], values[order]
    ids, start, counts = np.unique(g, return_index=True, return_counts=True)
    med = np.array([np.median(v[s : s + c]) for s, c in zip(start, counts, strict=True)])
    return ids, med, counts


def far_mask(p: np.ndarray) -> np.ndarray:
    """Mask of the returns used for elevations: beyond 1 m when at least half of them are."""
    r = np.linalg.norm(p, axis=1)
    far = r > 1.0
    return far if far.sum() >= 0.5 * r.size else r > 0.05


def azimuth_coverage_deg(points: np.ndarray) -> float:
    """The azimuth window (deg) that points (N, 3) (LiDAR frame) cover: 360 less the widest sector
    between two successive azimuths that holds none (a whole turn: about 360)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if p.shape[0] < 2:
        return 0.0
    az = np.sort(np.degrees(np.arctan2(p[:, 1], p[:, 0])))
    gaps = np.append(np.diff(az), az[0] + 360.0 - az[-1])
    return float(360.0 - gaps.max())


def sharpest_origin_height(p: np.ndarray) -> float:
    """Height h (m) of the beams' origin that makes the elevations' histogram sharpest."""
    best = (np.inf, 0.0)
    rho = np.hypot(p[:, 0], p[:, 1])
    for h in np.round(np.linspace(-0.08, 0.08, 33), 4):
        el = np.degrees(np.arctan2(p[:, 2] - h, rho))
        c, _ = np.histogram(el, bins=max(1, int(np.ptp(el) / 0.02)))
        q = c[c > 0] / c.sum()
        best = min(best, (float(-(q * np.log(q)).sum()) + 1e-9 * abs(h), float(h)))
    return best[1]


def intensity_ring(scan: Scan) -> np.ndarray | None:
    """(N,) int the scan's ``intensity`` read as its ring field, or None when it is not one.

    It is one when the scan has no ring field and no rows, every value is a whole number in 0 .. 1023
    with 4 .. 256 distinct values, the median elevations of the values' returns (from the sharpest
    beam origin height, the farther returns) run in the values' order, up or down, and each value's
    returns lie within a quarter of the spacing between neighbouring values' elevations (median
    absolute deviation over the median spacing). A reflectivity in whole numbers fails the order.
    """
    if scan.ring is not None or scan.columns or scan.intensity is None or not scan.has_intensity:
        return None
    if len(scan) < 50:
        return None
    v = np.asarray(scan.intensity, dtype=np.float64)
    if not np.all(np.isfinite(v)) or np.any(v != np.round(v)) or v.min() < 0 or v.max() > 1023:
        return None
    ring = v.astype(np.int64)
    ids = np.unique(ring)
    if not 4 <= ids.size <= 256:
        return None
    p = np.asarray(scan.points, dtype=np.float64).reshape(-1, 3)
    far = far_mask(p)
    el = elevation_deg(p, sharpest_origin_height(p[far][:: max(1, int(far.sum()) // 20000)]))
    ids, med, counts = group_medians(el[far], ring[far])
    keep = counts >= 3
    ids, med = ids[keep], med[keep]
    if ids.size < 4:
        return None
    step = np.diff(med)
    if not (np.all(step > 0) or np.all(step < 0)):
        return None
    mad = np.array([np.median(np.abs(el[far][ring[far] == i] - m)) for i, m in zip(ids, med, strict=True)])
    return ring if float(np.median(mad)) < 0.25 * float(np.median(np.abs(step))) else None


def with_intensity_ring(scan: Scan) -> Scan:
    """The scan with its intensity as its ring field when it is one (``intensity_ring``), else itself."""
    ring = intensity_ring(scan)
    return scan if ring is None else replace(scan, ring=ring.astype(np.int32))
