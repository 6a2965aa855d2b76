"""Corner estimation from reflectance intensity (Wang et al. 2017, Section 4.2), vectorised.

The board's points are put on their plane (along each point's own ray, so range noise does not
move them within the plane), expressed in PCA axes under the paper's direction rules, and a
full-scale chessboard model is fitted in that plane over (theta_z, t_x, t_y) by Powell's method
on the paper's cost ``C_m``. Several starts (every in-plane angle, both colour phases, picked by
a vectorised coarse search of the same cost) replace the paper's single start.

In-plane convention: plane coordinates ``q`` (metres, origin at the points' centroid, axes
``x_p, y_p`` of the plane frame) map to board coordinates ``b = R(theta) q + t``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..board import Board
from .options import LidarOptions

__all__ = [
    "PlaneFrame",
    "plane_frame",
    "project_on_plane",
    "gray_zone",
    "intensity_classes",
    "model_colour",
    "grid_l1_distance",
    "paper_cost",
    "fit_in_plane",
    "InPlaneFit",
    "pose_from_in_plane",
]


@dataclass(frozen=True)
class PlaneFrame:
    """Plane frame of the board's points (LiDAR frame).

    origin: (3,) centroid of the projected points. axes: (3, 3) rows x_p, y_p, n (right-handed),
    n the plane normal towards the sensor, y_p with a non-negative LiDAR-z component (paper's rule).
    offset: d in ``n @ p = d``.
    """

    origin: np.ndarray
    axes: np.ndarray
    offset: float


def project_on_plane(points: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """(N, 3) points moved along their rays from the sensor origin onto ``normal @ p = offset``."""
    den = points @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(np.abs(den) > 1e-9, offset / den, 1.0)
    # a ray nearly parallel to the plane would fly far off: fall back to the orthogonal projection
    ortho = points - (den - offset)[:, None] * normal
    ray = points * lam[:, None]
    bad = (lam <= 0) | (np.linalg.norm(ray - points, axis=1) > 0.5)
    return np.where(bad[:, None], ortho, ray)


def plane_frame(points: np.ndarray, normal: np.ndarray, offset: float) -> PlaneFrame:
    """PCA axes of the projected points within the plane, under the paper's direction rules.

    normal must already point towards the sensor (``normal @ centroid < 0``).
    """
    mu = points.mean(axis=0)
    q = points - mu
    q = q - np.outer(q @ normal, normal)
    _, _, vt = np.linalg.svd(q, full_matrices=False)
    x_p = vt[0] - (vt[0] @ normal) * normal
    x_p /= np.linalg.norm(x_p)
    y_p = np.cross(normal, x_p)
    if y_p[2] < 0:  # the board's y axis and the LiDAR's z axis less than 90 deg apart
        x_p, y_p = -x_p, -y_p
    return PlaneFrame(mu, np.stack([x_p, y_p, normal]), float(offset))


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


def powell_batched(
    fun,
    x0: np.ndarray,
    scales: np.ndarray,
    xtol: float = 1e-3,
    max_iter: int = 12,
    n_line: int = 13,
) -> tuple[np.ndarray, float, int]:
    """Powell's direction-set method (1964) with batched line minimisations.

    fun: (M, 3) -> (M,) costs. Each line minimisation evaluates ``n_line`` points of the line at
    once and narrows the bracket around the best (by ``(n_line - 1) / 2`` each round, until its
    half-width is below ``xtol`` of the direction's scale; robust on a piecewise cost, where Brent's
    parabolic steps are not). After each sweep the direction of largest decrease is
    replaced by the sweep's net displacement (Powell's rule). scales: initial half-widths of the
    line searches per coordinate. Returns (x, f(x), number of evaluations).
    """
    x = np.asarray(x0, dtype=np.float64).copy()
    fx = float(fun(x[None])[0])
    n_ev = 1
    dirs = [np.eye(3)[i] * scales[i] for i in range(3)]
    grid = np.linspace(-1.0, 1.0, n_line)

    def line_min(x: np.ndarray, fx: float, d: np.ndarray) -> tuple[np.ndarray, float, int]:
        half, centre, ev = 1.0, 0.0, 0
        best_a, best_f = 0.0, fx
        while half > xtol:
            a = centre + half * grid
            f = fun(x[None] + a[:, None] * d[None])
            ev += a.size
            k = int(np.argmin(f))
            if f[k] < best_f:
                best_a, best_f = float(a[k]), float(f[k])
            centre, half = best_a, 2 * half / (n_line - 1)
        return x + best_a * d, best_f, ev

    for _ in range(max_iter):
        x_start, f_start = x.copy(), fx
        drops = []
        for d in dirs:
            x_new, f_new, ev = line_min(x, fx, d)
            n_ev += ev
            drops.append(fx - f_new)
            x, fx = x_new, f_new
        disp = x - x_start
        if np.all(np.abs(disp) <= xtol * scales):
            break
        # Powell's rule: the net displacement replaces the direction of largest decrease (scaled so
        # that its bracket spans the same normalised length as the others)
        u = disp / scales
        d_new = disp * (1.0 / max(float(np.linalg.norm(u)), 1e-12))
        big = int(np.argmax(drops))
        dirs.pop(big)
        dirs.append(d_new)
        x_new, f_new, ev = line_min(x, fx, d_new)
        n_ev += ev
        if f_new < fx:
            x, fx = x_new, f_new
        if f_start - fx <= 1e-12 * max(abs(f_start), 1.0) and np.linalg.norm(disp) < 1e-9:
            break
    return x, fx, n_ev


@dataclass(frozen=True)
class InPlaneFit:
    """Result of :func:`fit_in_plane`: params (theta [rad], tx, ty [m]), cost C_m, and n_evals."""

    params: np.ndarray
    cost: float
    n_evals: int
    tau: tuple[float, float]
    levels: tuple[float, float]


def _angle_wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def fit_in_plane(
    q: np.ndarray,
    intensity: np.ndarray,
    board: Board,
    options: LidarOptions = LidarOptions(),
    rng: np.random.Generator | None = None,
) -> InPlaneFit:
    """Fit the board model to plane coordinates q (N, 2) with intensities (N,).

    Coarse search of C_m on a subsample over every in-plane angle and a translation grid that
    covers both colour phases, then Powell from the ``n_starts`` best distinct cells (on at most
    ``options.powell_max_points`` returns drawn at random; the returned cost is over all of them).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    tau_l, tau_h, r_l, r_h = gray_zone(intensity, options.gray_epsilon)
    cls = intensity_classes(intensity, tau_l, tau_h)
    s = board.square_size
    centre = board.pattern_centre[:2]
    sub = rng.choice(q.shape[0], min(q.shape[0], 160), replace=False)
    qs, cs = q[sub], cls[sub]
    q_all, cls_all = q, cls
    if options.powell_max_points and q.shape[0] > options.powell_max_points:
        keep = rng.choice(q.shape[0], options.powell_max_points, replace=False)
        q, cls = q[keep], cls[keep]

    # coarse: every angle (step), translations over +-1 square around the centre (both colour phases)
    step = np.deg2rad(options.angle_step_deg * 2)
    angles = np.arange(-np.pi, np.pi, step)
    shifts = np.arange(-1.0, 1.0 + 1e-9, 2 * options.shift_step) * s
    A, X, Y = np.meshgrid(angles, shifts, shifts, indexing="ij")
    grid = np.stack([A.ravel(), centre[0] + X.ravel(), centre[1] + Y.ravel()], axis=1)
    costs = paper_cost(grid, qs, cs, board)
    n_evals = grid.shape[0]
    # fine grid around the best few coarse cells
    best = grid[np.argsort(costs)[:6]]
    fa = np.arange(-1, 2) * step / 2
    fs = np.arange(-1, 2) * options.shift_step * s
    dA, dX, dY = np.meshgrid(fa, fs, fs, indexing="ij")
    delta = np.stack([dA.ravel(), dX.ravel(), dY.ravel()], axis=1)
    fine = (best[:, None, :] + delta[None]).reshape(-1, 3)
    fcost = paper_cost(fine, q, cls, board)
    n_evals += fine.shape[0]
    starts: list[np.ndarray] = []
    for k in np.argsort(fcost):
        cand = fine[k]
        if all(
            abs(_angle_wrap(cand[0] - o[0])) > np.deg2rad(10) or np.linalg.norm(cand[1:] - o[1:]) > 0.5 * s
            for o in starts
        ):
            starts.append(cand)
        if len(starts) >= options.n_starts:
            break
    # a second start only when its cell is nearly as good as the best (an ambiguous pattern)
    f0 = float(np.min(fcost))
    starts = [starts[0]] + [x for x in starts[1:] if float(paper_cost(x, q, cls, board)) <= 1.5 * f0 + 1e-12]

    scales = np.array([np.deg2rad(options.angle_step_deg), options.shift_step * s, options.shift_step * s])
    best_x, best_f = starts[0], np.inf
    for x0 in starts:
        x, f, ev = powell_batched(lambda X: paper_cost(X, q, cls, board), x0, scales, options.powell_xtol)
        n_evals += ev
        if f < best_f:
            best_x, best_f = x, f
    best_x[0] = _angle_wrap(best_x[0])
    # the pattern repeats: a model moved by a whole square diagonally (or two along a side) matches
    # the same colours and differs only at the board's edges, where few returns tell them apart;
    # try those lattice neighbours on every return and keep the cheapest
    # (and the quarter turns about the pattern's centre, when sparse rings leave the outline unclear)
    lattice = s * np.array(
        [[0, 0], [1, 1], [1, -1], [-1, 1], [-1, -1], [2, 0], [-2, 0], [0, 2], [0, -2]], float
    )
    best_f = float(paper_cost(best_x, q_all, cls_all, board))  # C_m over every point
    for _ in range(3):
        cand = []
        for phi in (0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi):
            c_, s_ = np.cos(phi), np.sin(phi)
            t_rot = np.array([[c_, -s_], [s_, c_]]) @ (best_x[1:] - centre) + centre
            for L in lattice:
                if phi == 0.0 and not L.any():
                    continue
                cand.append([best_x[0] + phi, *(t_rot - L)])
        cand = np.asarray(cand)
        f = paper_cost(cand, q_all, cls_all, board)
        n_evals += len(cand)
        k = int(np.argmin(f))
        if f[k] >= best_f:
            break
        x, f_new, ev = powell_batched(
            lambda X: paper_cost(X, q, cls, board), cand[k], scales, options.powell_xtol
        )
        n_evals += ev
        f_new = float(paper_cost(x, q_all, cls_all, board))
        best_x, best_f = (x, f_new) if f_new < f[k] else (cand[k], float(f[k]))
        best_x[0] = _angle_wrap(best_x[0])
    return InPlaneFit(best_x, best_f, n_evals, (tau_l, tau_h), (r_l, r_h))


def pose_from_in_plane(frame: PlaneFrame, params: np.ndarray) -> np.ndarray:
    """(4, 4) T_lidar_board from the plane frame and b = R(theta) q + t.

    A board point (bx, by, 0) sits at q = R(theta)^T (b - t) in the plane, i.e. at
    ``origin + [x_p y_p] q`` in the LiDAR frame; the board's z is the plane normal.
    """
    th, tx, ty = params
    c, s = np.cos(th), np.sin(th)
    Rt = np.array([[c, s], [-s, c]])  # R(theta)^T
    F = frame.axes[:2].T  # (3, 2) columns x_p, y_p
    T = np.eye(4)
    T[:3, :2] = F @ Rt
    T[:3, 2] = frame.axes[2]
    T[:3, 3] = frame.origin - F @ (Rt @ np.array([tx, ty]))
    return T
