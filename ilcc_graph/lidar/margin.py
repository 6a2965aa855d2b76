"""The board's white margin measured from the returns where the LiDAR shows the print (issue 38).

The print fixes the board's pose in its plane, so where each edge of its backing lies is a
measurement of the margin on that side: the rays about that edge (``shape.outline_samples``: returns
on the plane, rays that passed it) give a 1-D likelihood of the edge's place, the same soft-edged
occupancy ``shape.outline_loglik`` uses, evaluated on a grid (flat prior; the posterior is flat-topped
between two samples, so its mean and sigma are the grid's moments, not a curvature). A side whose
edge no ray brackets (beyond the beams, nothing behind it, a posterior wider than the search) has no
usable edge. The configured margin is contradicted when a whole axis (both of its sides measured)
differs from it by more than ``LidarOptions.margin_contradiction_m`` plus 3 sigma: the board is
larger or smaller, not its print off-centre or the pattern slid (those move one side in and the
other out). The outline then checks and sharpens the pattern's fit as the board measured, or,
when an axis could not be measured, not at all (:func:`outline_board`).

Board frame of the pose ``T`` (metres); sides in ``Board.extent`` order: x0, x1 (the long axis'
ends), y0, y1 (the short axis').
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import ndtr

from ..board import Board
from ..lidars import LidarModel
from .options import LidarOptions
from .shape import outline_samples

__all__ = ["SIDES", "MarginFit", "margin_summary", "margin_words", "measure_margin", "outline_board"]

SIDES = ("x0", "x1", "y0", "y1")
#: grid step of an edge's place (m)
STEP_M = 0.001
#: an edge is bracketed when a return on the board and a ray past it lie within this of it (m)
BRACKET_M = 0.1
#: an edge known to more than this (1 sigma, m) is no usable edge
MAX_SIGMA_M = 0.03


@dataclass(frozen=True)
class MarginFit:
    """The margin measured on each side of one board.

    sides, sigma: (4,) margin per side (x0, x1, y0, y1) and its sigma (m); NaN where the scan shows
    no usable edge. configured: (long, short) margins of config.yaml (m). tolerance: a measured axis
    within this (plus 3 sigma) of the configured one agrees with it (m).
    """

    sides: np.ndarray
    sigma: np.ndarray
    configured: tuple[float, float]
    tolerance: float

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """(2,) margins along the long and short axis (mean of their two sides) and their sigmas;
        NaN where either side has no usable edge."""
        m = 0.5 * (self.sides[[0, 2]] + self.sides[[1, 3]])
        s = 0.5 * np.hypot(self.sigma[[0, 2]], self.sigma[[1, 3]])
        return m, s

    @property
    def contradicted(self) -> np.ndarray:
        """(2,) bool: the long / short axis measured and beyond the configured margin's tolerance."""
        m, s = self.axes()
        with np.errstate(invalid="ignore"):
            return np.abs(m - np.asarray(self.configured)) > self.tolerance + 3.0 * s

    @property
    def contradicts(self) -> bool:
        """Either axis contradicts the configured margin."""
        return bool(self.contradicted.any())

    def board(self, board: Board) -> Board | None:
        """``board`` with the measured margins when both axes were measured, else None."""
        m, _ = self.axes()
        if not np.all(np.isfinite(m)):
            return None
        return replace(board, margin_long=float(max(m[0], 0.0)), margin_short=float(max(m[1], 0.0)))

    def diagnostics(self) -> dict[str, float]:
        """``BoardFit.diagnostics`` entries (mm; only the sides and axes measured):
        ``margin_<side>_mm``, ``margin_long_mm``, ``margin_short_mm`` (with ``sigma_margin_*_mm``),
        ``margin_contradicted`` (1 or 0)."""
        out: dict[str, float] = {}
        for k, side in enumerate(SIDES):
            if np.isfinite(self.sides[k]):
                out[f"margin_{side}_mm"] = 1e3 * float(self.sides[k])
        m, s = self.axes()
        for k, axis in enumerate(("long", "short")):
            if np.isfinite(m[k]):
                out[f"margin_{axis}_mm"] = 1e3 * float(m[k])
                out[f"sigma_margin_{axis}_mm"] = 1e3 * float(s[k])
        out["margin_contradicted"] = float(self.contradicts)
        return out


def _edge(x: np.ndarray, sd: np.ndarray, inside: np.ndarray, eps: np.ndarray,
          grid: np.ndarray) -> tuple[float, float]:  # fmt: skip
    """The margin m (grid (G,), m) of one side from the samples' distances x (N,) beyond the pattern's
    edge (positive outward, m), their sigmas, whether each returned from the board and their
    ``eps``: (mean, sigma) of the flat-prior posterior, NaN when no usable edge."""
    if not inside.any() or inside.all():
        return np.nan, np.nan
    z = (grid[:, None] - x[None, :]) / sd[None, :]  # > 0: the sample lies inside the board
    p = ndtr(np.where(inside[None, :], z, -z))
    ll = np.log(eps + (1.0 - eps) * p).sum(axis=1)
    w = np.exp(ll - ll.max())
    w /= w.sum()
    mean = float(w @ grid)
    sigma = float(np.sqrt(max(w @ (grid - mean) ** 2, 0.0)))
    bracketed = (inside & (x > mean - BRACKET_M) & (x <= mean)).any() and (
        ~inside & (x < mean + BRACKET_M) & (x >= mean)
    ).any()
    at_end = mean + 2.0 * sigma > grid[-1]
    if not bracketed or at_end or sigma > MAX_SIGMA_M:
        return np.nan, np.nan
    return mean, sigma


