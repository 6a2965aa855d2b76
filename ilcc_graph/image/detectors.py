"""Chessboard grid detectors, contrast variants of the search image, and the grid's sanity check.

An *attempt* is a detector run on one contrast variant of a grey image, named
``"<detector>"`` or ``"<detector>+<contrast>"`` (e.g. ``"classic+gamma"``); :func:`run_attempt`
returns the (rows-1) x (cols-1) inner corners row-major (``cols-1`` per row, pixel centres at
integers) or None, and never a grid that fails :func:`grid_problem`.

Detectors (``DETECTORS``):

- ``sb``: OpenCV's ``findChessboardCornersSB`` with ``CALIB_CB_NORMALIZE_IMAGE`` and, when that
  fails, without it (histogram equalisation hurts on a near-uniform view); fast and accurate,
  fails on a board much darker than its surroundings.
- ``sb-exhaustive``: the same with ``CALIB_CB_EXHAUSTIVE`` (tries harder, a little slower).
- ``classic``: OpenCV's ``findChessboardCorners`` (adaptive threshold, normalised, quads filtered;
  copes with a shaded board), its corners refined by ``cornerSubPix`` in the searched image;
  gated by OpenCV's fast check (``CALIB_CB_FAST_CHECK``), without which a search that fails can
  take seconds on a textured 2000-column image. ``classic-full``: the same without the gate.
- ``cbdetect``: Geiger's detector (PyPI ``libcbdetect``), the one the paper used; accepted only
  when it returns exactly the board's grid.

Contrast variants (``CONTRASTS``), applied to the search image only (the corners are always
refined on the unchanged image): ``gamma`` (grey^0.5: lifts a dark board), ``clahe`` (OpenCV's
contrast-limited adaptive histogram equalisation, 8 x 8 tiles, clip 2), ``stretch`` (grey
levels between the 1st and 99th percentile stretched to 0..255).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from ..board import Board

Detector = Callable[[np.ndarray, Board], "np.ndarray | None"]


# ------------------------------------------------------------------------------------ contrast
def _gamma(gray: np.ndarray) -> np.ndarray:
    lut = np.clip(np.rint(255.0 * np.sqrt(np.arange(256) / 255.0)), 0, 255).astype(np.uint8)
    return cv2.LUT(gray, lut)


def _clahe(gray: np.ndarray) -> np.ndarray:
    return cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8)).apply(gray)


def _stretch(gray: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(gray, (1.0, 99.0))
    if hi - lo < 1.0:
        return gray
    return cv2.convertScaleAbs(gray, alpha=255.0 / (hi - lo), beta=-255.0 * lo / (hi - lo))


CONTRASTS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "gamma": _gamma,
    "clahe": _clahe,
    "stretch": _stretch,
}


# ----------------------------------------------------------------------------------- detectors
def _pattern(board: Board) -> tuple[int, int]:
    return (board.cols - 1, board.rows - 1)


def _sb_with(*flag_sets: int) -> Detector:
    def detect(gray: np.ndarray, board: Board) -> np.ndarray | None:
        for flags in flag_sets:
            ok, c = cv2.findChessboardCornersSB(gray, _pattern(board), flags=flags)
            if ok:
                return c.reshape(-1, 2).astype(np.float64)
        return None

    return detect


def _classic_with(flags: int) -> Detector:
    def detect(gray: np.ndarray, board: Board) -> np.ndarray | None:
        ok, c = cv2.findChessboardCorners(gray, _pattern(board), flags=flags)
        if not ok:
            return None
        xy = c.reshape(-1, 2).astype(np.float64)
        half = int(np.clip(round(0.25 * grid_spacing(xy, board)), 2, 10))
        crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
        pts = xy.astype(np.float32).reshape(-1, 1, 2)
        return cv2.cornerSubPix(gray, pts, (half, half), (-1, -1), crit).reshape(-1, 2).astype(np.float64)

    return detect


def _cbdetect(gray: np.ndarray, board: Board) -> np.ndarray | None:
    try:
        from libCBDetect import Checkerboard
    except ImportError:  # optional: the cascade goes on without it
        return None
    det = Checkerboard()
    det.norm = True
    det.show_processing = False
    det.show_debug_image = False
    det.array_norm_to_image(gray.astype(np.float64) / 255.0, gray.shape[0], gray.shape[1])
    det.find_corners()
    if int(det.number_of_corners) < board.n_corners:  # also: the library divides by zero on none
        return None
    det.find_board_from_corners()
    r, c = int(det.rows), int(det.cols)
    n_i, n_j = board.inner_shape
    if {r, c} != {n_i, n_j}:
        return None
    u, v = np.zeros(r * c), np.zeros(r * c)
    det.get_board_corners(u, v)
    g = np.stack([u, v], axis=1).reshape(r, c, 2)
    if (r, c) != (n_i, n_j):
        g = g.transpose(1, 0, 2)
    return np.ascontiguousarray(g.reshape(-1, 2))


_CLASSIC = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FILTER_QUADS

DETECTORS: dict[str, Detector] = {
    "sb": _sb_with(cv2.CALIB_CB_NORMALIZE_IMAGE, 0),
    "sb-exhaustive": _sb_with(cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE),
    "classic": _classic_with(_CLASSIC | cv2.CALIB_CB_FAST_CHECK),
    "classic-full": _classic_with(_CLASSIC),
    "cbdetect": _cbdetect,
}


def check_attempts(names: tuple[str, ...]) -> None:
    """Raise ValueError unless every name is ``detector`` or ``detector+contrast`` known here."""
    if not names:
        raise ValueError("ImageOptions: the detector cascade is empty")
    for name in names:
        det, _, con = str(name).partition("+")
        if det not in DETECTORS or (con and con not in CONTRASTS):
            raise ValueError(
                f"ImageOptions: unknown detector attempt {name!r}; detectors {sorted(DETECTORS)}, "
                f"optionally +contrast with one of {sorted(CONTRASTS)}"
            )


class ContrastCache:
    """The contrast variants of one grey image, each computed once."""

    def __init__(self, gray: np.ndarray) -> None:
        self._variants = {"": gray}

    def get(self, contrast: str) -> np.ndarray:
        if contrast not in self._variants:
            self._variants[contrast] = CONTRASTS[contrast](self._variants[""])
        return self._variants[contrast]


def run_attempt(name: str, images: ContrastCache, board: Board) -> np.ndarray | None:
    """(K, 2) row-major corners found by attempt ``name`` (``detector[+contrast]``), or None.

    A grid that fails :func:`grid_problem`, or an OpenCV error on degenerate input, counts as not found.
    """
    det, _, con = name.partition("+")
    try:
        xy = DETECTORS[det](images.get(con), board)
    except cv2.error:  # OpenCV's asserts on degenerate input (a view a few pixels wide, say)
        return None
    if xy is None or grid_problem(xy, board) is not None:
        return None
    return xy


# ------------------------------------------------------------------------------------- checks
def grid_spacing(xy: np.ndarray, board: Board) -> float:
    """Largest distance (px) between neighbouring corners of a row-major grid (K, 2)."""
    g = np.asarray(xy, dtype=np.float64).reshape(board.rows - 1, board.cols - 1, 2)
    d1 = np.linalg.norm(np.diff(g, axis=0), axis=-1).max()
    d2 = np.linalg.norm(np.diff(g, axis=1), axis=-1).max()
    return float(max(d1, d2))


def grid_problem(xy: np.ndarray, board: Board) -> str | None:
    """Why the corners (K, 2) cannot be the board's grid (row-major), or None when they can.

    Checks the count, finiteness and that the grid is not folded: every cell is a convex
    quadrilateral turning the same way as all the others, with an area of at least 2% of the
    median cell (a perspective view of a plane keeps the orientation of every cell).
    """
    xy = np.asarray(xy, dtype=np.float64)
    n_i, n_j = board.inner_shape
    if xy.shape != (n_i * n_j, 2):
        return f"{xy.shape[0] if xy.ndim == 2 else xy.size} corners instead of {n_i}x{n_j}"
    if not np.all(np.isfinite(xy)):
        return "corners not finite"
    g = xy.reshape(n_i, n_j, 2)
    quad = np.stack([g[:-1, :-1], g[:-1, 1:], g[1:, 1:], g[1:, :-1]], axis=2)  # (n_i-1, n_j-1, 4, 2)
    e = np.roll(quad, -1, axis=2) - quad
    turn = e[..., 0] * np.roll(e, -1, axis=2)[..., 1] - e[..., 1] * np.roll(e, -1, axis=2)[..., 0]
    if not (np.all(turn > 0) or np.all(turn < 0)):
        return "folded grid (cells not all convex and turning the same way)"
    area = np.abs(turn).sum(axis=2) / 4.0  # mean of the four corner parallelograms ~ cell area
    if area.min() < 0.02 * np.median(area):
        return "degenerate grid (a cell is almost flat)"
    return None
