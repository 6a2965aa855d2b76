"""Is a detected corner grid the whole printed pattern? (issue 38: boards partly outside the image)

A detector asked for the configured (rows-1) x (cols-1) inner corners may return a grid of that
size that is only part of a larger checker pattern: a print with more squares than
``board.squares`` says, or a larger print whose outer squares leave the picture. Its corners would
be used with their indices shifted by a square or more, silently. A plain chessboard does not
number its corners, so such a grid cannot be indexed right; it is refused instead.

A whole pattern shows, beyond each outer row (column) of its inner corners, its border squares
(ring 0: in the picture, each the other colour than its inner neighbour) and beyond those no more
checker squares (ring 1: the margin or the background). Each side of the grid is checked in the
source image: the grey level of a square is the median of five samples (its centre and +-0.25
square along both axes), placed through the homography from the board plane to the fine view
fitted to the three rows (columns) of corners nearest that side, then through ``camera.project``
(so fisheye and panoramic images are read where the pixels are; a sample off the picture counts
as unseen). A side is refused when

0. the pattern continues: at half or more of the points where the next row of corners would be
   (between two neighbouring squares of ring 1, all four squares around it seen), the four squares
   form the pattern's saddle: the two diagonal pairs each of one level (within a quarter of the
   contrast; each ring-1 square as uniform as the border squares, the print's own, give or take a
   quarter of the contrast) and half the contrast or more apart, with the pattern's signs. A
   larger print does at every point; none of the 148 sides of the 37 recorded boards (margins, a
   striped shutter and a street behind them) has a single such point;
1. a border square has a sample off the picture (the squares that would tell are not all seen);
2. fewer than half of the ring-1 squares are (too little seen to show the pattern stops);
3. no ring-1 square differs from the colour the pattern would have there by half the contrast
   against its border neighbour (nothing shows the pattern stops: blurred squares of a few pixels
   can hide a larger print's corners from the test in 0.; a margin or a background differs at
   about half of them, at least one in 6 on every side of the recorded boards);
4. fewer than 3/4 of the border squares are the other colour than their inner neighbours by half
   the contrast (occluded, glare).

The contrast is the side's own: the median grey-level step between neighbouring squares of its
first inner row, whose colours (which of the two is the lighter) are read from the image, so the
grid's order and ``lower_left`` are not needed and a dark, shaded or low-contrast board is judged
as a bright one. About 5 ms per grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..board import Board
from ..cameras import CameraModel
from .views import VirtualView, wrap_image_u

__all__ = ["SideCheck", "WholeCheck", "check_whole_pattern"]

#: offsets (square units) of the points sampled in each square, around its centre
_OFFSETS = np.array([(0.0, 0.0), (0.25, 0.0), (-0.25, 0.0), (0.0, 0.25), (0.0, -0.25)])
STEP = 0.5  #: a grey-level step counts when it is at least this fraction of the side's contrast
MIN_CONTRAST = 3.0  #: grey levels: a side with less contrast is judged as if it had this much
SAME = 0.25  #: squares of one colour differ by less than this fraction of the contrast (and within one)
SPREAD = 0.25  #: a square beyond is uniform: its samples' range within this (x contrast) of the print's
BORDER_MIN = 0.75  #: fraction of the border squares that must show the border's colours
CONTINUES = 0.5  #: fraction of the judged points beyond the border that, as saddles, say "continues"
SEEN_MIN = 0.5  #: fraction of the squares beyond the border that must be in the picture


@dataclass(frozen=True)
class SideCheck:
    """One side of the grid as the image shows it.

    name: where the side lies in the (upright) fine view: "top row", "bottom row", "left column" or
    "right column". n: squares along it. border_in: border squares (ring 0) with all five samples
    in the picture; border_match: of those, the ones of the border's colour. beyond_in: squares
    one further out (ring 1) in the picture; beyond_breaking: of those, the ones not of the colour
    the pattern would have there. corners_judged: the points between two neighbouring squares
    beyond the border where the pattern's next row of corners would be, all four squares around
    them in the picture; corners_beyond: of those, the ones where the four squares form the
    pattern's saddle (two diagonal pairs, each of one level, the pair beyond the border square of
    the pattern's colour at least half the contrast apart). contrast: the side's grey-level step
    between neighbouring squares (grey levels).
    """

    name: str
    n: int
    border_in: int
    border_match: int
    beyond_in: int
    beyond_breaking: int
    corners_judged: int
    corners_beyond: int
    contrast: float

    def problem(self, board: Board) -> tuple[int, str] | None:
        """(priority, reason) when this side does not show the pattern ending here; lower first."""
        n, where = self.n, f"beyond its {self.name}"
        if self.corners_beyond >= 1 and self.corners_beyond >= CONTINUES * self.corners_judged:
            return 0, (
                f"the detected grid is not the whole pattern: the pattern continues {where} (its "
                f"corners one square further out: {self.corners_beyond} of {self.corners_judged} "
                f"points; a larger print than board.squares [{board.rows}, {board.cols}]?)"
            )
        if self.border_in < n:
            return 1, (
                f"the detected grid is not provably the whole pattern: the squares {where} run out of "
                f"the image ({n - self.border_in} of {n} outside)"
            )
        if self.beyond_in < SEEN_MIN * n:
            return 2, (
                f"the detected grid is not provably the whole pattern: {where} the image ends within "
                f"a square of the pattern's edge ({n - self.beyond_in} of the {n} squares one further "
                "out outside), too close to show that the pattern stops there"
            )
        if self.beyond_breaking == 0:
            return 3, (
                f"the detected grid is not provably the whole pattern: {where} the squares one further "
                f"out have the pattern's colours (none of {self.beyond_in} differs), though its corners "
                "there are not clear (blurred or small squares?)"
            )
        if self.border_match < BORDER_MIN * n:
            return 4, (
                f"the detected grid is not provably the whole pattern: the squares {where} do not "
                f"show the pattern's border ({self.border_match} of {n} of the expected colour, "
                f"contrast {self.contrast:.0f} grey levels; occluded or in glare?)"
            )
        return None


@dataclass(frozen=True)
class WholeCheck:
    """The four sides' checks and the first reason to refuse the grid (None: the whole pattern);
    continues: the reason is that the checker pattern goes on beyond a side."""

    sides: tuple[SideCheck, ...]
    reason: str | None
    continues: bool

    @property
    def alternating_beyond(self) -> float:
        """The largest fraction of a side's points one square beyond it that are the pattern's corners."""
        return max((s.corners_beyond / s.corners_judged if s.corners_judged else 0.0) for s in self.sides)

    @property
    def border_matching(self) -> float:
        """The smallest fraction of a side's border squares of the border's colour (0..1)."""
        return min(s.border_match / s.n for s in self.sides)


def _phase(levels: np.ndarray) -> np.ndarray:
    """+1 / -1 per square of a row of alternating squares: which of the two colours is the lighter
    as the grey levels say (NaN levels left out); the grid's order and ``lower_left`` are not needed."""
    sign = np.where(np.arange(len(levels)) % 2 == 0, 1.0, -1.0)
    return sign * (1.0 if np.nansum(sign * levels) >= 0 else -1.0)


