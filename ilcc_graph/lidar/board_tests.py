"""The paper's board tests on a candidate (Wang et al. 2017, 4.1), the contrast test, the fit's colour check.

See detection.py for the list; every intensity rule here is scale-free (measured on the candidate).
"""

from __future__ import annotations

from typing import overload

import numpy as np

from ..board import Board
from ..errors import BoardNotFound
from ..lidars import LidarModel
from .options import LidarOptions, breach

__all__ = [
    "PrintUnreadable",
    "board_tests",
    "colour_agreement",
    "intensity_contrast",
    "local_elevation_step",
    "print_visible",
]


@overload
def local_elevation_step(model: LidarModel, elevation: float) -> float: ...
@overload
def local_elevation_step(model: LidarModel, elevation: np.ndarray) -> np.ndarray: ...
def local_elevation_step(model: LidarModel, elevation: float | np.ndarray) -> float | np.ndarray:
    """Ring spacing (rad) of the model's beam table at an elevation (rad), scalar or array."""
    el = model.vertical_angles_rad
    if el.size < 2:
        return np.deg2rad(2.0) + 0.0 * np.asarray(elevation)
    mids = 0.5 * (el[1:] + el[:-1])
    gaps = np.diff(el)
    out = np.interp(elevation, mids, gaps)
    return float(out) if np.ndim(out) == 0 else out


def intensity_contrast(intensity: np.ndarray) -> tuple[float, float]:
    """Two-level contrast of intensities (M,): (separation d', smaller class fraction).

    Otsu's split into two classes; d' = (mean_high - mean_low) / pooled within-class sigma.
    A printed chessboard gives d' > 4 with both classes near half; a plain surface gives d' < 3.
    Both numbers are unchanged by any gain and offset of the intensity (scale-free); values beyond
    the 2-98 % quantiles are clipped to them first, so a few saturated returns (retro-reflective
    tape) do not make a class of their own.
    """
    r = np.asarray(intensity, dtype=np.float64)
    if r.size >= 4:
        r = np.clip(r, *np.quantile(r, [0.02, 0.98]))
    r = np.sort(r)
    m = r.size
    if m < 4 or r[-1] == r[0]:
        return 0.0, 0.0
    c = np.cumsum(r - r[0])
    k = np.arange(1, m)
    m0, m1 = c[:-1] / k, (c[-1] - c[:-1]) / (m - k)
    between = k * (m - k) * (m1 - m0) ** 2
    j = int(np.argmax(between))
    lo, hi = r[: j + 1], r[j + 1 :]
    pooled = np.sqrt((lo.var() * lo.size + hi.var() * hi.size) / m)
    spread = r[-1] - r[0]
    return float((hi.mean() - lo.mean()) / max(pooled, 1e-9 * spread)), float(min(lo.size, hi.size) / m)


class PrintUnreadable(BoardNotFound):
    """A board whose returns show a print, but too few of them lie clear of the squares' edges to
    tell whether a fitted pattern is right (scanlines along the rows' edges): its outline may place it."""


def _clear_of_lines(b: np.ndarray, board: Board, clear: float) -> np.ndarray:
    """(N,) bool: board-frame points ``b`` (N, 2, m) more than ``clear`` squares from every grid line
    of the pattern (a footprint there does not straddle two squares)."""
    u = b / board.square_size
    return np.asarray((np.abs(u - np.round(u)) > clear).all(axis=1), dtype=bool)


def colour_agreement(
    b: np.ndarray, cls: np.ndarray, board: Board, blur: float, dist: float, min_agreement: float
) -> float:
    """The share of black/white returns whose colour the fitted pattern has under them: returns ``b``
    (N, 2, board frame, m) of intensity class ``cls`` (N,: 0 black, 1 white, -1 gray), counted away
    from the edges, where footprints straddle both (0.15 squares; when fewer than 20 returns lie
    there, scanlines along the rows' edges, twice the footprint ``blur`` (m), at least 0.05 squares).
    PrintUnreadable when fewer than 20 are clear of the edges even so, BoardNotFound when the share is
    below ``min_agreement``; ``dist``: the object's range (m), for the message."""
    colour = board.colour_at(b)
    usable = (cls >= 0) & np.isfinite(colour)
    inner = _clear_of_lines(b, board, 0.15) & usable
    if inner.sum() < 20:
        clear = max(2.0 * blur, 0.05 * board.square_size)  # (m) beyond the footprint's straddle
        inner = _clear_of_lines(b, board, clear / board.square_size) & usable
        if inner.sum() < 20:
            raise PrintUnreadable(
                f"a board-shaped object at {dist:.2f} m, but only {int(inner.sum())} of its returns lie "
                f"more than {1e3 * clear:.0f} mm from the squares' edges: too few to tell whether the fitted "
                "chessboard explains its black/white returns (scanlines along the edges?) "
                + breach("returns clear of the edges", float(inner.sum()), "<", 20.0)
            )
    agree = float(np.mean(cls[inner] == colour[inner]))
    if agree < min_agreement:
        raise BoardNotFound(
            f"a board-shaped object at {dist:.2f} m, but the fitted chessboard explains only {agree:.0%} of "
            "its black/white returns " + breach("min_agreement", agree, "<", min_agreement)
        )
    return agree


