"""The paper's intensity cost C_m (Wang et al. 2017, Section 4.2): the gray zone, each return's
colour class, the board model's colour and grid-line distance, vectorised over poses and points.

In-plane convention: plane coordinates ``q`` (metres) map to board coordinates ``b = R(theta) q + t``
for a pose ``(theta, tx, ty)``.
"""

from __future__ import annotations

import numpy as np

from ..board import Board

__all__ = ["gray_zone", "grid_l1_distance", "intensity_classes", "model_colour", "paper_cost"]


def gray_zone(
    intensity: np.ndarray, epsilon: float = 2.0, bins: int = 100
) -> tuple[float, float, float, float]:
    """The paper's gray zone from the two histogram peaks.

    The intensities are split in two by Otsu's threshold; R_L and R_H are the centres of the
    fullest histogram bin below and above it. The histogram spans the 2-98 % quantiles (values
    beyond are clipped into its end bins), so a few saturated returns (retro-reflective tape, an
    Ouster's raw signal at close range) do not squeeze the board's two levels into a few bins; the
    result does not depend on the intensity's unit. Returns (tau_l, tau_h, R_L, R_H) with
    ``tau_l = ((eps-1) R_L + R_H) / eps`` and ``tau_h = (R_L + (eps-1) R_H) / eps``.
    """
    r = np.asarray(intensity, dtype=np.float64)
    if float(r.max()) - float(r.min()) <= 0:
        raise ValueError("gray_zone: all intensities are equal; no black and white to tell apart")
    lo, hi = (float(v) for v in np.quantile(r, [0.02, 0.98]))
    if hi - lo <= 0:
        lo, hi = float(r.min()), float(r.max())
    r = np.clip(r, lo, hi)
    hist, edges = np.histogram(r, bins=bins, range=(lo, hi))
    centres = 0.5 * (edges[1:] + edges[:-1])
    w0 = np.cumsum(hist)[:-1].astype(float)
    w1 = r.size - w0
    s0 = np.cumsum(hist * centres)[:-1]
    m0 = s0 / np.maximum(w0, 1)
    m1 = (np.sum(hist * centres) - s0) / np.maximum(w1, 1)
    between = w0 * w1 * (m0 - m1) ** 2
    k = int(np.argmax(between))  # threshold after bin k
    r_low = float(centres[: k + 1][np.argmax(hist[: k + 1])])
    r_high = float(centres[k + 1 :][np.argmax(hist[k + 1 :])])
    tau_l = ((epsilon - 1) * r_low + r_high) / epsilon
    tau_h = (r_low + (epsilon - 1) * r_high) / epsilon
    return tau_l, tau_h, r_low, r_high


def intensity_classes(intensity: np.ndarray, tau_l: float, tau_h: float) -> np.ndarray:
    """(N,) estimated colour from intensity: 0 black, 1 white, -1 gray (f_g = 0).

    Gray: ``tau_l < r < tau_h`` (f_g = 0). Outside the zone a point is white when ``r > tau_h``;
    with epsilon_g = 2 the zone is a single value and a point exactly on it counts as gray.
    """
    r = np.asarray(intensity, dtype=np.float64)
    cls = np.where(r > tau_h, 1, 0)
    gray = (r > tau_l) & (r < tau_h) | (r == tau_h)
    return np.where(gray, -1, cls).astype(np.int8)


def model_colour(b: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray]:
    """Colour of the board model at board coordinates b (..., 2): (colour 0/1, on-board bool).

    Same rule as ``Board.colour_at`` (margin white), vectorised over any leading shape.
    """
    s = board.square_size
    x, y = b[..., 0], b[..., 1]
    x0, x1, y0, y1 = board.extent()
    w, h = board.pattern_size_m
    on = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    inpat = (x >= 0) & (x <= w) & (y >= 0) & (y <= h)
    c = np.clip(np.floor(x / s), 0, board.cols - 1).astype(np.int64)
    r = np.clip(np.floor(y / s), 0, board.rows - 1).astype(np.int64)
    base = 0 if board.lower_left == "black" else 1
    pat = np.where((r + c) % 2 == 0, base, 1 - base)
    return np.where(inpat, pat, 1), on


