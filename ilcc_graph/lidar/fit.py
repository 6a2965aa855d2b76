"""Corner estimation from reflectance intensity (Wang et al. 2017, Section 4.2), vectorised.

The board's points are put on their plane (along each point's own ray, so range noise does not
move them within the plane), expressed in PCA axes under the paper's direction rules, and a
full-scale chessboard model is fitted in that plane over (theta_z, t_x, t_y) by Powell's method
on the paper's cost ``C_m`` (``cost.py``). Several starts (every in-plane angle, both colour phases,
picked by a vectorised coarse search of the same cost) replace the paper's single start.

In-plane convention: plane coordinates ``q`` (metres, origin at the points' centroid, axes
``x_p, y_p`` of the plane frame) map to board coordinates ``b = R(theta) q + t``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..board import Board
from .cost import gray_zone, intensity_classes, paper_cost
from .options import LidarOptions

__all__ = [
    "InPlaneFit",
    "PlaneFrame",
    "align_to_plane",
    "fit_in_plane",
    "plane_frame",
    "pose_from_in_plane",
    "powell_batched",
    "project_on_plane",
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


def align_to_plane(T: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """T_lidar_board turned by the smallest rotation to make its z ``normal``; its origin put on the plane."""
    z = T[:3, 2]
    v = np.cross(z, normal)
    sn, cs = np.linalg.norm(v), float(z @ normal)
    R = np.eye(3)
    if sn > 1e-12:
        k = v / sn
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R = np.eye(3) + sn * K + (1 - cs) * K @ K
    out = np.eye(4)
    out[:3, :3] = R @ T[:3, :3]
    o = T[:3, 3]
    out[:3, 3] = o - (o @ normal - offset) * normal
    return out


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


def powell_batched(
    fun: Callable[[np.ndarray], np.ndarray],
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
    sub = rng.choice(q.shape[0], min(q.shape[0], 160), replace=False)
    qs, cs = q[sub], cls[sub]
    q_all, cls_all = q, cls
    if options.powell_max_points and q.shape[0] > options.powell_max_points:
        keep = rng.choice(q.shape[0], options.powell_max_points, replace=False)
        q, cls = q[keep], cls[keep]

    starts, n_evals = _starts(qs, cs, q, cls, board, options)
    scales = np.array([np.deg2rad(options.angle_step_deg), options.shift_step * s, options.shift_step * s])
    best_x, best_f = starts[0], np.inf
    for x0 in starts:
        x, f, ev = powell_batched(lambda X: paper_cost(X, q, cls, board), x0, scales, options.powell_xtol)
        n_evals += ev
        if f < best_f:
            best_x, best_f = x, f
    best_x[0] = _angle_wrap(best_x[0])
    best_x, best_f, ev = _lattice_moves(best_x, q, cls, q_all, cls_all, board, scales, options)
    return InPlaneFit(best_x, best_f, n_evals + ev, (tau_l, tau_h), (r_l, r_h))


def _starts(
    qs: np.ndarray, cs: np.ndarray, q: np.ndarray, cls: np.ndarray, board: Board, options: LidarOptions
) -> tuple[list[np.ndarray], int]:
    """Powell's starts (angle, tx, ty) and the cost evaluations spent finding them: the best cells of
    a coarse grid on the subsample ``qs``, ``cs`` refined on a fine grid on ``q``, ``cls``, kept
    when distinct and, but for the best, nearly as good as it (an ambiguous pattern)."""
    s = board.square_size
    centre = board.pattern_centre[:2]
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
    return starts, n_evals


def _lattice_moves(
    best_x: np.ndarray,
    q: np.ndarray,
    cls: np.ndarray,
    q_all: np.ndarray,
    cls_all: np.ndarray,
    board: Board,
    scales: np.ndarray,
    options: LidarOptions,
) -> tuple[np.ndarray, float, int]:
    """The fit ``best_x`` moved on the pattern's lattice while that lowers C_m over every return
    (``q_all``, ``cls_all``): (parameters, their cost over every return, cost evaluations spent).

    The pattern repeats: a model moved by a whole square diagonally (or two along a side) matches
    the same colours and differs only at the board's edges, where few returns tell them apart; those
    lattice neighbours are tried on every return and the cheapest kept (and the quarter turns about
    the pattern's centre, when sparse rings leave the outline unclear)."""
    s = board.square_size
    centre = board.pattern_centre[:2]
    n_evals = 0
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
        cands = np.asarray(cand)
        f = paper_cost(cands, q_all, cls_all, board)
        n_evals += len(cands)
        k = int(np.argmin(f))
        if f[k] >= best_f:
            break
        x, f_new, ev = powell_batched(
            lambda X: paper_cost(X, q, cls, board), cands[k], scales, options.powell_xtol
        )
        n_evals += ev
        f_new = float(paper_cost(x, q_all, cls_all, board))
        best_x, best_f = (x, f_new) if f_new < f[k] else (cands[k], float(f[k]))
        best_x[0] = _angle_wrap(best_x[0])
    return best_x, best_f, n_evals


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
