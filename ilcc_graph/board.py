"""Chessboard geometry and colours in the board frame (``shared/interface.md``, "The chessboard").

Board frame: x along the long side, y along the short side, z = x × y out of the printed face;
origin at the pattern's outer corner whose square has colour ``lower_left``. Square (r, c) covers
``x in [c*s, (c+1)*s]``, ``y in [r*s, (r+1)*s]`` and has colour ``lower_left`` when ``r + c`` is even.
The white margin extends x by ``margin_long`` and y by ``margin_short`` at both ends.
Colours are numbers: 0.0 black, 1.0 white, NaN off the board. Lengths are metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

BLACK = 0.0
WHITE = 1.0
_COLOUR_VALUE = {"black": BLACK, "white": WHITE}


@dataclass(frozen=True)
class Board:
    """A printed chessboard.

    Parameters
    ----------
    rows, cols : squares along the short and long side (ILCC's ``pattern_size``), each >= 2.
    square_size : edge of one square, metres, > 0.
    margin_long, margin_short : white border beyond the pattern at both ends of the long (x) and
        short (y) side, metres, >= 0.
    lower_left : ``"black"`` or ``"white"``, the colour of the square at the board-frame origin.
    """

    rows: int
    cols: int
    square_size: float
    margin_long: float = 0.0
    margin_short: float = 0.0
    lower_left: str = "black"

    def __post_init__(self) -> None:
        for name in ("rows", "cols"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 2:
                raise ValueError(f"Board: {name} must be an integer >= 2, got {value!r}")
            object.__setattr__(self, name, int(value))
        if self.rows > self.cols:
            raise ValueError(
                f"Board: rows (short side) must not exceed cols (long side), got rows={self.rows}, "
                f"cols={self.cols}"
            )
        for name, lower in (("square_size", None), ("margin_long", 0.0), ("margin_short", 0.0)):
            value = getattr(self, name)
            try:
                f = float(value)
            except (TypeError, ValueError):
                raise ValueError(f"Board: {name} must be a number (metres), got {value!r}") from None
            if not np.isfinite(f) or (f <= 0.0 if lower is None else f < lower):
                bound = "> 0" if lower is None else ">= 0"
                raise ValueError(f"Board: {name} must be finite and {bound} (metres), got {value!r}")
            object.__setattr__(self, name, f)
        if self.lower_left not in _COLOUR_VALUE:
            raise ValueError(f"Board: lower_left must be 'black' or 'white', got {self.lower_left!r}")

    # ---------------------------------------------------------------- sizes
    @property
    def inner_shape(self) -> tuple[int, int]:
        """(rows-1, cols-1): inner corners along the short and long side."""
        return self.rows - 1, self.cols - 1

    @property
    def n_corners(self) -> int:
        """Number of inner corners K = (rows-1)*(cols-1)."""
        return (self.rows - 1) * (self.cols - 1)

    @property
    def pattern_size_m(self) -> tuple[float, float]:
        """(cols*s, rows*s): the printed pattern's extent along x and y, metres."""
        return self.cols * self.square_size, self.rows * self.square_size

    @property
    def pattern_centre(self) -> np.ndarray:
        """(3,) centre of the pattern (and of the board), board frame, metres."""
        w, h = self.pattern_size_m
        return np.array([0.5 * w, 0.5 * h, 0.0])

    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the physical board including the margin, board frame."""
        w, h = self.pattern_size_m
        return (-self.margin_long, w + self.margin_long, -self.margin_short, h + self.margin_short)

    def outline(self) -> np.ndarray:
        """(4, 3) physical board outline (incl. margin), board frame, counter-clockwise from (xmin, ymin)."""
        x0, x1, y0, y1 = self.extent()
        return np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])

    # -------------------------------------------------------------- corners
    def corners_board(self) -> np.ndarray:
        """(K, 3) inner corners, board frame: corner (i, j) at ((j+1)s, (i+1)s, 0), k = i*(cols-1)+j."""
        ni, nj = self.inner_shape
        i, j = np.divmod(np.arange(ni * nj), nj)
        s = self.square_size
        return np.stack([(j + 1) * s, (i + 1) * s, np.zeros(ni * nj)], axis=1)

    def corner_index(self, i: np.ndarray | int, j: np.ndarray | int) -> np.ndarray:
        """Index k = i*(cols-1) + j of inner corner (i, j)."""
        return np.asarray(i) * (self.cols - 1) + np.asarray(j)

    # -------------------------------------------------------------- colours
    def square_colour(self, r: np.ndarray | int, c: np.ndarray | int) -> np.ndarray:
        """Colour (0 black, 1 white) of square (r, c); r along y (0..rows-1), c along x (0..cols-1)."""
        r, c = np.asarray(r), np.asarray(c)
        if np.any((r < 0) | (r >= self.rows) | (c < 0) | (c >= self.cols)):
            raise ValueError(f"square_colour: (r, c) outside the {self.rows}x{self.cols} pattern")
        base = _COLOUR_VALUE[self.lower_left]
        return np.where((r + c) % 2 == 0, base, 1.0 - base).astype(float)

    def outer_corner_squares(self) -> np.ndarray:
        """(4, 3) the pattern's four corner squares as rows (r, c, colour).

        Order: the origin square (0, 0), then (0, cols-1), (rows-1, cols-1), (rows-1, 0), i.e.
        counter-clockwise seen from +z. The first has colour ``lower_left`` by definition.
        """
        r = np.array([0, 0, self.rows - 1, self.rows - 1])
        c = np.array([0, self.cols - 1, self.cols - 1, 0])
        return np.stack([r, c, self.square_colour(r, c)], axis=1)

    def colour_at(self, xy: np.ndarray) -> np.ndarray:
        """Printed colour at board-frame points.

        Parameters
        ----------
        xy : (N, 2) or (N, 3) board-frame points, metres (z ignored).

        Returns
        -------
        (N,) float: 0 black, 1 white (margin included), NaN off the physical board.
        Points on a square edge take the square on their +x / +y side (the last row/column
        is closed at the pattern's far edge).
        """
        xy = np.asarray(xy, dtype=float)
        if xy.ndim != 2 or xy.shape[1] not in (2, 3):
            raise ValueError(f"colour_at: xy must have shape (N, 2) or (N, 3), got {xy.shape}")
        x, y = xy[:, 0], xy[:, 1]
        x0, x1, y0, y1 = self.extent()
        on_board = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
        s = self.square_size
        w, h = self.pattern_size_m
        in_pattern = (x >= 0.0) & (x <= w) & (y >= 0.0) & (y <= h)
        with np.errstate(invalid="ignore"):
            c = np.clip(np.floor(np.nan_to_num(x) / s), 0, self.cols - 1).astype(np.int64)
            r = np.clip(np.floor(np.nan_to_num(y) / s), 0, self.rows - 1).astype(np.int64)
        base = _COLOUR_VALUE[self.lower_left]
        pattern = np.where((r + c) % 2 == 0, base, 1.0 - base)
        return np.where(on_board, np.where(in_pattern, pattern, WHITE), np.nan)

    # ------------------------------------------------------------ half turn
    @property
    def half_turn_symmetric(self) -> bool:
        """True when the pattern looks the same after a half turn about z ((rows + cols) even)."""
        return (self.rows + self.cols) % 2 == 0

    def half_turn_permutation(self) -> np.ndarray:
        """(K,) int: index of the corner that corner k lands on after the half turn (k -> K-1-k)."""
        return np.arange(self.n_corners)[::-1].copy()

    def T_half_turn(self) -> np.ndarray:
        """(4, 4) rotation by pi about z through the pattern centre, board frame -> board frame.

        ``T_half_turn() @ corners_board()[k]`` is ``corners_board()[half_turn_permutation()[k]]``.
        Composing a board pose with it, ``T_x_board @ T_half_turn()``, gives the pose of the same
        physical board with its origin at the opposite outer corner. It is its own inverse.
        """
        w, h = self.pattern_size_m
        T = np.eye(4)
        T[0, 0] = T[1, 1] = -1.0
        T[0, 3], T[1, 3] = w, h
        return T

    # ------------------------------------------------------------------ io
    def to_dict(self) -> dict[str, Any]:
        """Our config schema's ``board`` section (interface.md)."""
        return {
            "squares": [self.rows, self.cols],
            "square_size": self.square_size,
            "margin": [self.margin_long, self.margin_short],
            "lower_left": self.lower_left,
        }