def _levels(
    gray: np.ndarray, camera: CameraModel, view: VirtualView, H: np.ndarray, rc: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(median grey level, spread, wholly in the picture) of the squares rc (N, 2) as (row, col).

    The level is the median of the square's five samples, its spread their range (NaN outside).

    H maps board square units (x along the columns, y along the rows; corner (i, j) at (j+1, i+1))
    to view pixels; the view's rays go through ``camera.project`` into the source image ``gray``.
    """
    centres = rc[:, ::-1].astype(np.float64) + 0.5
    pts = (centres[:, None, :] + _OFFSETS[None]).reshape(1, -1, 2)
    xy = cv2.perspectiveTransform(pts, H).reshape(-1, 2)
    uv = wrap_image_u(camera, camera.project(view.rays(xy)))
    ok = np.all(np.isfinite(uv), axis=1)
    ok[ok] = camera.in_image(uv[ok])
    grey = np.full(len(uv), np.nan)
    if ok.any():
        m = uv[ok].astype(np.float32)
        grey[ok] = cv2.remap(
            gray, m[:, :1], m[:, 1:], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        ).ravel()
    inside = ok.reshape(len(rc), -1).all(axis=1)
    per = grey.reshape(len(rc), -1)
    level = np.where(inside, np.median(per, axis=1), np.nan)
    spread = np.where(inside, np.ptp(np.where(np.isfinite(per), per, 0.0), axis=1), np.nan)
    return level, spread, inside


def _side_name(H: np.ndarray, inner: np.ndarray, beyond: np.ndarray) -> str:
    """Where the side lies in the view: the direction from its inner row's middle to ring 1's."""
    mid = np.stack([inner.mean(axis=0), beyond.mean(axis=0)])[:, ::-1] + 0.5
    a, b = cv2.perspectiveTransform(mid.reshape(1, -1, 2), H).reshape(2, 2)
    dx, dy = b - a
    if abs(dx) > abs(dy):
        return "right column" if dx > 0 else "left column"
    return "bottom row" if dy > 0 else "top row"


def _check_side(
    gray: np.ndarray,
    camera: CameraModel,
    view: VirtualView,
    grid: np.ndarray,
    board: Board,
    side: tuple[int, int],
) -> SideCheck:
    """One side: ``side`` = (axis, end), axis 0 the rows (y) and 1 the columns (x), end 0 or -1.

    grid: (rows-1, cols-1, 2) corners in view pixels (any of the grid's symmetries).
    """
    axis, end = side
    g = grid if axis == 0 else grid.transpose(1, 0, 2)  # rows of g run along the side
    n_out = (board.rows, board.cols)[axis]  # squares across the side, ring 0 at 0 or n_out-1
    n = (board.cols, board.rows)[axis]  # squares along it
    k = min(3, g.shape[0])
    rows = np.arange(k) if end == 0 else np.arange(g.shape[0] - k, g.shape[0])
    ii, jj = np.meshgrid(rows, np.arange(g.shape[1]), indexing="ij")
    src = np.stack([jj.ravel() + 1.0, ii.ravel() + 1.0], axis=1)  # (along, across) square units
    if axis == 1:
        src = src[:, ::-1]
    H: np.ndarray | None = cv2.findHomography(src, g[rows].reshape(-1, 2), 0)[0]  # None: degenerate
    if H is None:  # not after the fine pass's plane fit; judged as a side the picture does not show
        return SideCheck("edge", n, 0, 0, 0, 0, 0, 0, 0.0)
    step = 1 if end == 0 else -1
    ring0 = 0 if end == 0 else n_out - 1
    along = np.arange(n)

    def squares(across: int) -> np.ndarray:
        rc = np.stack([np.full(n, across), along], axis=1)
        return rc if axis == 0 else rc[:, ::-1]

    inner, border, beyond = squares(ring0 + step), squares(ring0), squares(ring0 - step)
    (li, _, in_i), (l0, d0, in0), (l1, d1, in1) = (
        _levels(gray, camera, view, H, q) for q in (inner, border, beyond)
    )
    si = _phase(li)  # +1 where the inner row's square is the lighter colour
    s1 = si  # the checker pattern one square beyond the border: the inner row's colours again
    with np.errstate(invalid="ignore"):
        steps = si[:-1] * (li[:-1] - li[1:])
        contrast = float(np.nanmedian(steps)) if np.isfinite(steps).any() else 0.0
        t = STEP * max(contrast, MIN_CONTRAST)
        match = (-si * (l0 - li) > t) & in0 & in_i  # the border square: the inner one's opposite
        a, b = s1[:-1], s1[1:]  # a square beyond the border and its neighbour along the side
        opposite = (a * (l1[:-1] - l0[:-1]) > t) & (b * (l1[1:] - l0[1:]) > t) & (a * (l1[:-1] - l1[1:]) > t)
        u = SAME * max(contrast, MIN_CONTRAST)  # a printed square: one level, the pattern's
        own = float(np.nanmedian(d0)) if in0.any() else 0.0  # the print's own squares' spread here
        v = SPREAD * max(contrast, MIN_CONTRAST) + own
        same = (np.abs(l1[:-1] - l0[1:]) < u) & (np.abs(l1[1:] - l0[:-1]) < u) & (d1[:-1] < v) & (d1[1:] < v)
        breaks = (s1 * (l1 - l0) < t) & in1 & in0  # one square further out, not the pattern's colour
    judged = in1[:-1] & in1[1:] & in0[:-1] & in0[1:]
    alternating = judged & opposite & same  # a saddle: the pattern's corner one row further out
    return SideCheck(
        name=_side_name(H, inner, beyond),
        n=n,
        border_in=int(in0.sum()),
        border_match=int(match.sum()),
        beyond_in=int(in1.sum()),
        beyond_breaking=int(breaks.sum()),
        corners_judged=int(judged.sum()),
        corners_beyond=int(alternating.sum()),
        contrast=contrast,
    )


def check_whole_pattern(
    gray: np.ndarray, camera: CameraModel, view: VirtualView, corners: np.ndarray, board: Board
) -> WholeCheck:
    """Whether the grid ``corners`` is the whole printed pattern.

    gray: (H, W) uint8 the source image; view: the fine view the corners are in; corners: (K, 2)
    view pixels, row-major (rows-1) x (cols-1) in any of the grid's symmetries (a detector's).
    """
    grid = np.asarray(corners, dtype=np.float64).reshape(*board.inner_shape, 2)
    sides = tuple(
        _check_side(gray, camera, view, grid, board, side) for side in ((0, 0), (0, -1), (1, 0), (1, -1))
    )
    found = [p for p in (s.problem(board) for s in sides) if p is not None]
    first = min(found) if found else None
    return WholeCheck(sides, first[1] if first else None, first is not None and first[0] == 0)
