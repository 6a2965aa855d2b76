"""Put a detected corner grid into the board's canonical order (``shared/interface.md``).

A detector returns the (rows-1) x (cols-1) grid in one of its symmetries (flips along either axis,
and transposes for a square grid). Two facts pick the canonical one, both read in a virtual pinhole
view (see ``views.py``) where the board is a plane seen by an ideal pinhole:

1. handedness, from geometry: the board frame's z = x × y points towards the camera, so with
   rays r_0, r_x, r_y through corners (0, 0), (0, last) and (last, 0),
   ``((r_x - r_0) × (r_y - r_0)) · r_0 < 0`` (rays scaled to depth 1, i.e. points on the view's
   normalised image plane, which preserves the sign of the triple product);
2. colour: the grey level at the centre of every square (through the homography from the board
   plane to the view) must correlate positively with the printed pattern, whose square (0, 0)
   has colour ``board.lower_left``. For a half-turn symmetric board the turned grid scores the same:
   either is returned and the result is flagged ambiguous.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..board import Board
from ..errors import BoardColourMismatch, CornersNotFound


@dataclass(frozen=True)
class Ordering:
    """Result of :func:`order_grid`.

    corners: (K, 2) view pixels in canonical order k = i*(cols-1) + j.
    half_turn_ambiguous: True when the half-turned order explains the image equally well.
    colour_score: correlation (-1..1) of square grey levels with the printed pattern.
    """

    corners: np.ndarray
    half_turn_ambiguous: bool
    colour_score: float


def _grid_symmetries(grid: np.ndarray) -> list[np.ndarray]:
    """All flips (and transposes when square) of a (n_i, n_j, 2) grid that keep its shape."""
    out = []
    bases = [grid] + ([grid.transpose(1, 0, 2)] if grid.shape[0] == grid.shape[1] else [])
    for g in bases:
        for fi in (1, -1):
            for fj in (1, -1):
                out.append(np.ascontiguousarray(g[::fi, ::fj]))
    return out


def _right_handed(g: np.ndarray, f: float, cx: float, cy: float) -> bool:
    """Board z (= x × y) points towards the pinhole for grid ``g`` (n_i, n_j, 2) of view pixels."""

    def ray(p: np.ndarray) -> np.ndarray:
        return np.array([(p[0] - cx) / f, (p[1] - cy) / f, 1.0])

    r0, rx, ry = ray(g[0, 0]), ray(g[0, -1]), ray(g[-1, 0])
    return float(np.cross(rx - r0, ry - r0) @ r0) < 0.0


def square_grey_levels(gray: np.ndarray, g: np.ndarray, board: Board) -> np.ndarray:
    """(rows, cols) mean grey level near each square's centre, grid ``g`` taken as canonical.

    Uses the homography from board-plane square units to the view fitted to the grid's corners.
    """
    n_i, n_j = g.shape[:2]
    jj, ii = np.meshgrid(np.arange(1, n_j + 1, dtype=np.float64), np.arange(1, n_i + 1, dtype=np.float64))
    src = np.stack([jj.ravel(), ii.ravel()], axis=1)
    H, _ = cv2.findHomography(src, g.reshape(-1, 2), 0)
    if H is None:
        raise CornersNotFound("corner grid is degenerate (no homography)")
    rr, cc = np.meshgrid(np.arange(board.rows), np.arange(board.cols), indexing="ij")
    offs = np.array([(dx, dy) for dx in (-0.2, 0.0, 0.2) for dy in (-0.2, 0.0, 0.2)])
    pts = np.stack([cc + 0.5, rr + 0.5], axis=-1)[:, :, None, :] + offs  # (rows, cols, 9, 2)
    view = cv2.perspectiveTransform(pts.reshape(1, -1, 2), H).reshape(-1, 2).astype(np.float32)
    vals = cv2.remap(gray, view[:, 0:1], view[:, 1:2], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return vals.reshape(board.rows, board.cols, 9).astype(np.float64).mean(axis=-1)


def order_grid(
    corners: np.ndarray,
    board: Board,
    gray: np.ndarray,
    f: float,
    cx: float,
    cy: float,
    strict_colour: bool = True,
) -> Ordering:
    """Canonical order of detector corners (K, 2) given row-major as (rows-1) x (cols-1) or transposed.

    Parameters
    ----------
    corners : (K, 2) view pixels as the detector returned them (row-major, cols-1 per row).
    board : the board.
    gray : (h, w) the view's grey image.
    f, cx, cy : the view's pinhole (view pixels).
    strict_colour : raise when the print's colours contradict ``board.lower_left`` (only possible for
        a board with an even number of squares on both sides); else return the best right-handed
        order, flagged ambiguous, with its negative ``colour_score``.

    Raises
    ------
    CornersNotFound when no symmetry of the grid is both right-handed and coloured like the print
    (with ``strict_colour``), or the grid is degenerate.
    """
    n_i, n_j = board.inner_shape
    grid = np.asarray(corners, dtype=np.float64).reshape(n_i, n_j, 2)
    expected = board.square_colour(*np.meshgrid(np.arange(board.rows), np.arange(board.cols), indexing="ij"))
    e = expected - expected.mean()
    scored = []
    for g in _grid_symmetries(grid):
        if not _right_handed(g, f, cx, cy):
            continue
        levels = square_grey_levels(gray, g, board)
        d = levels - levels.mean()
        denom = np.linalg.norm(d) * np.linalg.norm(e)
        scored.append((float(d.ravel() @ e.ravel() / denom) if denom > 0 else 0.0, g))
    if not scored:
        raise CornersNotFound("corner grid has no right-handed ordering (degenerate view)")
    scored.sort(key=lambda t: -t[0])
    best, g = scored[0]
    if best < 0.5:
        other = "white" if board.lower_left == "black" else "black"
        if best < -0.5 and board.half_turn_symmetric and board.rows % 2 == 0:
            if not strict_colour:
                return Ordering(g.reshape(-1, 2), True, best)
            raise BoardColourMismatch(
                f"the printed pattern's origin square (z towards the camera) is {other}, but the board "
                f"configuration says lower_left: {board.lower_left} (square colour correlation {best:.2f}); "
                f"set board.lower_left: {other}"
            )
        raise CornersNotFound(
            f"square colours do not match the printed pattern for any right-handed order "
            f"(best correlation {best:.2f}); wrong board size or a mirrored image?"
        )
    return Ordering(g.reshape(-1, 2), bool(board.half_turn_symmetric), best)
