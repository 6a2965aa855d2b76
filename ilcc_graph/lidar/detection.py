"""Finding the chessboard among the segments of one scan (Wang et al. 2017, Section 4.1).

A candidate passes the paper's tests, with the board's physical size (margin included):

1. point count within ``count_ratio`` of the count a frontal board would give at that range;
2. PCA planarity: smallest variance / total below ``planarity_ratio`` (after taking out the
   range noise's own share, estimated from the scan);
3. a RANSAC plane holds (nearly) all of it;
4. extent along the two PCA axes within ``size_ratio`` of the board's sides;
5. uniformity ``1 - (n_max - n_min) / n_all >= uniformity_min`` over the four quadrants of the
   extent, each return weighted by the board area it stands for (range^2 / cos(incidence));
6. (ours) the intensities split into two levels (black and white print).

The most uniform candidate wins. An object that fails because it is too large or not planar
(board merged with a wall close behind, a person touching it, the stand under it) is split:
RANSAC planes are peeled off it one by one and each plane's inliers are cut into connected
pieces with the segmentation's own point links; every piece is tested again.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..board import Board
from ..errors import BoardNotFound
from ..lidar_models import LidarModel
from .options import LidarOptions
from .segmentation import Segmentation, components_of, segment_scan

__all__ = ["Candidate", "find_board", "roi_mask", "board_tests", "ransac_plane"]


@dataclass(frozen=True)
class Candidate:
    """The chessboard's points found in a scan.

    indices: (M,) indices into the scan's points. normal: (3,) unit plane normal towards the sensor.
    offset: plane offset d with ``normal @ p = d`` (metres, negative: the sensor is on the normal's side).
    uniformity: the paper's quadrant uniformity. noise_sigma: range noise of the scan (m).
    tested: number of candidates tested.
    """

    indices: np.ndarray
    normal: np.ndarray
    offset: float
    uniformity: float
    noise_sigma: float
    tested: int


def roi_mask(points: np.ndarray, roi: Any | None) -> np.ndarray:
    """(N,) bool: points inside the region of interest (config.Roi or None = everything).

    Azimuth ``atan2(y, x)`` and elevation ``atan2(z, hypot(x, y))`` in degrees, range in metres;
    an azimuth interval with lo > hi wraps through +-180 deg.
    """
    p = np.asarray(points, dtype=np.float64)
    if roi is None:
        return np.ones(p.shape[0], bool)
    if hasattr(roi, "contains"):
        return np.asarray(roi.contains(p), bool)
    keep = np.ones(p.shape[0], bool)
    if getattr(roi, "azimuth_deg", None) is not None:
        lo, hi = roi.azimuth_deg
        az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
        keep &= ((az >= lo) & (az <= hi)) if lo <= hi else ((az >= lo) | (az <= hi))
    if getattr(roi, "elevation_deg", None) is not None:
        lo, hi = roi.elevation_deg
        el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
        keep &= (el >= lo) & (el <= hi)
    if getattr(roi, "range_m", None) is not None:
        lo, hi = roi.range_m
        r = np.linalg.norm(p, axis=1)
        keep &= (r >= lo) & (r <= hi)
    return keep


def ransac_plane(
    p: np.ndarray, threshold: float, rng: np.random.Generator, n_hyp: int = 128, max_score: int = 3000
) -> tuple[np.ndarray, float, np.ndarray]:
    """Vectorised RANSAC plane, refined by least squares on the inliers.

    p: (M, 3). Returns (normal (3,), offset d with normal @ x = d, inlier mask (M,)).
    """
    m = p.shape[0]
    sub = p if m <= max_score else p[rng.choice(m, max_score, replace=False)]
    tri = rng.integers(0, m, size=(n_hyp, 3))
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    nrm = np.cross(b - a, c - a)
    ln = np.linalg.norm(nrm, axis=1)
    good = ln > 1e-9
    nrm = nrm[good] / ln[good, None]
    d = np.einsum("ij,ij->i", nrm, a[good])
    if nrm.shape[0] == 0:
        return np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(m, bool)
    score = (np.abs(sub @ nrm.T - d) < threshold).sum(axis=0)
    best = int(np.argmax(score))
    n, dd = nrm[best], d[best]
    for _ in range(2):
        inl = np.abs(p @ n - dd) < threshold
        if inl.sum() < 3:
            break
        q = p[inl]
        mu = q.mean(axis=0)
        _, _, vt = np.linalg.svd(q - mu, full_matrices=False)
        n, dd = vt[2], float(vt[2] @ mu)
    inl = np.abs(p @ n - dd) < threshold
    return n, float(dd), inl


def _local_elevation_step(model: LidarModel, elevation: float) -> float:
    el = model.vertical_angles_rad
    if el.size < 2:
        return np.deg2rad(2.0)
    mids = 0.5 * (el[1:] + el[:-1])
    gaps = np.diff(el)
    return float(np.interp(elevation, mids, gaps))


def intensity_contrast(intensity: np.ndarray) -> tuple[float, float]:
    """Two-level contrast of intensities (M,): (separation d', smaller class fraction).

    Otsu's split into two classes; d' = (mean_high - mean_low) / pooled within-class sigma.
    A printed chessboard gives d' >> 4 with both classes near half; a plain surface gives d' < 3.
    """
    r = np.sort(np.asarray(intensity, dtype=np.float64))
    m = r.size
    if m < 4 or r[-1] == r[0]:
        return 0.0, 0.0
    c = np.cumsum(r)
    k = np.arange(1, m)
    m0, m1 = c[:-1] / k, (c[-1] - c[:-1]) / (m - k)
    between = k * (m - k) * (m1 - m0) ** 2
    j = int(np.argmax(between))
    lo, hi = r[: j + 1], r[j + 1 :]
    pooled = np.sqrt((lo.var() * lo.size + hi.var() * hi.size) / m)
    return float((hi.mean() - lo.mean()) / max(pooled, 1e-9)), float(min(lo.size, hi.size) / m)


def board_tests(
    p: np.ndarray, board: Board, model: LidarModel, sigma: float, options: LidarOptions,
    intensity: np.ndarray | None = None,
) -> tuple[bool, float, str, str]:
    """The paper's tests on one candidate's points p (M, 3) (and intensities (M,), when given).

    Returns (passed, uniformity, failed test name or "", human-readable detail).
    """
    x0, x1, y0, y1 = board.extent()
    long_side, short_side = x1 - x0, y1 - y0
    m = p.shape[0]
    mu = p.mean(axis=0)
    dist = float(np.linalg.norm(mu))
    elev = float(np.arctan2(mu[2], np.hypot(mu[0], mu[1])))
    step_az = np.deg2rad(model.horizontal_resolution_deg)
    step_el = _local_elevation_step(model, elev)
    area = long_side * short_side
    n_theory = area / (dist**2 * step_az * step_el)
    hi = options.count_ratio[1] * (1 + dist * step_el / short_side) * (1 + dist * step_az / short_side)
    ratio = m / n_theory
    if not (options.count_ratio[0] <= ratio <= hi):
        return False, 0.0, "count", f"{m} points, {ratio:.2f} x the {n_theory:.0f} expected at {dist:.2f} m"
    q = p - mu
    cov = q.T @ q / m
    w, v = np.linalg.eigh(cov)
    noise_share = (0.5 * options.noise_sigmas * sigma) ** 2
    planar = (w[0] - noise_share) / w.sum()
    if planar > options.planarity_ratio:
        return False, 0.0, "planarity", f"not flat (PCA ratio {w[0] / w.sum():.3f}) at {dist:.2f} m"
    uv = q @ v[:, [2, 1]]
    lo, hi_ = np.quantile(uv, 0.005, axis=0), np.quantile(uv, 0.995, axis=0)
    ext = (hi_ - lo) * m / max(m - 1, 1)
    smin, smax = options.size_ratio
    if not (smin * long_side <= ext[0] <= smax * long_side and smin * short_side <= ext[1] <= smax * short_side):
        return (
            False, 0.0, "size",
            f"{ext[0]:.2f} x {ext[1]:.2f} m at {dist:.2f} m, board {long_side:.2f} x {short_side:.2f} m",
        )  # fmt: skip
    mid = 0.5 * (lo + hi_)
    quad = (uv[:, 0] >= mid[0]).astype(int) * 2 + (uv[:, 1] >= mid[1]).astype(int)
    # each return stands for the board area r^2 d_az d_el / cos(incidence): weigh by it so that a
    # board tilted at close range (denser on its near side) still counts as evenly covered
    r_i = np.linalg.norm(p, axis=1)
    cos_i = np.abs(p @ v[:, 0]) / np.maximum(r_i, 1e-9)
    w_i = r_i**2 / np.maximum(cos_i, 0.2)
    nq = np.bincount(quad, weights=w_i, minlength=4)
    uniformity = 1.0 - (nq.max() - nq.min()) / nq.sum()
    if uniformity < options.uniformity_min:
        return False, uniformity, "uniformity", f"uneven ({uniformity:.2f}) {ext[0]:.2f} x {ext[1]:.2f} m at {dist:.2f} m"
    if intensity is not None:
        sep, frac = intensity_contrast(intensity)
        if sep < options.contrast_min or frac < 0.1:
            return (
                False, uniformity, "contrast",
                f"board-shaped at {dist:.2f} m but no black/white intensity contrast (d'={sep:.1f}, {frac:.0%})",
            )  # fmt: skip
    return True, float(uniformity), "", f"{m} points at {dist:.2f} m"


def trim_attachments(p: np.ndarray, cell: float, short_side: float) -> np.ndarray:
    """Indices of the largest compact blob of a planar piece p (M, 3): drops thin attachments.

    The points go into a 2-D occupancy grid in their plane (cells of ``cell`` metres, a little more
    than the ring spacing so that rings leave no holes); a morphological opening with a disc of about a quarter of the board's
    short side removes arms, poles and edges of other objects that lie in the board's plane; the
    largest remaining blob, grown back, is kept.
    """
    from scipy import ndimage

    mu = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - mu, full_matrices=False)
    uv = (p - mu) @ vt[:2].T
    ij = np.floor((uv - uv.min(axis=0)) / cell).astype(np.int64) + 2
    shape = ij.max(axis=0) + 3
    if shape[0] * shape[1] > 4_000_000:
        return np.arange(p.shape[0])
    occ = np.zeros(shape, bool)
    occ[ij[:, 0], ij[:, 1]] = True
    rad = max(1, int(np.floor(0.25 * short_side / cell)))
    yy, xx = np.mgrid[-rad : rad + 1, -rad : rad + 1]
    disc = xx**2 + yy**2 <= rad**2 + 0.5
    core = ndimage.binary_erosion(occ, structure=disc)
    lab, n = ndimage.label(core)
    if n == 0:
        return np.zeros(0, np.int64)
    big = np.argmax(np.bincount(lab.ravel())[1:]) + 1
    keep = ndimage.binary_dilation(lab == big, structure=disc, iterations=1)
    return np.flatnonzero(keep[ij[:, 0], ij[:, 1]])


def find_board(
    points: np.ndarray,
    ring: np.ndarray,
    intensity: np.ndarray,
    board: Board,
    model: LidarModel,
    roi: Any | None = None,
    options: LidarOptions = LidarOptions(),
    rng: np.random.Generator | None = None,
) -> Candidate:
    """Segment the scan and return the chessboard's points; raise BoardNotFound with the reason.

    points: (N, 3) LiDAR frame. ring: (N,) beam index. intensity: (N,).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    p = np.asarray(points, dtype=np.float64)
    inten = np.asarray(intensity, dtype=np.float64)
    inside = roi_mask(p, roi)
    if not inside.any():
        raise BoardNotFound("no point of the scan lies inside the region of interest (board.roi)")
    seg: Segmentation = segment_scan(p, ring, model, options, valid=inside)
    sigma = seg.noise_sigma
    x0, x1, y0, y1 = board.extent()
    short_side = y1 - y0
    diag = float(np.hypot(x1 - x0, y1 - y0))
    step_az = np.deg2rad(model.horizontal_resolution_deg)
    thr = max(options.ransac_threshold_m, 2.5 * sigma)

    order = np.argsort(seg.labels, kind="stable")
    lab_sorted = seg.labels[order]
    first = np.searchsorted(lab_sorted, np.arange(seg.n_objects))
    last = np.searchsorted(lab_sorted, np.arange(seg.n_objects), side="right")

    passed: list[tuple[float, np.ndarray]] = []
    misses: list[tuple[int, str, str]] = []  # (size, test, detail)
    tested = 0

    def min_count(idx: np.ndarray) -> float:
        d = float(np.linalg.norm(p[idx].mean(axis=0)))
        el = float(np.arctan2(p[idx, 2].mean(), np.hypot(p[idx, 0].mean(), p[idx, 1].mean())))
        n_th = (x1 - x0) * short_side / (d**2 * step_az * _local_elevation_step(model, el))
        return options.count_ratio[0] * n_th

    def test(idx: np.ndarray, depth: int) -> None:
        nonlocal tested
        q = p[idx]
        span = np.ptp(q, axis=0)
        if np.linalg.norm(span) < options.size_ratio[0] * short_side or idx.size < 12:
            return
        if idx.size < min_count(idx):
            return
        tested += 1
        ok, uni, name, detail = board_tests(q, board, model, sigma, options, inten[idx])
        if ok:
            n, d, inl = ransac_plane(q, thr, rng)
            if inl.mean() >= 0.9:
                passed.append((uni, idx[inl]))
                return
            name, detail = "plane", f"only {inl.mean():.0%} of its points on one plane; {detail}"
        if depth == 1 and name in ("size", "uniformity", "count", "plane", "contrast"):
            d = float(np.linalg.norm(q.mean(axis=0)))
            el = float(np.arctan2(q[:, 2].mean(), np.hypot(q[:, 0].mean(), q[:, 1].mean())))
            cell = 1.2 * d * max(_local_elevation_step(model, el), step_az)
            kept = trim_attachments(q, cell, short_side)
            if 12 <= kept.size < idx.size:
                test(idx[kept], 2)
                return
        misses.append((idx.size, name, detail))
        if depth > 0 or float(np.linalg.norm(span)) < options.size_ratio[0] * diag:
            return
        split(idx)

    def split(idx: np.ndarray) -> None:
        # peel planes off an over-merged object; cut each plane's inliers into connected pieces
        remaining = idx
        local_of = np.full(p.shape[0], -1, np.int64)
        for _ in range(options.max_planes):
            if remaining.size < 12:
                break
            n, d, inl = ransac_plane(p[remaining], thr, rng)
            if inl.sum() < 12:
                break
            plane_idx = remaining[inl]
            local_of[:] = -1
            local_of[plane_idx] = np.arange(plane_idx.size)
            e = seg.edges
            ea, eb = local_of[e[:, 0]], local_of[e[:, 1]]
            keep = (ea >= 0) & (eb >= 0)
            _, comp = components_of(plane_idx.size, np.stack([ea[keep], eb[keep]], axis=1))
            for c in np.unique(comp):
                piece = plane_idx[comp == c]
                if piece.size >= 12:
                    test(piece, 1)
            remaining = remaining[~inl]

    for k in range(seg.n_objects):
        idx = order[first[k] : last[k]]
        test(idx, 0)

    if not passed:
        if not misses:
            raise BoardNotFound(
                f"no object of board size ({x1 - x0:.2f} x {short_side:.2f} m) in the scan"
                + (" inside the region of interest" if roi is not None else "")
            )
        misses.sort(key=lambda t: -t[0])
        near = "; ".join(f"{name}: {detail}" for _, name, detail in misses[:3])
        raise BoardNotFound(
            f"no segment passed the chessboard tests ({tested} board-sized candidates); largest: {near}. "
            "If the board is in view, narrow the search with board.roi (azimuth_deg, elevation_deg, range_m)."
        )
    best = max(passed, key=lambda t: t[0])
    idx = np.unique(best[1])
    q = p[idx]
    n, d, inl = ransac_plane(q, thr, rng)
    if n @ q.mean(axis=0) > 0:  # normal towards the sensor
        n, d = -n, -d
    return Candidate(idx, n, float(d), float(best[0]), sigma, tested)