def print_visible(
    intensity: np.ndarray, points: np.ndarray, contrast_min: float, ring: np.ndarray | None = None
) -> tuple[bool, str]:
    """Whether a board's returns (intensities (M,), points (M, 3) LiDAR frame, beam index (M,)) show
    a two-tone print, and if not, why: Otsu's two levels at least ``contrast_min`` pooled sigmas apart
    with both holding 10 % (``intensity_contrast``), and intensities that do not follow the beams
    (the elevation: a ring number written as intensity; or each beam's own level: uneven per-laser
    intensity calibration splits a plain board into "levels" by beam, a print splits every beam)."""
    r = np.asarray(intensity, dtype=np.float64)
    ok = np.isfinite(r)
    if ok.sum() < 10:
        return False, "no finite intensity on the board"
    sep, frac = intensity_contrast(r[ok])
    if sep < contrast_min or frac < 0.1:
        return False, f"no black/white contrast in the intensity (d'={sep:.1f}, {frac:.0%})"
    p = np.asarray(points, dtype=np.float64)[ok]
    el = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))
    if np.ptp(el) > 0:
        corr = float(np.corrcoef(r[ok], el)[0, 1])
        if abs(corr) > 0.9:
            return (
                False,
                f"the intensity follows the beams' elevation (correlation {corr:+.2f}): no print in it",
            )
    if ring is not None:
        _, g = np.unique(np.asarray(ring)[ok], return_inverse=True)
        x = r[ok] - r[ok].mean()
        n = np.bincount(g)
        between = float((np.bincount(g, x) ** 2 / n).sum())
        if between > 0.7 * float((x * x).sum()):
            return False, "the intensity differs by beam, not across each beam: no print in it"
    return True, ""


def _count_breach(ratio: float, lo: float, hi: float) -> str:
    """The count test's figures: below ``count_ratio``'s low end or above its widened high end."""
    if ratio < lo:
        return breach("count_ratio", ratio, "<", lo)
    return breach("count_ratio, widened by a ring, a column and margin_tolerance_m", ratio, ">", hi)


def _count_test(
    m: int, sides: tuple[float, float], dist: float, steps: tuple[float, float], grow: float,
    options: LidarOptions,
) -> str | None:  # fmt: skip
    """Why ``m`` returns at ``dist`` (m) fail the count test for a board of ``sides`` (m, margin
    included; grown by ``grow`` for the high end) under the beams' ``steps`` (azimuth, elevation,
    rad), or None when they pass."""
    (long_side, short_side), (step_az, step_el) = sides, steps
    area = long_side * short_side
    n_theory = area / (dist**2 * step_az * step_el)
    grown = (long_side + grow) * (short_side + grow) / area
    quantised = (1 + dist * step_el / short_side) * (1 + dist * step_az / short_side)
    hi = options.count_ratio[1] * grown * quantised
    ratio = m / n_theory
    if options.count_ratio[0] <= ratio <= hi:
        return None
    rule = _count_breach(ratio, options.count_ratio[0], hi)
    return f"{m} points, {ratio:.2f} x the {n_theory:.0f} expected at {dist:.2f} m {rule}"


def _size_breaches(
    ext: np.ndarray, sides: tuple[float, float], ratio: tuple[float, float], slack: float, grow: float = 0.0
) -> list[str]:
    """The size test's figures: each extent (long, short) below ``size_ratio``'s low end (less a ring
    spacing ``slack``) or above its high end, times the board's side (grown by ``grow``: a margin
    wider than configured)."""
    out = []
    for e, name, side in zip(ext, ("long side", "short side"), sides, strict=True):
        lo, hi = ratio[0] * side - slack, ratio[1] * (side + grow)
        if e < lo or e > hi:
            out.append(breach(f"size_ratio, {name}", e, "<" if e < lo else ">", lo if e < lo else hi, "m"))
    return out


