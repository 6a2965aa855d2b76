"""Finding the chessboard in a scan without scanlines (Livox-style non-repetitive patterns).

A scanline-free scan has no ring and no azimuth order: the scanline segmentation has nothing to
walk along. Here the same ideas are carried over to neighbours in direction (pattern.py):

1. **Density.** The pattern's returns per steradian on 1 x 1 deg cells, smoothed over 5 x 5 cells
   of the field, measured from the scan itself (a rosette is several times denser at its centre
   than half-way out, and denser the longer it integrates); the local spacing is
   ``delta = 1 / sqrt(density)``.
2. **Objects.** The search runs on at most ``SEARCH_POINTS`` returns (an even random draw of a long
   integration). A return is linked to those of its 32 nearest directions that are less than
   ``jump_ratio * delta`` away in direction and closer than ``jump_ratio * range * delta`` plus
   the noise allowance ``noise_sigmas * sigma`` (the scanline stage's jump rule, the local spacing
   for the azimuth step; ``sigma`` from local planes). Connected components are the objects.
3. **Tests.** Each object is put to the paper's board tests (``board_tests.board_tests``) with a
   local beam model whose azimuth and elevation steps are both the spacing over the object (RMS of
   ``delta``): the theoretical count is ``area * density / d^2`` with the pattern's mean density
   over the object, the size slack one spacing; each return stands for the part of the object's
   plane nearest to it (``pattern.area_weights``), so that the PCA and the quadrant counts follow the
   board, not where the rosette's petals happen to cross it.
4. **Splitting.** An object that fails and is big enough to hold a board is split: a RANSAC plane
   is peeled off (floor, wall), its inliers and the rest are clustered into pieces again and
   tested (a board on its stand comes apart from the floor); a piece that fails the size or
   uniformity test is trimmed in its own plane (a morphological opening a third of the board's
   short side wide removes a pole or an arm).

The candidates then go to the same intensity fit as ring-based ones, which groups returns by ring
for its sampling covariance and plane jackknife: here by elevation bands one spacing high
(:func:`pseudo_rings`). The estimation core gets a single pseudo-beam 0 (:func:`one_pseudo_beam`:
one laser, one range offset).

Testing, trimming, offering and splitting are search.py's, shared with the scanline search; this
module gives it the pieces, counts, tests and trimming above. Planes and clusters are pluggable
(``plane_fn``, ``cluster_fn``) so that Open3D's ``segment_plane`` and ``cluster_dbscan`` can be
measured against these (scripts/bench_ringless.py, docs/lidar_ringless.md).
Frames: the LiDAR frame, metres, radians.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..board import Board
from ..lidars import LidarModel
from ..types import BoardFit
from .board_tests import board_tests
from .options import LidarOptions
from .pattern import area_weights, density_map, estimate_noise, link_components, pseudo_rings, trim_in_plane
from .search import (
    Candidate,
    PlaneFn,
    SearchInput,
    inlier_threshold,
    inside_mask,
    piece_range,
    ransac_plane,
    search_board,
)

__all__ = ["find_ringless_candidates", "one_pseudo_beam", "pseudo_rings", "SEARCH_POINTS"]

#: the search runs on at most this many returns (an even random draw: the pattern's angular density
#: scales, nothing else changes); the fit gathers every return near a candidate's plane
SEARCH_POINTS = 20_000


def one_pseudo_beam(fit: BoardFit) -> BoardFit:
    """The fit with its returns on the one pseudo-beam 0 (what the estimation core is given: one
    laser, one range offset; the bands were for the fit's own covariance). A fit without returns
    has no beams to change."""
    if fit.returns is None:
        return fit
    return replace(fit, returns=replace(fit.returns, ring=np.zeros(len(fit.returns.ring), np.int64)))


def _local_model(model: LidarModel, spacing_rad: float) -> LidarModel:
    """A beam model whose azimuth and elevation steps are both the local spacing: what the paper's
    tests need to give ``area * density / d^2`` as the theoretical count."""
    s = float(np.degrees(min(max(spacing_rad, 1e-5), np.deg2rad(9.0))))
    return LidarModel(
        "local", np.array([-0.5 * s, 0.5 * s]), s, model.range_sigma_m, model.beam_divergence_rad
    )


def _groups(labels: np.ndarray) -> list[np.ndarray]:
    """Indices (sorted) of each label's members; negative labels (DBSCAN's noise) left out."""
    order = np.argsort(labels, kind="stable")
    cuts = np.flatnonzero(np.diff(labels[order])) + 1
    return [np.sort(g) for g in np.split(order, cuts) if labels[g[0]] >= 0]


def find_ringless_candidates(
    points: np.ndarray,
    ring: np.ndarray | None,
    intensity: np.ndarray,
    board: Board,
    model: LidarModel,
    roi: Any | None = None,
    options: LidarOptions = LidarOptions(),
    rng: np.random.Generator | None = None,
    mask: np.ndarray | None = None,
    accept: Callable[[list[Candidate]], bool] | None = None,
    plane_fn: PlaneFn = ransac_plane,
    cluster_fn: Callable[..., np.ndarray] = link_components,
) -> list[Candidate]:
    """Every segment of a scanline-free scan that passes the chessboard tests (``detection.find_candidates``'s
    contract: same arguments, ``ring`` unused); raise BoardNotFound with the reason if none.

    points: (N, 3) LiDAR frame. intensity: (N,). mask: optional (N,) bool of points the search may
    use (with ``roi``). ``accept`` is asked after the objects as found and after each split object.
    plane_fn(p, threshold, rng) -> (normal, offset, inliers); cluster_fn(p, u, delta, jump_ratio,
    allow) -> labels (negative: noise): the plane segmentation and the clustering (run again on
    the pieces of a split object).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    p_all = np.asarray(points, dtype=np.float64)
    inten_all = np.asarray(intensity, dtype=np.float64)
    r_all = np.linalg.norm(p_all, axis=1)
    ok = np.isfinite(r_all) & (r_all > options.min_range_m)
    if ok.sum() > SEARCH_POINTS:
        keep = np.zeros_like(ok)
        keep[np.sort(rng.choice(np.flatnonzero(ok), SEARCH_POINTS, replace=False))] = True
        ok = keep
    dens = density_map(p_all[ok] / r_all[ok, None])
    idx_all = np.flatnonzero(inside_mask(p_all, roi, mask, valid=ok))
    p, inten = p_all[idx_all], inten_all[idx_all]
    u = p / r_all[idx_all, None]
    sigma = estimate_noise(p, rng)
    own = _Pieces(p, u, dens.spacing(u), inten, sigma, inlier_threshold(options, sigma), board, model,
                  options, rng, plane_fn, cluster_fn)  # fmt: skip
    scan = SearchInput(
        points=p,
        intensity=inten,
        sigma=sigma,
        threshold=own.thr,
        objects=[obj for obj, _ in own.pieces(np.arange(p.shape[0]))],
        n_theory=own.n_theory,
        tests=own.tests,
        trims=own.trims,
        pieces=own.pieces,
        plane_fn=plane_fn,
        to_scan=idx_all,
        note=", scan without scanlines",
        hint=", and accumulate the scan longer (a non-repetitive pattern covers a board evenly after about "
        "0.5 s)",
    )
    return search_board(scan, board, options, rng, accept, in_roi=roi is not None)