def measure_margin(
    points: np.ndarray, T: np.ndarray, cov: np.ndarray, board: Board, model: LidarModel, s_z: float,
    options: LidarOptions,
) -> MarginFit:  # fmt: skip
    """The margin on each side of the board at ``T`` (4, 4; its pattern placed by the print) from the
    scan's points (N, 3), LiDAR frame. cov: (3, 3) covariance of the pose's in-plane correction
    (rz, tx, ty), added to each side's sigma; s_z: the returns' noise along the normal (m)."""
    reach = options.margin_search_m
    s = outline_samples(points, T, board, model, s_z, options.outline_blur, grow=reach + 0.05)
    w, h = board.cols * board.square_size, board.rows * board.square_size
    cfg = (board.margin_long, board.margin_short)
    sides, sig = np.full(4, np.nan), np.full(4, np.nan)
    half = 0.5 * np.hypot(w, h)
    for k in range(4):
        a = k // 2  # the edge's own axis: 0 for the x sides, 1 for the y sides
        length, span = (w, h) if a == 0 else (h, w)  # the pattern along that axis, and along the edge
        c, o = s.b[:, a], s.b[:, 1 - a]
        beyond = -c if k % 2 == 0 else c - length  # distance past the pattern's edge (outward)
        near = (o > 0.0) & (o < span) & (beyond > -0.5 * length)
        grid = np.arange(-0.02, cfg[a] + reach + STEP_M / 2, STEP_M)
        m, sd = _edge(beyond[near], s.sigma[near, a], s.inside[near], s.eps[near], grid)
        sides[k] = m
        sig[k] = np.sqrt(sd**2 + cov[1 + a, 1 + a] + half**2 * cov[0, 0]) if np.isfinite(sd) else np.nan
    return MarginFit(sides, sig, cfg, options.margin_contradiction_m)


def outline_board(
    points: np.ndarray, T: np.ndarray, cov: np.ndarray, board: Board, model: LidarModel, s_z: float,
    options: LidarOptions,
) -> tuple[Board | None, dict[str, float]]:  # fmt: skip
    """The board the outline checks a print-visible fit against, and the margin's diagnostics: the
    configured board when the scan agrees with its margin (or cannot tell), the board as measured
    when it contradicts it on an axis and both axes were measured, None (the outline left out: it
    would pull the fit the print determines) when it contradicts it and an axis could not be measured."""
    fit = measure_margin(points, T, cov, board, model, s_z, options)
    diag = fit.diagnostics()
    if not fit.contradicts:
        return board, diag
    measured = fit.board(board)
    diag["margin_outline_dropped"] = float(measured is None)
    return measured, diag


def margin_summary(diagnostics: Sequence[Mapping[str, float]], board: Board) -> dict[str, float]:
    """A run's margin as its boards measured it, when it contradicts the configured one: the boards
    whose margin was measured on an axis and those that contradict ``board``'s
    (``lidar_margin_boards``, ``lidar_margin_contradicted_boards``), the median margin per axis
    (``lidar_margin_long_mm``, ``lidar_margin_short_mm``, where measured) and the configured one
    (``lidar_margin_configured_long_mm``, ``..._short_mm``); {} when at most half of the boards
    measured contradict it (or none was measured)."""
    measured = [d for d in diagnostics if "margin_long_mm" in d or "margin_short_mm" in d]
    bad = sum(1 for d in measured if d.get("margin_contradicted"))
    if not measured or 2 * bad <= len(measured):
        return {}
    out = {"lidar_margin_boards": float(len(measured)), "lidar_margin_contradicted_boards": float(bad)}
    for axis, cfg in (("long", board.margin_long), ("short", board.margin_short)):
        v = [d[f"margin_{axis}_mm"] for d in measured if f"margin_{axis}_mm" in d]
        if v:
            out[f"lidar_margin_{axis}_mm"] = float(np.median(v))
        out[f"lidar_margin_configured_{axis}_mm"] = 1e3 * float(cfg)
    return out


def margin_words(summary: Mapping[str, float], file: str = "config.yaml") -> str:
    """The measured margin against the configured one in words (``margin_summary``'s figures; the
    margin to set in ``file``); "" without a contradiction."""
    if not summary.get("lidar_margin_contradicted_boards"):
        return ""
    said = [summary[f"lidar_margin_configured_{a}_mm"] for a in ("long", "short")]
    got = [summary.get(f"lidar_margin_{a}_mm", s) for a, s in zip(("long", "short"), said, strict=True)]
    axes = " and ".join(
        f"{summary[f'lidar_margin_{a}_mm']:.0f} mm at the ends of the {a} side (config: {s:.0f})"
        for a, s in zip(("long", "short"), said, strict=True) if f"lidar_margin_{a}_mm" in summary
    )  # fmt: skip
    return (
        f"the board's white margin the LiDAR measured is {axes}, the median of "
        f"{summary['lidar_margin_boards']:.0f} boards ({summary['lidar_margin_contradicted_boards']:.0f} "
        f"contradict board.margin): the boards' outlines were taken as measured; set board.margin: "
        f"[{1e-3 * got[0]:.3f}, {1e-3 * got[1]:.3f}] in {file} if the board is as measured"
    )