def grid_l1_distance(b: np.ndarray, board: Board) -> np.ndarray:
    """f_d: L1 distance of board coordinates b (..., 2) to the model's nearest grid lines.

    ``min_j |x - X_j| + min_k |y - Y_k|`` over the pattern's lines X_j = j s (j = 0..cols),
    Y_k = k s (k = 0..rows) and, when the board has a margin, its physical edges.
    """
    s = board.square_size
    x, y = b[..., 0], b[..., 1]
    dx = np.abs(x - s * np.clip(np.round(x / s), 0, board.cols))
    dy = np.abs(y - s * np.clip(np.round(y / s), 0, board.rows))
    x0, x1, y0, y1 = board.extent()
    if board.margin_long > 0:
        dx = np.minimum(dx, np.minimum(np.abs(x - x0), np.abs(x - x1)))
    if board.margin_short > 0:
        dy = np.minimum(dy, np.minimum(np.abs(y - y0), np.abs(y - y1)))
    return dx + dy


def _transform(params: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """b = R(theta) q + t for params (..., 3) = (theta, tx, ty), q (N, 2): (bx, by), each (..., N)."""
    params = np.asarray(params, dtype=np.float64)
    th, tx, ty = params[..., 0:1], params[..., 1:2], params[..., 2:3]
    c, s = np.cos(th), np.sin(th)
    qx, qy = q[:, 0], q[:, 1]
    return c * qx - s * qy + tx, s * qx + c * qy + ty


def paper_cost(params: np.ndarray, q: np.ndarray, cls: np.ndarray, board: Board) -> np.ndarray:
    """The paper's C_m for one pose (3,) or many (M, 3); vectorised over points and poses.

    ``C_m = sum_i [ f_in(b_i) f_g(r_i) [c(r_i) != c_model(b_i)] + (1 - f_in(b_i)) ] f_d(b_i)``:
    a point on the board model costs its L1 distance to the nearest grid lines when its
    intensity colour disagrees with the model's colour there (nothing in the gray zone); a point
    off the model costs that distance always. q: (N, 2) plane coordinates, cls: (N,) from
    :func:`intensity_classes`. Returns a float array of shape params.shape[:-1].
    """
    params = np.asarray(params, dtype=np.float64)
    if params.ndim == 2 and params.shape[0] * q.shape[0] > _CHUNK:
        per = max(1, _CHUNK // q.shape[0])  # keep temporaries cache-sized (large arrays page-fault)
        return np.concatenate([_cost(params[i : i + per], q, cls, board) for i in range(0, len(params), per)])
    return _cost(params, q, cls, board)


_CHUNK = 40_000


def _cost(params: np.ndarray, q: np.ndarray, cls: np.ndarray, board: Board) -> np.ndarray:
    s = board.square_size
    bx, by = _transform(params, q)
    ux, uy = bx * (1.0 / s), by * (1.0 / s)  # board coordinates in squares
    kx, ky = np.floor(ux), np.floor(uy)
    # f_d: distance to the nearest pattern line (lines 0..cols, 0..rows), L1 over the two axes
    dx = np.abs(ux - np.minimum(np.maximum(np.rint(ux), 0.0), board.cols))
    dy = np.abs(uy - np.minimum(np.maximum(np.rint(uy), 0.0), board.rows))
    inpat = (kx >= 0) & (kx < board.cols) & (ky >= 0) & (ky < board.rows)
    base = 0 if board.lower_left == "black" else 1
    colour = (kx + ky + base).astype(np.int64) & 1
    if board.margin_long > 0 or board.margin_short > 0:
        x0, x1, y0, y1 = (e / s for e in board.extent())
        on = (ux >= x0) & (ux <= x1) & (uy >= y0) & (uy <= y1)
        if board.margin_long > 0:
            dx = np.minimum(dx, np.minimum(np.abs(ux - x0), np.abs(ux - x1)))
        if board.margin_short > 0:
            dy = np.minimum(dy, np.minimum(np.abs(uy - y0), np.abs(uy - y1)))
        colour = np.where(inpat, colour, 1)
    else:
        on = inpat
    free = on & ((cls < 0) | (colour == cls))
    return s * np.where(free, 0.0, dx + dy).sum(axis=-1)
