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

:func:`find_candidates` returns every candidate that passes (the search itself, shared with
scanline-free scans, is search.py's); the caller (``estimate_board``) fits the chessboard to the
best few and picks by how well the fitted pattern explains them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from ..board import Board
from ..lidars import LidarModel
from .board_tests import board_tests, intensity_contrast, local_elevation_step
from .options import LidarOptions
from .search import (
    Candidate,
    SearchInput,
    inlier_threshold,
    inside_mask,
    piece_range,
    ransac_plane,
    roi_mask,
    search_board,
)
from .segmentation import Segmentation, components_of, segment_scan

__all__ = [
    "Candidate", "find_candidates", "roi_mask", "board_tests", "intensity_contrast",
    "ransac_plane",
]  # fmt: skip


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
    top_beam = len(model.vertical_angles_rad) - 1
    inside = inside_mask(p, roi, mask)
    seg: Segmentation = segment_scan(p, ring, model, options, valid=inside)
    x0, x1, y0, y1 = board.extent()
    short_side = y1 - y0
    step_az = np.deg2rad(model.horizontal_resolution_deg)

    def n_theory(idx: np.ndarray) -> float:
        """Returns of a frontal board at the piece's range: area / (d^2 azimuth step x ring spacing)."""
        q = p[idx]
        d = piece_range(q)
        step_el = float(np.mean(local_elevation_step(model, np.arctan2(q[:, 2], np.hypot(q[:, 0], q[:, 1])))))
        return (x1 - x0) * short_side / (d**2 * step_az * step_el)

    def trims(idx: np.ndarray, depth: int) -> Iterator[np.ndarray]:
        """A piece of a split object without its attachments: an opening of about a third of the
        board's short side, then a stronger one (trim_attachments)."""
        if depth != 1:
            return
        for strength in (1.0, 1.6):
            yield idx[trim_attachments(p[idx], ring_a[idx], step_az, short_side, strength)]

    member = np.zeros(p.shape[0], bool)
    e_all = seg.edges
    e_obj = seg.labels[e_all[:, 0]]  # both ends of a link share the object

    def pieces(sub: np.ndarray, edges: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Connected pieces of the point subset ``sub`` under the links ``edges`` (a superset of its
        own), each with its own links."""
        member[sub] = True
        e = edges[member[edges[:, 0]] & member[edges[:, 1]]]
        member[sub] = False
        local = np.searchsorted(sub, e) if e.size else e
        _, comp = components_of(sub.size, local)
        order_c = np.argsort(comp, kind="stable")
        cuts = np.flatnonzero(np.diff(comp[order_c])) + 1
        groups = [sub[g] for g in np.split(order_c, cuts)]
        if e.size == 0:
            return [(g, e) for g in groups]
        ec = comp[local[:, 0]]
        eo = np.argsort(ec, kind="stable")
        ecuts = np.searchsorted(ec[eo], np.arange(len(groups) + 1))
        return [(g, e[eo[ecuts[i] : ecuts[i + 1]]]) for i, g in enumerate(groups)]

    order = np.argsort(seg.labels, kind="stable")
    bounds = np.searchsorted(seg.labels[order], np.arange(seg.n_objects + 1))
    scan = SearchInput(
        points=p,
        intensity=inten,
        sigma=seg.noise_sigma,
        threshold=inlier_threshold(options, seg.noise_sigma),
        objects=[order[bounds[k] : bounds[k + 1]] for k in range(seg.n_objects)],
        n_theory=n_theory,
        tests=lambda idx: board_tests(p[idx], board, model, seg.noise_sigma, options, inten[idx]),
        trims=trims,
        pieces=pieces,
        links=lambda idx: e_all[e_obj == seg.labels[idx[0]]],
        admit=lambda idx: np.unique(ring_a[idx]).size >= options.min_rings,
        at_edge=lambda idx: bool(ring_a[idx].min() <= 0 or ring_a[idx].max() >= top_beam),
    )
    return search_board(scan, board, options, rng, accept, in_roi=roi is not None)