def board_tests(
    p: np.ndarray,
    board: Board,
    model: LidarModel,
    sigma: float,
    options: LidarOptions,
    intensity: np.ndarray | None = None,
    solid_angle: np.ndarray | None = None,
) -> tuple[bool, float, str, str]:
    """The paper's tests on one candidate's points p (M, 3) (and intensities (M,), when given).

    solid_angle: optional (M,) steradians each return stands for (a scanline-free pattern: one over
    its local density); None: the beam model's azimuth step times the local ring spacing.
    Returns (passed, uniformity, failed test name or "", human-readable detail).
    """
    x0, x1, y0, y1 = board.extent()
    long_side, short_side = x1 - x0, y1 - y0
    m = p.shape[0]
    mu = p.mean(axis=0)
    dist = float(np.linalg.norm(mu))
    step_az = np.deg2rad(model.horizontal_resolution_deg)
    # local ring spacing at each return: beam tables need not be uniform (vlp32c, hdl64)
    r_i = np.linalg.norm(p, axis=1)
    el_i = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))
    step_el_i = local_elevation_step(model, el_i)
    step_el = float(np.mean(step_el_i))
    tol = 2.0 * options.margin_tolerance_m  # the board may be larger than configured by this per side
    if (why := _count_test(m, (long_side, short_side), dist, (step_az, step_el), tol, options)) is not None:
        return False, 0.0, "count", why
    # every return stands for the board area r^2 d_az d_el / cos(incidence); weighing by it makes
    # the PCA and the quadrant counts follow the board, not where the beams are dense (a board
    # tilted at close range, a table denser near the horizon)
    w0 = r_i**2 * (step_el_i if solid_angle is None else np.asarray(solid_angle, np.float64))
    mu_w = (w0[:, None] * p).sum(axis=0) / w0.sum()
    q = p - mu_w
    cov = (w0[:, None] * q).T @ q / w0.sum()
    w, v = np.linalg.eigh(cov)
    cos_i = np.abs(p @ v[:, 0]) / np.maximum(r_i, 1e-9)
    w_i = w0 / np.maximum(cos_i, 0.2)
    noise_share = (0.5 * options.noise_sigmas * sigma) ** 2
    planar = (w[0] - noise_share) / w.sum()
    if planar > options.planarity_ratio:
        return (
            False, 0.0, "planarity",
            f"not flat at {dist:.2f} m (PCA ratio {w[0] / w.sum():.4f}, less the range noise's share) "
            + breach("planarity_ratio", planar, ">", options.planarity_ratio),
        )  # fmt: skip
    uv = q @ v[:, [2, 1]]
    lo, hi_ = np.quantile(uv, 0.01, axis=0), np.quantile(uv, 0.99, axis=0)
    ext = (hi_ - lo) * m / max(m - 1, 1)
    # (less a ring spacing: the scan can miss a corner's tip between two rings)
    if bad := _size_breaches(ext, (long_side, short_side), options.size_ratio, dist * step_el, tol):
        sizes = f"{ext[0]:.2f} x {ext[1]:.2f} m at {dist:.2f} m, board {long_side:.2f} x {short_side:.2f} m"
        return False, 0.0, "size", f"{sizes} {' '.join(bad)}"
    mid = 0.5 * (lo + hi_)
    quad = (uv[:, 0] >= mid[0]).astype(int) * 2 + (uv[:, 1] >= mid[1]).astype(int)
    nq = np.bincount(quad, weights=w_i, minlength=4)
    uniformity = 1.0 - (nq.max() - nq.min()) / nq.sum()
    if uniformity < options.uniformity_min:
        return (
            False,
            uniformity,
            "uniformity",
            f"uneven, {ext[0]:.2f} x {ext[1]:.2f} m at {dist:.2f} m "
            + breach("uniformity_min", uniformity, "<", options.uniformity_min),
        )
    if intensity is not None and options.contrast_min is not None:
        sep, frac = intensity_contrast(intensity)
        if sep < options.contrast_min or frac < 0.1:
            return (
                False, uniformity, "contrast",
                f"board-shaped at {dist:.2f} m but no black/white contrast "
                + (breach("contrast_min, d'", sep, "<", options.contrast_min) if sep < options.contrast_min
                   else breach("share of the smaller level", frac, "<", 0.1)),
            )  # fmt: skip
    return True, float(uniformity), "", f"{m} points at {dist:.2f} m"
