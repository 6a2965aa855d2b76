"""In-plane refinement of the intensity fit with a soft-edged chessboard model, and its covariance.

Powell's cost is piecewise constant in places and has no useful Hessian, so the in-plane pose
(rz, tx, ty) is refined with a *soft-edged* model of the intensities,

    I(b) = a + c * w(b),   w = M(b) * (1 + ph * Sx(x) Sy(y)) / 2 + (1 - M(b)),

where ``Sx(x) = (-1)^j erf(u / (sqrt(2) sigma_b))`` is a square wave blurred by a Gaussian beam
footprint (``j`` the nearest grid line, ``u`` the signed distance to it), ``M`` the blurred
pattern box (outside it the margin is white; no box along a side without margin) and
``ph = -1`` for a black lower-left square.
Levenberg-Marquardt on a Huber loss fits (rz, tx, ty, a, c, log sigma_b); the pose covariance is the
(rz, tx, ty) block of the M-estimator's sandwich covariance. The correction is in GTSAM's Pose3
tangent at the start pose, ``T_refined = T_start * Expmap((0, 0, rz, tx, ty, 0))`` (``se2_exp``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, overload

import numpy as np
from scipy.special import erf

from ..board import Board

__all__ = ["SoftFit", "se2_exp", "se2_log", "soft_edge_refine", "soft_intensity"]

_SQRT2 = np.sqrt(2.0)
_C = 2.0 / np.sqrt(np.pi)


def _wave(v: np.ndarray, s: float, n_lines: int, sig: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Blurred square wave along one axis (inner lines at 1..n_lines-1 times s): value, d/dv, d/dsigma.

    The pattern's outer lines are not blurred here: beyond them is the margin (handled by the
    pattern box) or nothing at all.
    """
    j = np.clip(np.round(v / s), 1, n_lines - 1)
    u = v - j * s
    sign = np.where(j % 2 == 0, 1.0, -1.0)
    z = u / (_SQRT2 * sig)
    g = sign * _C * np.exp(-z * z)
    return sign * erf(z), g / (_SQRT2 * sig), -g * z / sig


