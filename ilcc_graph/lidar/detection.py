"""Finding the chessboard among the segments of one scan (Wang et al. 2017, Section 4.1).

A candidate passes the paper's tests, with the board's physical size (margin included):

1. point count within ``count_ratio`` of the count a frontal board would give at that range;
2. PCA planarity: smallest variance / total below ``planarity_ratio`` (after taking out the
   range noise's own share, estimated from the scan);
3. a RANSAC plane holds (nearly) all of it;
4. extent along the two PCA axes within ``size_ratio`` of the board's sides (the lower limit less
   one ring spacing: a board turned diamond-wise loses its tips between rings);
5. uniformity ``1 - (n_max - n_min) / n_all >= uniformity_min`` over the four quadrants of the
   extent, each return weighted by the board area it stands for (range^2 / cos(incidence));
6. (ours) the intensities split into two levels (black and white print), measured on the
   candidate itself (Otsu's split, separation in pooled sigmas): no absolute intensity scale, so
   Velodyne 0-100, Ouster raw signal or reflectivity and Livox 0-255 are treated alike.

:func:`find_candidates` returns every candidate that passes; the caller (``estimate_board``)
fits the chessboard to the best few and picks by how well the fitted pattern explains them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..board import Board
from ..errors import BoardNotFound
from ..lidars import LidarModel
from .board_tests import board_tests, intensity_contrast, local_elevation_step
from .options import LidarOptions
from .segmentation import Segmentation, components_of, segment_scan

__all__ = [
    "Candidate", "find_board", "find_candidates", "roi_mask", "board_tests", "intensity_contrast",
    "ransac_plane",
]  # fmt: skip


@dataclass(frozen=True)
class Candidate:
    """The chessboard's points found in a scan.

    indices: (M,) indices into the scan's points. normal: (3,) unit plane normal towards the sensor.
    offset: plane offset d with ``normal @ p = d`` (metres, negative: the sensor is on the normal's side).
    uniformity: the paper's quadrant uniformity. noise_sigma: range noise of the scan (m).
    tested: number of candidates tested (so far). contrast: the black/white separation d'.
    """

    indices: np.ndarray
    normal: np.ndarray
    offset: float
    uniformity: float
    noise_sigma: float
    tested: int
    contrast: float = 0.0


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
    p: np.ndarray, threshold: float, rng: np.random.Generator, n_hyp: int = 96, max_score: int = 1500
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


def trim_attachments(
    p: np.ndarray, ring: np.ndarray, step_az: float, short_side: float, strength: float = 1.0
) -> np.ndarray:
    """Indices of the largest compact blob of a planar piece p (M, 3): drops thin attachments.

    The returns go into their range image (ring x azimuth step), where a board is a block several
    rings tall and many columns wide whatever the beam table. A morphological opening by a box
    ``3 rings x strength * (short side / 3)`` wide removes poles (a few columns), arms and
    edges of other objects (one ring), and the largest remaining block, grown back, is kept.
    ring: (M,) beam index; step_az: azimuth step (rad).
    """
    from scipy import ndimage

    az = np.arctan2(p[:, 1], p[:, 0])
    az = np.angle(np.exp(1j * (az - np.angle(np.exp(1j * az).mean()))))  # unwrapped about the mean
    col = np.round((az - az.min()) / step_az).astype(np.int64)
    ring_u, row = np.unique(ring, return_inverse=True)
    dist = float(np.median(np.linalg.norm(p, axis=1)))
    width = max(3, int(np.floor(strength * short_side / (3.0 * dist * step_az))))
    if col.max() + 1 > 20_000 or row.max() + 1 < 3:
        return np.arange(p.shape[0])
    occ = np.zeros((row.max() + 3, col.max() + 1 + 2 * width), bool)
    occ[row + 1, col + width] = True
    # returns lost between columns (dropouts, dark print) must not break the board apart
    occ = ndimage.binary_closing(occ, structure=np.ones((1, 3), bool))
    box = np.ones((3, width), bool)
    core = ndimage.binary_erosion(occ, structure=box)
    lab, n = ndimage.label(core)
    if n == 0:
        return np.arange(p.shape[0])  # nothing survives: too small to judge, keep it whole
    big = np.argmax(np.bincount(lab.ravel())[1:]) + 1
    keep = ndimage.binary_dilation(lab == big, structure=box)
    return np.flatnonzero(keep[row + 1, col + width])


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
    """Segment the scan and return the most uniform candidate; raise BoardNotFound with the reason.

    points: (N, 3) LiDAR frame. ring: (N,) beam index. intensity: (N,).
    """
    cands = find_candidates(points, ring, intensity, board, model, roi, options, rng)
    return max(cands, key=lambda c: c.uniformity)


def find_candidates(
    points: np.ndarray,
    ring: np.ndarray,
    intensity: np.ndarray,
    board: Board,
    model: LidarModel,
    roi: Any | None = None,
    options: LidarOptions = LidarOptions(),
    rng: np.random.Generator | None = None,
    mask: np.ndarray | None = None,
    accept: Callable[[list[Candidate]], bool] | None = None,
) -> list[Candidate]:
    """Every segment that passes the chessboard tests; raise BoardNotFound with the reason if none.

    points: (N, 3) LiDAR frame. ring: (N,) beam index. intensity: (N,). mask: optional (N,) bool,
    the points the search may use (with ``roi``). The objects are tested as they are; only when
    ``accept`` (given the new candidates) says no, the over-merged objects are split, smallest
    first, and ``accept`` is asked again after each. Without ``accept`` the first candidates found
    are taken.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    p = np.asarray(points, dtype=np.float64)
    inten = np.asarray(intensity, dtype=np.float64)
    ring_a = np.asarray(ring)
    inside = roi_mask(p, roi)
    if mask is not None:
        inside &= np.asarray(mask, bool)
    if not inside.any():
        where = "the region of interest (board.roi)" if mask is None else "the expected board's box"
        raise BoardNotFound(f"no point of the scan lies inside {where}")
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

    passed: list[tuple[float, np.ndarray, float]] = []
    misses: list[tuple[int, str, str]] = []  # (size, test, detail)
    to_split: list[np.ndarray] = []
    tested = 0

    def min_count(idx: np.ndarray) -> float:
        q = p[idx]
        d = float(np.linalg.norm(q.mean(axis=0)))
        step_el = float(np.mean(local_elevation_step(model, np.arctan2(q[:, 2], np.hypot(q[:, 0], q[:, 1])))))
        n_th = (x1 - x0) * short_side / (d**2 * step_az * step_el)
        return options.count_ratio[0] * n_th

    def test(idx: np.ndarray, depth: int) -> None:
        nonlocal tested
        q = p[idx]
        span = np.ptp(q, axis=0)
        if np.linalg.norm(span) < options.size_ratio[0] * short_side or idx.size < 12:
            return
        if (
            idx.size < max(min_count(idx), options.min_points)
            or np.unique(ring_a[idx]).size < options.min_rings
        ):
            return
        tested += 1
        ok, uni, name, detail = board_tests(q, board, model, sigma, options, inten[idx])
        if ok:
            n, d, inl = ransac_plane(q, thr, rng)
            if inl.mean() >= 0.9:
                passed.append((uni, idx[inl], intensity_contrast(inten[idx[inl]])[0]))
                return
            name, detail = "plane", f"only {inl.mean():.0%} of its points on one plane; {detail}"
        if depth == 1 and name in ("size", "uniformity", "count", "plane", "contrast"):
            # an opening of about a third of the board's short side, then a stronger one
            for strength in (1.0, 1.6):
                kept = trim_attachments(q, ring_a[idx], step_az, short_side, strength)
                if 12 <= kept.size < idx.size:
                    n_pass = len(passed)
                    test(idx[kept], 2)
                    if len(passed) > n_pass:
                        return
        misses.append((idx.size, name, detail))
        if depth > 0 or float(np.linalg.norm(span)) < options.size_ratio[0] * diag:
            return
        to_split.append(idx)

    member = np.zeros(p.shape[0], bool)
    e_all = seg.edges
    e_obj = seg.labels[e_all[:, 0]]  # both ends of a link share the object

    def pieces(sub: np.ndarray, edges: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Connected pieces of the point subset ``sub`` under the links ``edges`` (a superset of its own),
        and each piece's own links."""
        member[sub] = True
        e = edges[member[edges[:, 0]] & member[edges[:, 1]]]
        member[sub] = False
        local = np.searchsorted(sub, e) if e.size else e
        _, comp = components_of(sub.size, local)
        order_c = np.argsort(comp, kind="stable")
        cuts = np.flatnonzero(np.diff(comp[order_c])) + 1
        groups = [sub[g] for g in np.split(order_c, cuts)]
        if e.size == 0:
            return groups, [e for _ in groups]
        ec = comp[local[:, 0]]
        eo = np.argsort(ec, kind="stable")
        ecuts = np.searchsorted(ec[eo], np.arange(len(groups) + 1))
        return groups, [e[eo[ecuts[i] : ecuts[i + 1]]] for i in range(len(groups))]

    budget = [options.max_planes * 6]  # RANSAC planes for the whole scan

    def split(idx: np.ndarray) -> None:
        # peel planes off an over-merged object: each plane's inliers are cut into connected pieces
        # and tested; what is left is cut into connected pieces again (the ground gone, a board on a
        # pole comes apart from it) and those are tested or split in turn
        idx = np.sort(idx)
        queue = [(idx, e_all[e_obj == seg.labels[idx[0]]])]
        own = options.max_planes * 3
        n_before = len(passed)
        while queue and budget[0] > 0 and own > 0 and len(passed) == n_before:
            own -= 1
            # smallest first: the floor and walls are big, a board with a pole or an arm is not
            queue.sort(key=lambda t: -len(t[0]))
            cur, cur_e = queue.pop()
            if cur.size < 12:
                continue
            budget[0] -= 1
            n, d, inl = ransac_plane(p[cur], thr, rng)
            if inl.sum() < 12:
                continue
            groups, _ = pieces(cur[inl], cur_e)
            for piece in groups:
                if piece.size >= 12:
                    test(piece, 1)
            rest = cur[~inl]
            if rest.size < 12:
                continue
            groups, edges = pieces(rest, cur_e)
            for piece, pe in zip(groups, edges, strict=True):
                if piece.size < 12:
                    continue
                size = float(np.linalg.norm(np.ptp(p[piece], axis=0)))
                if size < 2.0 * diag:
                    test(piece, 1)  # small enough to be judged (and trimmed) directly
                if size >= options.size_ratio[0] * diag and piece.size >= max(
                    min_count(piece), options.min_points
                ):
                    queue.append((piece, pe))  # big enough, and with returns enough, to hold a board

    out: list[Candidate] = []

    def offer() -> bool:
        """Turn the new passes into Candidates; True when the caller accepts them (stop searching)."""
        new: list[Candidate] = []
        for uni, members, sep in passed[len(out) :]:
            idx = np.unique(members)
            q = p[idx]
            n, d, inl = ransac_plane(q, thr, rng)
            if n @ q.mean(axis=0) > 0:  # normal towards the sensor
                n, d = -n, -d
            new.append(Candidate(idx, n, float(d), float(uni), sigma, tested, float(sep)))
        out.extend(new)
        if not new:
            return False
        return True if accept is None else bool(accept(new))

    for k in range(seg.n_objects):
        idx = order[first[k] : last[k]]
        test(idx, 0)
    # only when no object passed as it is (or none of them was accepted): split the over-merged
    # ones, smallest first: a board merged with a hand or its stand is cheap to split; the room last
    done = offer()
    for idx in sorted(to_split, key=len):
        if done:
            break
        split(idx)
        done = offer()

    if not out:
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
    return out
