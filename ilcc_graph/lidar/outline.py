"""The outline's part in a board's fit (shape.py's evidence put to use).

- :func:`outline_only`: the in-plane pose from the outline alone, for a board whose print the LiDAR
  does not show (no contrast): the start from the outline (:func:`outline_start`, every in-plane
  angle), and the quarter turn of a nearly square board checked (refused when the scan cannot
  tell it); :func:`refuse_outline`: such a fit refused when its outline is not the board's;
- :func:`shape_check`: the outline's posterior about the intensity fit's pose and the chi-square
  of their difference; :func:`lattice_moves`: the moves of the pattern by whole squares (and its
  half turn) the outline allows, for a slid intensity fit; :func:`fuse`: the two combined;
- :func:`outline_coupling`: how a plane error moves the outline's evidence (ray projection);
- :func:`fov_share`: the part of the board the beams cannot reach (above the top beam, below the
  lowest, beyond a cropped scan's azimuth window): unknown, not evidence, reported.

Poses are ``T_lidar_board`` (4, 4); in-plane corrections ``xi = (rz, tx, ty)`` in GTSAM's Pose3
tangent, ``T' = T * Expmap((0, 0, rz, tx, ty, 0))``; covariances (3, 3) of xi.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gammaincinv, ndtr

from ..board import Board
from ..errors import BoardNotFound
from ..lidars import LidarModel
from .covariance import ray_coupling
from .options import LidarOptions, breach
from .shape import (
    OutlineSamples,
    ShapeFit,
    edge_z,
    growth_prior,
    outline_loglik,
    outline_mode,
    outline_posterior,
    outline_samples,
)
from .silent import scan_window
from .soft_edge import se2_exp, se2_log

__all__ = [
    "BEYOND_FOV_SHARE",
    "EDGE_LEFT_OUT_REACH",
    "ShapeCheck",
    "apply_xi",
    "fov_share",
    "fuse",
    "inplane_reach",
    "lattice_moves",
    "outline_coupling",
    "outline_only",
    "outline_start",
    "refuse_outline",
    "shape_check",
    "shape_diagnostics",
    "shape_gate",
    "slid_message",
]


def apply_xi(T: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """``T * Expmap((0, 0, rz, tx, ty, 0))`` for xi (3,) = (rz, tx, ty)."""
    H = se2_exp(np.asarray(xi, np.float64))
    E = np.eye(4)
    E[:2, :2], E[:2, 3] = H[:2, :2], H[:2, 2]
    return T @ E


def _half_turn_2d(board: Board) -> np.ndarray:
    """3x3 SE(2) of the board's half turn about the pattern's centre (board frame)."""
    H = np.eye(3)
    H[:2, :2] = -np.eye(2)
    H[:2, 2] = 2 * board.pattern_centre[:2]
    return H


def _nearest_turn(xi: np.ndarray, board: Board) -> np.ndarray:
    """The correction xi or the same outline half-turned, whichever turns less."""
    if abs(xi[0]) <= np.pi / 2:
        return xi
    return se2_log(se2_exp(xi) @ _half_turn_2d(board))


def _wide(board: Board) -> float:
    """How far beyond the outline rays are taken before the in-plane angle is known (m)."""
    x0, x1, y0, y1 = board.extent()
    return 0.5 * float(np.hypot(x1 - x0, y1 - y0)) - 0.5 * (y1 - y0) + 0.15


def outline_coupling(s: OutlineSamples, shape: ShapeFit, board: Board) -> np.ndarray:
    """K (3, 3): the in-plane error of the outline's fit caused by a plane error (rx, ry, tz)
    (``covariance.ray_coupling``, each sample weighted by its Fisher information at the mean)."""
    z = edge_z(np.append(shape.xi, shape.growth), s, board)[0]
    p = np.clip(ndtr(z), 1e-9, 1 - 1e-9)
    info = np.exp(-z * z) / (2 * np.pi * p * (1 - p)) / s.sigma.min(axis=1) ** 2
    H = np.linalg.inv(se2_exp(shape.xi))
    b = s.b @ H[:2, :2].T + H[:2, 2]
    u = s.u.copy()
    u[:, :2] = u[:, :2] @ H[:2, :2].T
    return ray_coupling(b, u, info)


#: a board more than this share of whose area lies beyond the beams is reported as leaving the field of view
BEYOND_FOV_SHARE = 0.02


def fov_share(
    T: np.ndarray, board: Board, model: LidarModel, scan: np.ndarray | None = None, n: int = 24
) -> float:
    """Share of the board's area the beams cannot reach: above the top beam or below the lowest
    (by more than half the neighbouring ring spacing), or beyond the azimuth window of a cropped
    ``scan`` (its returns (N, 3), LiDAR frame; ``silent.scan_window``). 0 for a scanline-free LiDAR."""
    el = np.sort(model.vertical_angles_rad)
    if model.ringless or el.size < 2:
        return 0.0
    x0, x1, y0, y1 = board.extent()
    gx, gy = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n))
    p = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)]) @ T[:3, :3].T + T[:3, 3]
    e = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))
    out = (e > el[-1] + 0.5 * (el[-1] - el[-2])) | (e < el[0] - 0.5 * (el[1] - el[0]))
    if scan is not None and len(scan):
        az_c = float(np.arctan2(T[1, 3], T[0, 3]))
        q = np.asarray(scan, np.float64)
        lo, hi = scan_window((np.arctan2(q[:, 1], q[:, 0]) - az_c + np.pi) % (2 * np.pi) - np.pi, 0.0)
        a = (np.arctan2(p[:, 1], p[:, 0]) - az_c + np.pi) % (2 * np.pi) - np.pi
        out |= (a < lo) | (a > hi)
    return float(out.mean())


def nearest_edge(b: np.ndarray, board: Board) -> np.ndarray:
    """(N,) the edge of ``Board.extent`` (0: x0, 1: x1, 2: y0, 3: y1) nearest each in-plane point b (N, 2)."""
    x0, x1, y0, y1 = board.extent()
    return np.argmin(np.abs(np.c_[b[:, 0] - x0, b[:, 0] - x1, b[:, 1] - y0, b[:, 1] - y1]), axis=1)


def _posterior_at(points: np.ndarray, T: np.ndarray, board: Board, model: LidarModel, s_z: float,
                  options: LidarOptions, rng: np.random.Generator, xi0: np.ndarray | None = None,
                  without_edge: int | None = None) -> tuple[OutlineSamples, ShapeFit]:  # fmt: skip
    """The outline's samples about ``T`` and their posterior; ``without_edge``: less the samples
    nearest that edge (``nearest_edge``)."""
    s = outline_samples(points, T, board, model, s_z, options.outline_blur)
    if without_edge is not None:
        s = s.subset(nearest_edge(s.b, board) != without_edge)
    return s, outline_posterior(s, board, rng, xi0)


def outline_only(
    points: np.ndarray, T0: np.ndarray, board: Board, model: LidarModel, s_z: float, options: LidarOptions,
    rng: np.random.Generator,
) -> np.ndarray:  # fmt: skip
    """The board pose from its outline alone: ``T0`` (its plane, the board's centre near the
    returns' centroid) turned and shifted in the plane to where the outline fits the scan's points
    (N, 3) best. BoardNotFound when there is nothing to fit, or when a quarter turn of a nearly
    square board fits as well (the order of the corners could not be told)."""
    s0 = outline_samples(points, T0, board, model, s_z, options.outline_blur, grow=_wide(board))
    if s0.inside.sum() < 10:
        raise BoardNotFound(
            "too few returns on the board's plane to fit its outline "
            + breach("returns on the plane", float(s0.inside.sum()), "<", 10.0)
        )
    starts = outline_start(s0, board, rng)
    if len(starts) < 2 or starts[1][1] < options.quarter_turn_score * starts[0][1]:
        return apply_xi(T0, starts[0][0])
    # the outline turned by a quarter nearly fits too: compare the likelihoods of the two on the same
    # samples, each at its mode (the growth's prior included)
    g_sd = growth_prior(s0)
    modes = [outline_mode(s0, board, xi, growth_sd=g_sd)[0] for xi, _ in starts[:2]]
    L = [float(outline_loglik(m, s0, board, g_sd)[0]) for m in modes]
    if abs(L[0] - L[1]) < np.log(options.quarter_turn_odds):
        x0, x1, y0, y1 = board.extent()
        raise BoardNotFound(
            f"the board's outline ({x1 - x0:.2f} x {y1 - y0:.2f} m) fits this scan as well turned by a "
            "quarter turn, and the LiDAR shows no print to tell them apart: the corners' order is unknown "
            + breach("quarter_turn_odds", float(np.exp(abs(L[0] - L[1]))), "<", options.quarter_turn_odds)
        )
    return apply_xi(T0, modes[int(np.argmax(L))][:3])


def shape_gate(options: LidarOptions) -> float:
    """The outline's gate against the intensity fit: chi-square's ``options.shape_gate_p`` quantile
    for 3 dof, as ``scipy.stats.chi2.ppf`` gives it (``2 P^-1(3/2, p)``, the regularised incomplete
    gamma function's inverse) without importing scipy.stats (0.7 s in every process)."""
    return float(2.0 * gammaincinv(1.5, options.shape_gate_p))


@dataclass(frozen=True)
class ShapeCheck:
    """The outline's posterior about a pose and how it compares with the intensity fit there.

    samples, fit: shape.py's samples and posterior (correction about the pose). chi2: Mahalanobis
    distance squared of the correction under the sum of both covariances; consistent: below the
    gate (``options.shape_gate_p``, 3 dof). shift: how far the correction moves the board's corners
    at most (m). slid: beyond the gate and by more than ``options.slide_squares`` squares: the
    pattern fit is not where the outline is (a print off the centre of its backing, or covariances
    a few times too small, differ by less: then the two are not combined, nothing is refused).
    """

    samples: OutlineSamples
    fit: ShapeFit
    chi2: float
    consistent: bool
    shift: float
    slid: bool


def shape_check(
    points: np.ndarray, T: np.ndarray, cov_int: np.ndarray, board: Board, model: LidarModel, s_z: float,
    options: LidarOptions, rng: np.random.Generator, without_edge: int | None = None,
) -> ShapeCheck:  # fmt: skip
    """The outline's posterior about the intensity fit's pose ``T`` (covariance ``cov_int`` of its
    in-plane correction) and their chi-square. When the outline does not fit about ``T`` (the
    pattern slid), the outline is fitted afresh (``outline_start``) and taken in the half turn
    nearest ``T``. without_edge: the outline without the samples nearest that edge (0-3, the order of
    ``Board.extent``; an edge that something beside the board, a hand or a stand, draws out)."""
    s, fit = _posterior_at(points, T, board, model, s_z, options, rng, without_edge=without_edge)
    if fit.agreement < options.min_shape_agreement:
        s0 = outline_samples(points, T, board, model, s_z, options.outline_blur, grow=_wide(board))
        if s0.inside.sum() >= 10:
            xi = _nearest_turn(outline_start(s0, board, rng)[0][0], board)
            s1, fit1 = _posterior_at(points, T, board, model, s_z, options, rng, xi, without_edge)
            if fit1.agreement > fit.agreement:
                s, fit = s1, fit1
    S = fit.cov + cov_int
    d = fit.xi
    c2 = float(d @ np.linalg.solve(S, d)) if np.all(np.isfinite(S)) else np.inf
    gate = shape_gate(options)
    x0, x1, y0, y1 = board.extent()
    shift = float(np.linalg.norm(d[1:]) + 0.5 * np.hypot(x1 - x0, y1 - y0) * abs(d[0]))
    slid = c2 > gate and shift > options.slide_squares * board.square_size
    return ShapeCheck(s, fit, c2, bool(c2 <= gate), shift, bool(slid))


#: the outline less one edge checks a slid pattern only when both fix the board's corners in its plane
#: to this many squares (2 sigma): a pattern slid by a whole square is then 5 sigma off (a board-sized
#: two-tone panel, whose pattern fit is known to centimetres or metres, is not checked so)
EDGE_LEFT_OUT_REACH = 0.4


def inplane_reach(cov: np.ndarray, board: Board) -> float:
    """2 sigma (m) of the board's corners in its plane under an in-plane covariance (3, 3) (rz, tx, ty)."""
    if not np.all(np.isfinite(cov)):
        return np.inf
    x0, x1, y0, y1 = board.extent()
    sd_t = float(np.sqrt(max(np.linalg.eigvalsh(cov[1:3, 1:3]).max(), 0.0)))
    return 2.0 * (sd_t + 0.5 * float(np.hypot(x1 - x0, y1 - y0)) * float(np.sqrt(max(cov[0, 0], 0.0))))


def lattice_moves(board: Board, check: ShapeCheck, cov_int: np.ndarray, gate: float) -> list[np.ndarray]:
    """In-plane corrections (3,) moving the pattern by whole squares (up to two along each side)
    and/or half-turning it, that the outline allows (chi-square below ``gate``; a half-turned board
    has the same outline), most likely first."""
    s = board.square_size
    out = []
    S = check.fit.cov + cov_int
    for turn in (False, True):
        for i in range(-2, 3):
            for j in range(-2, 3):
                if not turn and i == 0 and j == 0:
                    continue
                H = np.eye(3)
                H[:2, 2] = (i * s, j * s)
                if turn:
                    H = H @ _half_turn_2d(board)
                xi = se2_log(H)
                d = _nearest_turn(xi, board) - check.fit.xi  # the outline looks the same half-turned
                c2 = float(d @ np.linalg.solve(S, d))
                if c2 <= gate:
                    out.append((c2, xi))
    return [xi for _, xi in sorted(out, key=lambda t: t[0])]


def fuse(
    cov_int: np.ndarray, K_int: np.ndarray, check: ShapeCheck, K_shape: np.ndarray
) -> tuple[np.ndarray, ...]:
    """The intensity fit (correction 0, ``cov_int``, coupling ``K_int``) and the outline's
    posterior combined by their information: (correction (3,), covariance (3, 3), coupling (3, 3))."""
    Wi = np.linalg.inv(cov_int)
    Ws = np.linalg.inv(check.fit.cov)
    C = np.linalg.inv(Wi + Ws)
    xi = C @ Ws @ check.fit.xi
    K = C @ (Wi @ K_int + Ws @ K_shape)
    return xi, 0.5 * (C + C.T), K


def slid_message(check: ShapeCheck, board: Board, options: LidarOptions) -> str:
    """Why a pattern fit that the outline contradicts is refused."""
    gate = shape_gate(options)
    square, slide = board.square_size, options.slide_squares
    d = check.fit.xi
    return (
        f"the chessboard pattern fitted to the returns lies {1e3 * np.linalg.norm(d[1:]):.0f} mm and "
        f"{np.degrees(abs(d[0])):.1f} deg off the board's outline (chi-square {check.chi2:.0f}, 3 dof), and "
        "no move by whole squares reconciles them: the pattern fit slid "
        + breach("shape_gate_p chi-square", check.chi2, ">", gate)
        + " "
        + breach("slide_squares", check.shift / square, ">", slide, "squares")
    )


def refuse_outline(shape: ShapeFit, range_m: float, board: Board, options: LidarOptions) -> None:
    """BoardNotFound when an outline fit (no print) is not the board's: returns on its plane outside
    it or rays through it (``min_shape_agreement``), a size the footprints do not explain
    (``ShapeFit.size_ok``), no edge seen along one of its axes (a tall object cut by the beams'
    field looks board-sized), or a posterior that did not settle."""
    x0, x1, y0, y1 = board.extent()
    what = (
        f"a board-sized object at {range_m:.2f} m without a print the LiDAR shows, but its outline is "
        f"not the board's ({x1 - x0:.2f} x {y1 - y0:.2f} m as configured)"
    )
    if shape.agreement < options.min_shape_agreement:
        raise BoardNotFound(
            f"{what}: {shape.bad_in} returns on its plane lie outside the fitted board, {shape.bad_out} "
            f"rays pass through where it would be, of {shape.n_in + shape.n_out} samples near its outline "
            + breach("min_shape_agreement", shape.agreement, "<", options.min_shape_agreement)
        )
    if not shape.size_ok:
        raise BoardNotFound(
            f"{what}: it is {1e3 * abs(shape.growth):.0f} mm {'larger' if shape.growth > 0 else 'smaller'} "
            "on every side (check board.squares, square_size and margin) "
            + breach(
                "outline growth, 3 footprint sigmas and 2 of its own",
                1e3 * abs(shape.growth),
                ">",
                1e3 * (3.0 * shape.growth_prior + 2.0 * shape.growth_sd),
                "mm",
            )
        )
    e = shape.edges_seen
    if not shape.opposite_edges_seen:
        raise BoardNotFound(
            f"a board-sized object at {range_m:.2f} m without a print the LiDAR shows, whose outline the "
            "scan does not show on two opposite sides (beyond the beams, cut off by a cropped scan, or with "
            "nothing behind): its size "
            "and place cannot be told from its shape "
            + breach("rays beside its edges along one axis", float(min(sum(e[:2]), sum(e[2:]))), "<", 1.0)
        )
    if shape.ess < 30:
        raise BoardNotFound(
            f"the board's outline at {range_m:.2f} m could not be fitted (its posterior's effective sample "
            f"size is {shape.ess:.0f}): no trustworthy pose without a print the LiDAR shows "
            + breach("effective sample size", shape.ess, "<", 30.0)
        )


def shape_diagnostics(shape: ShapeFit, check: ShapeCheck | None = None) -> dict[str, float]:
    """The outline fit's numbers for ``BoardFit.diagnostics``; with the check against the pattern,
    its chi-square and the outline's offset from the pattern (the print's place on its backing)."""
    sd = np.sqrt(np.clip(np.diag(shape.cov), 0.0, None))
    out = {
        "shape_agreement": shape.agreement, "shape_ess": shape.ess,
        "shape_n_in": float(shape.n_in), "shape_n_out": float(shape.n_out),
        "sigma_shape_rz_deg": float(np.degrees(sd[0])),
        "sigma_shape_txy_mm": 1e3 * float(np.hypot(sd[1], sd[2])),
        "shape_growth_mm": 1e3 * shape.growth, "sigma_shape_growth_mm": 1e3 * shape.growth_sd,
        "shape_edges_seen": float(sum(n > 0 for n in shape.edges_seen)),
    }  # fmt: skip
    if check is not None:
        d = check.fit.xi
        out.update({
            "shape_chi2": check.chi2, "shape_offset_rz_deg": float(np.degrees(d[0])),
            "shape_offset_x_mm": 1e3 * float(d[1]), "shape_offset_y_mm": 1e3 * float(d[2]),
        })  # fmt: skip
    return out


def _windows(v: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row of v (A, N): the most values a window of ``width`` covers, and the least and the
    largest value it covers."""
    A, N = v.shape
    vs = np.sort(v, axis=1)
    span = float(vs.max() - vs.min()) + width + 1.0
    off = (np.arange(A) * span)[:, None]
    flat = (vs + off).ravel()
    j = (
        np.searchsorted(flat, (vs + off + width).ravel(), side="right").reshape(A, N)
        - np.arange(A)[:, None] * N
    )
    cnt = j - np.arange(N)[None, :]
    k = np.argmax(cnt, axis=1)
    rows = np.arange(A)
    return cnt[rows, k], vs[rows, k], vs[rows, j[rows, k] - 1]


def _xi_of(w: float, shift: np.ndarray) -> np.ndarray:
    """The correction xi (3,) whose board coordinates are ``R(-w) b + shift``: R(xi) = R(w) and
    ``V(w) t = -R(w) shift`` (Pose3.Expmap's SE(2) part)."""
    Rw = np.array([[np.cos(w), -np.sin(w)], [np.sin(w), np.cos(w)]])
    a, e = (np.sin(w) / w, (1 - np.cos(w)) / w) if abs(w) > 1e-9 else (1.0, 0.0)
    V = np.array([[a, -e], [e, a]])
    return np.array([w, *np.linalg.solve(V, -Rw @ shift)])


def outline_start(
    s: OutlineSamples, board: Board, rng: np.random.Generator, step_deg: float = 1.0, max_in: int = 800
) -> list[tuple[np.ndarray, float]]:
    """In-plane corrections xi (3,) that put the board's outline around the returns on its plane,
    found from the outline alone, best first, with their scores; the best of the quarter-turned
    orientation (about 90 deg from the best) comes second.

    Every angle of a half turn (the outline looks the same after one) is tried: the returns are
    turned by it, and along each axis the board's side (its extent incl. margin) is slid to cover
    as many as possible; the score is that count less twice the rays that pass inside the board
    placed in the middle. For the best angle and its quarter turn, the shift is then chosen among
    those that cover the same returns (a grid over them) by the outline's likelihood: where part of
    the board is not scanned, the rays passing beside the scanned part place it.
    """
    b_in, b_out = s.b[s.inside], s.b[~s.inside]
    if b_in.shape[0] > max_in:
        b_in = b_in[rng.choice(b_in.shape[0], max_in, replace=False)]
    if b_out.shape[0] > max_in:
        b_out = b_out[rng.choice(b_out.shape[0], max_in, replace=False)]
    x0, x1, y0, y1 = board.extent()
    ang = np.deg2rad(np.arange(0.0, 180.0, step_deg))
    c, sn = np.cos(ang)[:, None], np.sin(ang)[:, None]
    # board coordinates of the returns under a turn by ang (before the shift): R(-ang) b
    X, Y = c * b_in[:, 0] + sn * b_in[:, 1], c * b_in[:, 1] - sn * b_in[:, 0]
    nx, lox, hix = _windows(X, x1 - x0)
    ny, loy, hiy = _windows(Y, y1 - y0)
    Xo, Yo = c * b_out[:, 0] + sn * b_out[:, 1], c * b_out[:, 1] - sn * b_out[:, 0]
    # the board flush with the covered returns' low end, centred on them, or flush with the high
    # end, along each axis (a board partly outside the beams is flush with its scanned part)
    inner = np.full(len(ang), np.inf)
    for fx in (0.0, 0.5, 1.0):
        for fy in (0.0, 0.5, 1.0):
            sx = (1 - fx) * (x0 - lox) + fx * (x1 - hix)
            sy = (1 - fy) * (y0 - loy) + fy * (y1 - hiy)
            Xs, Ys = Xo + sx[:, None], Yo + sy[:, None]
            n_in = ((Xs > x0 + 0.01) & (Xs < x1 - 0.01) & (Ys > y0 + 0.01) & (Ys < y1 - 0.01)).sum(axis=1)
            inner = np.minimum(inner, n_in)
    score = (nx + ny - 2 * inner).astype(np.float64)
    order = np.argsort(-score)
    best = int(order[0])
    rival = [int(k) for k in order if abs(((ang[k] - ang[best]) % np.pi) - np.pi / 2) < np.deg2rad(20)][:1]
    out = []
    for k in [best, *rival]:
        # shifts that keep the covered returns inside: x0 <= X + sx <= x1 for X in [lox, hix]
        gx = np.linspace(x0 - lox[k], x1 - hix[k], 7)
        gy = np.linspace(y0 - loy[k], y1 - hiy[k], 7)
        cand = np.array([_xi_of(float(ang[k]), np.array([a, b])) for a in gx for b in gy])
        f = outline_loglik(cand, s, board)
        out.append((cand[int(np.argmax(f))], float(score[k])))
    return out
