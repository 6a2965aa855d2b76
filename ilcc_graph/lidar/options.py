"""Tuning knobs of the LiDAR stage (segmentation, board tests, corner fit), with defaults, and how a
refusal states the knob it breaks (``breach``).

Every number is dimensionless or in the unit its name says. Defaults follow the paper
(Wang et al. 2017, Section 4) where it gives one; the others are ours and documented in
docs/lidar_stage.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LidarOptions:
    """Options of :func:`ilcc_graph.lidar.estimate_board`.

    Segmentation
    ------------
    min_range_m: points closer than this are ignored (the sensor's own housing, dust).
    jump_ratio: a scanline breaks where two successive points are farther apart than
        ``jump_ratio * range * azimuth step`` (plus the noise allowance); ILCC uses 5.
    link_ratio: two points of neighbouring rings are linked when closer than
        ``link_ratio * range * elevation step`` (plus the noise allowance).
    noise_sigmas: the noise allowance is ``noise_sigmas * sigma`` with sigma the range noise
        estimated from the scan itself.
    min_links: scanline segments of neighbouring rings merge when at least this many point
        pairs link them.

    Board tests (paper, Section 4.1)
    --------------------------------
    count_ratio: accepted (lo, hi) of points / theoretical count of a frontal board at that range;
        hi is widened by one ring and one column of quantisation (see docs) and by the margin
        tolerance.
    margin_tolerance_m: how much wider than configured the board's margin may be on each side (m):
        the high ends of the count and size tests allow a board that much larger (a print taped to a
        larger panel; users seldom know their margin to the centimetre; issue 38). 0.12 m: a
        configured margin 100 mm narrower than the board's lost 109 of 135 simulated frames without
        it, none with it.
    planarity_ratio: smallest PCA variance over the total must be below this, after removing the
        range noise's own contribution (``(noise_sigmas/2 * sigma)^2``).
    size_ratio: (lo, hi) of the segment's extent along its PCA axes over the board's sides
        (margin included; hi over the sides grown by twice ``margin_tolerance_m``).
    uniformity_min: ``1 - (n_max - n_min) / n_all`` over the four quadrants must reach this.
    contrast_min: the board's intensities must split in two levels at least this many pooled
        sigmas apart (our addition: a plain board-sized surface is not the chessboard); None: no
        contrast test (the search for a board whose print the LiDAR does not show).
    print_contrast_min: a board's intensities show a print (not only for the test above: to be
        fitted by its pattern rather than its outline) when their two levels are at least this
        many pooled sigmas apart, within each beam (a uniform spread of intensities, e.g. by the
        incidence angle, already splits 3.5 apart; printed boards split 5 to 30 apart).
    min_points, min_rings: fewest returns and scanlines a candidate may have (a few returns at long
        range pass the paper's tests by chance and cannot give corners anyway).
    ransac_threshold_m: plane inlier distance floor (grown with the noise estimate).
    max_planes: sets the RANSAC planes tried when splitting over-merged objects (wall behind,
        person): three times as many per object, six times as many for the whole scan.

    Corner fit (paper, Section 4.2)
    -------------------------------
    gray_epsilon: epsilon_g of the gray zone; 2 collapses it to the midpoint between the peaks.
    angle_step_deg, shift_step: coarse search grid of in-plane angle and translation (fraction of a
        square) that seeds Powell.
    n_starts: Powell starts taken from the best coarse cells.
    powell_xtol: Powell's tolerance, a fraction of the coarse grid's steps (angle, shift).
    projection: how returns are put on the board's plane: ``"ray"`` along each return's own ray
        (removes range noise and range biases from the in-plane positions; right for a real
        LiDAR) or ``"normal"`` orthogonally (right when the noise is along the board's normal).
    powell_max_points: Powell runs on at most this many of the board's returns, drawn at random
        (None: all); the soft-edged refinement that follows uses all of them.
    refine: run the soft-edged Gauss-Newton refinement (gives the in-plane covariance and the
        final pose); when False the Powell pose is returned with the refinement's covariance.
    max_fits: the chessboard is fitted to at most this many of each batch of candidates that pass
        the tests (best first, see choice.py; three batches' worth in all); the best fit wins.
    good_fit_score, min_fit_score: a fit scoring at least ``good_fit_score`` (choice.fit_score:
        colour agreement less the cost per return in squares) ends the search; fits below
        ``min_fit_score`` are refused.
    min_agreement: after the fit, the share of black/white returns (away from the edges) whose
        colour matches the fitted pattern must reach this, else BoardNotFound.
    covariance_inflation: multiplies the final covariance (1 = the derivation as documented).

    The board's outline (shape.py, outline.py)
    ------------------------------------------
    shape: what the outline's evidence does when the print shows: ``"fuse"`` checks the intensity
        fit against it and combines the two, ``"check"`` only checks, ``"off"`` ignores it. Without a
        visible print the outline is the in-plane evidence whatever this says.
    outline_blur: the blur of the board's edge as the beams see it, in footprint radii (a return
        straddling the edge is the board's or the background's depending on how much of the
        footprint each holds; its systematic part, the board looking larger or smaller, is the
        outline's growth, estimated). The simulator's edges are sharp (0 would be exact there); a
        real one's a little blurred; a board prior too optimistic is scaled up by the graph's
        variance components, a pessimistic one is not scaled down.
    shape_gate_p: the intensity fit and the outline disagree when the chi-square of their
        difference (3 dof) is beyond this quantile: the pattern slid; it is moved by whole squares
        (or half-turned) to where the outline allows, or the fit is refused.
    slide_squares: a disagreement beyond the gate is a slid fit only when it moves the board's
        corners by more than this many squares (less: a print off the centre of its backing, or
        covariances a few times too small; the two are then not combined, nothing is refused).
    min_shape_agreement: share of the samples near the outline (returns on the board's plane,
        rays passing it) the fitted board must explain, else it is not the board's outline.
    quarter_turn_score, quarter_turn_odds: without a visible print, a quarter-turned outline whose
        start scores at least ``quarter_turn_score`` of the best is fitted too, and the board is
        refused when neither is ``quarter_turn_odds`` times likelier.
    margin_search_m: where the print shows, each edge of the board's backing is sought up to this far
        beyond the configured margin (m; margin.py: the margin measured, per side).
    margin_contradiction_m: a margin measured on both sides of an axis contradicts the configured
        one when they differ by more than this (m) plus 3 sigma; the outline then checks the fit as
        the board measured (or not at all when an axis could not be measured).
    max_inplane_2sigma_squares: a fit whose in-plane uncertainty (2 sigma at the board's corners)
        exceeds this many squares is refused.
    """

    min_range_m: float = 0.3
    jump_ratio: float = 5.0
    link_ratio: float = 2.5
    noise_sigmas: float = 4.0
    min_links: int = 2
    count_ratio: tuple[float, float] = (0.5, 1.0)
    margin_tolerance_m: float = 0.12
    planarity_ratio: float = 0.01
    size_ratio: tuple[float, float] = (0.8, 1.6)
    uniformity_min: float = 0.85
    contrast_min: float | None = 3.0
    print_contrast_min: float = 5.0
    min_points: int = 30
    min_rings: int = 4
    ransac_threshold_m: float = 0.03
    max_planes: int = 6
    gray_epsilon: float = 2.0
    angle_step_deg: float = 3.0
    shift_step: float = 0.25
    n_starts: int = 2
    powell_xtol: float = 5e-3
    powell_max_points: int | None = 600
    projection: str = "ray"
    refine: bool = True
    max_fits: int = 4
    good_fit_score: float = 0.9
    min_fit_score: float = 0.5
    min_agreement: float = 0.8
    covariance_inflation: float = 1.0
    shape: str = "fuse"
    outline_blur: float = 0.1
    shape_gate_p: float = 0.999
    slide_squares: float = 0.5
    min_shape_agreement: float = 0.9
    quarter_turn_score: float = 0.85
    quarter_turn_odds: float = 20.0
    margin_search_m: float = 0.3
    margin_contradiction_m: float = 0.03
    max_inplane_2sigma_squares: float = 1.0


def breach(rule: str, value: float, op: str, limit: float, unit: str = "") -> str:
    """A refusal's figures, ``"(rule: value op limit unit)"``: the rule that refused (an option's name,
    or what it tests), the measured value and the limit it breaks (``op`` "<" or ">": refused because
    value < limit, or > limit). Printed with the fewest decimals (two or more) that keep the relation,
    so that the figures read make it a refusal (tests/test_lidar_refusals.py reads them so)."""
    if op not in ("<", ">") or any(c in rule for c in "():"):
        raise ValueError(f"breach: op must be '<' or '>' (not {op!r}), the rule without ( ) : ({rule!r})")
    v, lim = f"{value:.2f}", f"{limit:.2f}"
    for nd in range(2, 7):
        v, lim = f"{value:.{nd}f}", f"{limit:.{nd}f}"
        if np.isfinite(value) and ((float(v) < float(lim)) if op == "<" else (float(v) > float(lim))):
            break
    return f"({rule}: {v} {op} {lim}{' ' + unit if unit else ''})"