@dataclass
class _Pieces:
    """What the shared search (``search.SearchInput``) asks of a scanline-free scan, at the pattern's
    local density: p (M, 3) the returns searched, u their unit directions, delta (M,) the pattern's
    spacing at each (rad), intensity (M,), sigma the range noise and thr the RANSAC inlier distance (m)."""

    p: np.ndarray
    u: np.ndarray
    delta: np.ndarray
    intensity: np.ndarray
    sigma: float
    thr: float
    board: Board
    model: LidarModel
    options: LidarOptions
    rng: np.random.Generator
    plane_fn: PlaneFn
    cluster_fn: Callable[..., np.ndarray]

    def __post_init__(self) -> None:
        x0, x1, y0, y1 = self.board.extent()
        self.short_side = y1 - y0
        self.area = (x1 - x0) * self.short_side
        self.allow = self.options.noise_sigmas * self.sigma

    def pieces(self, sub: np.ndarray, links: None = None) -> list[tuple[np.ndarray, None]]:
        """The connected pieces of the subset ``sub`` (indices), clustered on their own."""
        if sub.size < 12:
            return []
        labels = self.cluster_fn(
            self.p[sub], self.u[sub], self.delta[sub], self.options.jump_ratio, self.allow
        )
        return [(sub[g], None) for g in _groups(labels)]

    def spacing(self, idx: np.ndarray) -> float:
        """The pattern's spacing over the piece, ``sqrt(mean(delta_i^2))`` (rad): its mean density
        over the piece's solid angle is ``M / sum_i delta_i^2`` (each return stands for ``delta_i^2`` sr)."""
        return float(np.sqrt(np.mean(self.delta[idx] ** 2)))

    def n_theory(self, idx: np.ndarray) -> float:
        """Returns of a frontal board at the piece's range: ``area / (d * spacing)^2``."""
        d = piece_range(self.p[idx])
        return self.area / (d * self.spacing(idx)) ** 2

    def tests(self, idx: np.ndarray) -> tuple[bool, float, str, str]:
        """The paper's tests at the local spacing, each return weighted by the board area it stands for."""
        q = self.p[idx]
        s = self.spacing(idx)
        r_q = np.linalg.norm(q, axis=1)
        w_area = area_weights(q, float(np.linalg.norm(q.mean(axis=0))) * s)
        n_q = np.linalg.svd(q - q.mean(axis=0), full_matrices=False)[2][2]
        solid = w_area * np.abs(q @ n_q) / r_q**3  # each return's board area as a solid angle
        model = _local_model(self.model, s)
        return board_tests(q, self.board, model, self.sigma, self.options, self.intensity[idx], solid)

    def trims(self, idx: np.ndarray, depth: int) -> Iterator[np.ndarray]:
        """The piece trimmed in its own plane by an opening a third of the board's short side wide,
        then a stronger one (the plane is fitted at any depth: the same random draws as ever)."""
        q = self.p[idx]
        n, _, inl = self.plane_fn(q, self.thr, self.rng)
        cell = max(0.01, 1.5 * float(np.linalg.norm(q.mean(axis=0))) * self.spacing(idx))
        for strength in (1.0, 1.6):
            yield idx[np.flatnonzero(inl)[trim_in_plane(q[inl], n, cell, strength * self.short_side / 3.0)]]