def _box(v: np.ndarray, width: float, sig: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Blurred indicator of [0, width]: value, d/dv, d/dsigma."""
    z0, z1 = v / (_SQRT2 * sig), (v - width) / (_SQRT2 * sig)
    g0, g1 = _C * np.exp(-z0 * z0), _C * np.exp(-z1 * z1)
    return 0.5 * (erf(z0) - erf(z1)), 0.5 * (g0 - g1) / (_SQRT2 * sig), -0.5 * (g0 * z0 - g1 * z1) / sig


def soft_intensity(
    b: np.ndarray, board: Board, a: float, c: float, sig: float, with_sigma: bool = False
) -> tuple[np.ndarray, ...]:
    """Soft-edged model intensity at board coordinates b (N, 2), its gradient (N, 2)[, and d/dsigma (N,)]."""
    s = board.square_size
    w_, h_ = board.pattern_size_m
    sx, dsx, ssx = _wave(b[:, 0], s, board.cols, sig)  # +1 on square 0, alternating
    sy, dsy, ssy = _wave(b[:, 1], s, board.rows, sig)
    # the white margin is blurred into the pattern; where the board ends at the pattern (no
    # margin) there is nothing beyond it and no blending
    one, zero = np.ones(len(b)), np.zeros(len(b))
    mx, dmx, smx = _box(b[:, 0], w_, sig) if board.margin_long > 0 else (one, zero, zero)
    my, dmy, smy = _box(b[:, 1], h_, sig) if board.margin_short > 0 else (one, zero, zero)
    ph = -1.0 if board.lower_left == "black" else 1.0
    chk = 0.5 * (1 + ph * sx * sy)
    m = mx * my
    w = m * chk + (1 - m)
    dw_dx = m * 0.5 * ph * dsx * sy + dmx * my * (chk - 1)
    dw_dy = m * 0.5 * ph * sx * dsy + mx * dmy * (chk - 1)
    if not with_sigma:
        return a + c * w, c * np.stack([dw_dx, dw_dy], axis=1)
    dw_ds = m * 0.5 * ph * (ssx * sy + sx * ssy) + (smx * my + mx * smy) * (chk - 1)
    return a + c * w, c * np.stack([dw_dx, dw_dy], axis=1), c * dw_ds


@dataclass(frozen=True)
class SoftFit:
    """Result of :func:`soft_edge_refine`.

    xi: (3,) in-plane correction (rz, tx, ty) in the Pose3 tangent of the start pose
    (``T_refined = T_start * Expmap((0, 0, rz, tx, ty, 0))``).
    cov: (3, 3) covariance of (rz, tx, ty) at the refined pose. a, c: black level and contrast.
    blur: fitted footprint sigma (m). scale: robust residual sigma (intensity units).
    converged: False when Gauss-Newton did not settle or moved implausibly far.
    """

    xi: np.ndarray
    cov: np.ndarray
    a: float
    c: float
    blur: float
    scale: float
    converged: bool
    iterations: int


def _se2_V(w: float) -> np.ndarray:
    """(2, 2) V(w) of SE(2)'s exponential: t = V(w) v (identity for a tiny w)."""
    if abs(w) < 1e-9:
        return np.eye(2)
    return np.array([[np.sin(w), -(1 - np.cos(w))], [1 - np.cos(w), np.sin(w)]]) / w


def se2_exp(xi: np.ndarray) -> np.ndarray:
    """3x3 homogeneous SE(2) of the in-plane part of Pose3.Expmap((0, 0, rz, tx, ty, 0)); xi (rz, tx, ty)."""
    w, tx, ty = xi
    V = _se2_V(w)
    H = np.eye(3)
    H[:2, :2] = [[np.cos(w), -np.sin(w)], [np.sin(w), np.cos(w)]]
    H[:2, 2] = V @ np.array([tx, ty])
    return H


def se2_log(H: np.ndarray) -> np.ndarray:
    """(rz, tx, ty) with ``se2_exp(xi) = H`` for a 3x3 homogeneous SE(2) ``H``."""
    w = float(np.arctan2(H[1, 0], H[0, 0]))
    Vinv = np.eye(2) if abs(w) < 1e-9 else np.linalg.inv(_se2_V(w))
    t = Vinv @ H[:2, 2]
    return np.array([w, t[0], t[1]])


def _huber(res: np.ndarray, k: float) -> tuple[float, np.ndarray]:
    a = np.abs(res)
    rho = np.where(a <= k, 0.5 * res * res, k * (a - 0.5 * k))
    return float(rho.sum()), np.where(a <= k, 1.0, k / np.maximum(a, 1e-12))


@overload
def _residual(
    r: np.ndarray, b0h: np.ndarray, board: Board, H: np.ndarray, a: float, c: float, lsig: float,
    jac: Literal[True],
) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def _residual(
    r: np.ndarray, b0h: np.ndarray, board: Board, H: np.ndarray, a: float, c: float, lsig: float,
    jac: Literal[False],
) -> tuple[np.ndarray, None]: ...
def _residual(
    r: np.ndarray, b0h: np.ndarray, board: Board, H: np.ndarray, a: float, c: float, lsig: float, jac: bool
) -> tuple[np.ndarray, np.ndarray | None]:
    """The intensities ``r`` less the soft-edged model's at the points ``b0h`` (N, 3: homogeneous,
    start board frame) moved by ``H``; with ``jac`` the (N, 6) Jacobian of the prediction's negative
    in (rz, tx, ty, a, c, log sigma)."""
    b = (b0h @ H.T)[:, :2]
    if not jac:
        return r - soft_intensity(b, board, a, c, np.exp(lsig))[0], None
    pred, grad, dsig = soft_intensity(b, board, a, c, np.exp(lsig), with_sigma=True)
    res = r - pred
    J = np.empty((len(r), 6))
    # d b / d xi for b' = Exp(-xi) b: [[y, -1, 0], [-x, 0, -1]]
    J[:, 0] = -(grad[:, 0] * b[:, 1] - grad[:, 1] * b[:, 0])
    J[:, 1] = grad[:, 0]
    J[:, 2] = grad[:, 1]
    J[:, 3] = -1.0
    J[:, 4] = -(pred - a) / c if c != 0 else 0.0
    J[:, 5] = -dsig * np.exp(lsig)  # d/d log(sigma)
    return res, J


def _sandwich(J: np.ndarray, res: np.ndarray, W: np.ndarray, k: float) -> np.ndarray:
    """(3, 3) the pose part of the Huber M-estimator's sandwich covariance ``A^-1 B A^-1``:
    ``A = sum psi'(r) J J^T`` (psi' 1 inside the threshold ``k``, 0 beyond), ``B = sum psi(r)^2 J J^T``
    with ``psi(r) = w r``; LinAlgError when the fit does not determine every parameter."""
    inside = (np.abs(res) <= k).astype(np.float64)
    A = (J * inside[:, None]).T @ J
    d = np.sqrt(np.diag(A))  # a parameter the points do not determine: no covariance (no overflow)
    if not (np.all(d > 0) and np.linalg.cond(A / np.outer(d, d)) < 1e12):
        raise np.linalg.LinAlgError("the fit does not determine every parameter")
    Ainv = np.linalg.inv(A)
    G = J * (W * res)[:, None]
    return (Ainv @ (G.T @ G) @ Ainv)[:3, :3]


def soft_edge_refine(
    b0: np.ndarray,
    intensity: np.ndarray,
    board: Board,
    levels: tuple[float, float],
    blur0: float,
    max_iter: int = 200,
) -> SoftFit:
    """Levenberg-Marquardt (Huber loss) fit of the soft-edged model to intensities at b0 (N, 2).

    b0: points in the start pose's board frame (on the board). levels: (R_L, R_H) start values.
    Parameters: in-plane pose correction (rz, tx, ty) in the Pose3 tangent, black level a,
    contrast c, log of the footprint sigma. A board whose beams run along its rows, a few beams on
    it, leaves a flat valley (its position across them) that takes some 40-70 steps to settle.
    """
    r = np.asarray(intensity, dtype=np.float64)
    b0h = np.column_stack([b0, np.ones(len(b0))])
    sig_lo, sig_hi = np.log(2e-4), np.log(0.5 * board.square_size)

    def residual(H: np.ndarray, a: float, c: float, lsig: float) -> tuple[np.ndarray, np.ndarray]:
        return _residual(r, b0h, board, H, a, c, lsig, True)

    H = np.eye(3)
    a, c = float(levels[0]), float(levels[1] - levels[0])
    lsig = float(np.clip(np.log(max(blur0, 1e-3)), sig_lo, sig_hi))
    res, J = residual(H, a, c, lsig)
    k = 1.5 * max(1.4826 * float(np.median(np.abs(res - np.median(res)))), 1e-6)
    f, W = _huber(res, k)
    lam, converged, it = 1e-3, False, 0
    for it in range(1, max_iter + 1):  # noqa: B007
        JW = J * W[:, None]
        N = JW.T @ J
        g = JW.T @ res
        try:
            step = -np.linalg.solve(N + lam * np.diag(np.diag(N) + 1e-12), g)
        except np.linalg.LinAlgError:
            break
        Hn = np.linalg.inv(se2_exp(step[:3])) @ H
        an, cn = a + step[3], c + step[4]
        ln = float(np.clip(lsig + step[5], sig_lo, sig_hi))
        res_n, _ = _residual(r, b0h, board, Hn, an, cn, ln, False)
        fn, _ = _huber(res_n, k)
        if fn < f:
            small = abs(step[0]) < 1e-6 and np.linalg.norm(step[1:3]) < 1e-6 or (f - fn) < 1e-8 * f
            H, a, c, lsig = Hn, an, cn, ln
            res, J = residual(H, a, c, lsig)
            f, W = _huber(res, k)
            lam = max(lam / 3, 1e-9)
            if small:
                converged = True
                break
        else:
            lam *= 5
            if lam > 1e8:
                converged = True  # no step lowers the cost: at the minimum
                break
    scale = max(1.4826 * float(np.median(np.abs(res - np.median(res)))), 1e-6)
    try:
        # sandwich (Huber-White) covariance A^-1 B A^-1: it holds when the residuals' spread varies
        # from point to point (returns near edges, whose positions are noisy, vs flat squares)
        # M-estimator sandwich: A = sum psi'(r) J J^T (psi' = 1 inside the Huber threshold, 0 beyond),
        # B = sum psi(r)^2 J J^T with psi(r) = w r
        cov = _sandwich(J, res, W, k)
    except np.linalg.LinAlgError:
        cov = np.full((3, 3), np.nan)
        converged = False
    # the correction xi in the start pose's tangent: board_new = H board_start, T_new = T_start * H^-1
    xi = se2_log(np.linalg.inv(H))
    w, t = float(xi[0]), xi[1:]
    if not np.all(np.isfinite(cov)) or abs(w) > np.deg2rad(5) or np.linalg.norm(t) > 0.5 * board.square_size:
        converged = False
    return SoftFit(xi, cov, a, c, float(np.exp(lsig)), scale, converged, it)
