"""Uncertainty of the board pose: the plane fit, the edges' sampling, and how they combine.

Out-of-plane (rx, ry, tz): the board-frame heights of the points, ``z = tz + rx y - ry x`` to first
order (plus an offset of the returns from black print), fitted by least squares; covariance the
larger of the iid and the ring-clustered sandwich estimate (per-beam range biases).

In-plane (rz, tx, ty): the soft-edged refinement's covariance (``soft_edge.py``) plus the
quantisation of the edges by the scan's sampling (:func:`sampling_covariance`).

Both in GTSAM's Pose3 tangent at the estimate, ``T_true = T_est * Expmap(xi)``,
``xi = (rx, ry, rz, tx, ty, tz)``. The two come from independent data (intensity vs range), but the
returns are put on the fitted plane along their rays, so a plane error displaces the pattern the
intensity fit sees: that coupling is propagated (:func:`ray_coupling`, :func:`assemble_covariance`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..board import Board

__all__ = ["PlaneFit", "assemble_covariance", "plane_fit", "ray_coupling", "sampling_covariance"]


def sampling_covariance(
    b: np.ndarray, cls: np.ndarray, ring: np.ndarray, board: Board, blur: float
) -> np.ndarray:
    """Covariance of (rz, tx, ty) from where the scan samples the pattern's edges (quantisation).

    An edge between two neighbouring returns of different colour is only known to lie between
    them: a uniform error over the gap ``delta`` along the edge's normal, less the part the two
    footprints resolve, variance ``max(delta^2 - (2 blur)^2, (delta/10)^2) / 12``. Pairs crossing
    the same grid line between the same two rings share that error and count once (mean gap,
    mean position). For a board whose edges run along the scanlines this is what bounds the
    position across them; the soft model's Hessian cannot see it.

    b: (N, 2) board coordinates of the returns, cls: (N,) intensity class (0/1, -1 gray),
    ring: (N,) beam index, blur: footprint sigma (m). Returns (3, 3), or an all-inf matrix when no
    edge is crossed at all.
    """
    n = b.shape[0]
    if n < 3:
        return np.full((3, 3), np.inf)
    s = board.square_size
    i, j = _beam_neighbours(b, ring)
    if i.size == 0:
        return np.full((3, 3), np.inf)
    keep = (i != j) & (cls[i] >= 0) & (cls[j] >= 0) & (cls[i] != cls[j])
    i, j = i[keep], j[keep]
    rows = []
    for axis, n_lines in ((0, board.cols), (1, board.rows)):
        ki, kj = np.floor(b[i, axis] / s), np.floor(b[j, axis] / s)
        other = 1 - axis
        lim_o = board.rows * s if axis == 0 else board.cols * s
        mid = 0.5 * (b[i] + b[j])
        line = np.maximum(ki, kj)
        ok = (np.abs(ki - kj) == 1) & (line >= 1) & (line <= n_lines - 1)
        ok &= (mid[:, other] >= 0) & (mid[:, other] <= lim_o)
        if not np.any(ok):
            continue
        gap = np.abs(b[i, axis] - b[j, axis])[ok]
        ra, rb = np.minimum(ring[i], ring[j])[ok], np.maximum(ring[i], ring[j])[ok]
        key = (line[ok].astype(np.int64) * 4096 + ra) * 4096 + rb
        _, grp = np.unique(key, return_inverse=True)
        cnt = np.bincount(grp)
        g_gap = np.sqrt(np.bincount(grp, gap**2) / cnt)
        g_mid = np.stack([np.bincount(grp, mid[ok, 0]) / cnt, np.bincount(grp, mid[ok, 1]) / cnt], axis=1)
        var = np.maximum(g_gap**2 - (2 * blur) ** 2, (0.1 * g_gap) ** 2) / 12.0
        # d(point coordinate along the line's normal)/d(rz, tx, ty) for b' = Exp(-xi) b
        J = np.zeros((len(cnt), 3))
        if axis == 0:
            J[:, 0], J[:, 1] = g_mid[:, 1], -1.0
        else:
            J[:, 0], J[:, 2] = -g_mid[:, 0], -1.0
        rows.append((J, var))
    if not rows:
        return np.full((3, 3), np.inf)
    J = np.concatenate([r[0] for r in rows])
    var = np.concatenate([r[1] for r in rows])
    info = (J / var[:, None]).T @ J
    try:
        return np.linalg.inv(info + 1e-12 * np.eye(3))
    except np.linalg.LinAlgError:
        return np.full((3, 3), np.inf)


def _beam_neighbours(b: np.ndarray, ring: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j) of returns ``b`` (N, 2) on beams ``ring`` (N,): each return with its
    nearest returns on its own beam (up to three, itself among them) and its two nearest on the
    next beam up (index + 1), by distance in the board's plane; a beam of one return has no pairs
    along it and is no beam's next. Beam by beam in increasing order (own beam, then the next), each
    return's neighbours nearest first.

    Rings are far apart compared with the spacing along them, so plain nearest neighbours would
    never pair returns across rings: one k-d tree over (x, y, beam * gap), ``gap`` a power of two
    larger than four times the returns' extent, so every other beam lies farther than any return
    of the queried one while a distance within a beam is the plane's own (the beam term is exactly 0).
    """
    from scipy.spatial import cKDTree

    n = b.shape[0]
    empty = np.zeros(0, dtype=np.int64)
    if n == 0:
        return empty, empty
    beams, of, count = np.unique(ring, return_inverse=True, return_counts=True)
    of = of.reshape(-1)
    extent = float(np.max(np.ptp(b, axis=0)))
    gap = 2.0 ** math.ceil(math.log2(4.0 * extent + 1.0))
    xyz = np.column_stack([b, beams.astype(np.float64)[of] * gap])
    tree = cKDTree(xyz)
    own = tree.query(xyz, k=min(3, n))[1].reshape(n, -1)
    up_at = np.minimum(np.searchsorted(beams, beams + 1), beams.size - 1)
    has_up = (beams[up_at] == beams + 1) & (count[up_at] >= 2)
    asks = has_up[of]
    up_row = np.cumsum(asks) - 1
    up = tree.query(xyz[asks] + np.array([0.0, 0.0, gap]), k=2)[1].reshape(-1, 2) if np.any(asks) else None
    members = np.argsort(of, kind="stable")
    starts = np.cumsum(count) - count
    pi, pj = [], []
    for g in range(beams.size):
        ix = members[starts[g] : starts[g] + count[g]]
        if count[g] >= 2:
            kk = min(3, int(count[g]))
            pi.append(np.repeat(ix, kk))
            pj.append(own[ix, :kk].reshape(-1))
        if has_up[g]:
            assert up is not None
            pi.append(np.repeat(ix, 2))
            pj.append(up[up_row[ix]].reshape(-1))
    if not pi:
        return empty, empty
    return np.concatenate(pi), np.concatenate(pj)


@dataclass(frozen=True)
class PlaneFit:
    """Least-squares plane of the board's returns in a board frame.

    coef: (rx, ry, tz, delta): the board frame's correction ``z = tz + rx y - ry x`` (first order)
    and ``delta`` the extra height of returns from black print (negative: they read long).
    cov: (3, 3) covariance of (rx, ry, tz); sigma: robust residual sigma (m);
    clustered: True when the ring jackknife was the larger in some direction.
    """

    coef: np.ndarray
    cov: np.ndarray
    sigma: float
    clustered: bool


def plane_fit(b_xyz: np.ndarray, black: np.ndarray | None = None, ring: np.ndarray | None = None) -> PlaneFit:
    """Fit the white print's plane to board-frame points, with a dark-print offset, and its covariance.

    b_xyz: (N, 3) returns in the current board frame. black: (N,) bool, returns on black print
    (their range may differ: LiDARs read dark targets long), or None. ring: (N,) beam index, or None.

    The covariance of (rx, ry, tz) is the larger, in every direction, of the iid one
    ``s^2 (A^T A)^-1`` and the delete-one-ring jackknife
    ``(G-1)/G sum_g (beta_-g - mean)(beta_-g - mean)^T``: a range
    bias shared by one beam's returns (every beam has its own) tilts the plane the same way for all
    of them, which independent errors cannot describe.
    """
    x, y, z = b_xyz[:, 0], b_xyz[:, 1], b_xyz[:, 2]
    cols = [y, -x, np.ones_like(x)]
    dark = black if black is not None and 0.1 < float(np.mean(black)) < 0.9 else None
    use_dark = dark is not None
    if dark is not None:
        cols.append(dark.astype(np.float64))
    A = np.column_stack(cols)
    sol, *_ = np.linalg.lstsq(A, z, rcond=None)
    res = z - A @ sol
    s = max(1.4826 * float(np.median(np.abs(res - np.median(res)))), 1e-5)
    # Huber reweighting once, against stray returns (edge mixtures, a hand)
    w = np.minimum(1.0, 2.5 * s / np.maximum(np.abs(res), 1e-12))
    Aw = A * w[:, None]
    sol = np.linalg.solve(Aw.T @ A, Aw.T @ z)
    res = z - A @ sol
    Ninv = np.linalg.inv(Aw.T @ A)
    cov = s**2 * Ninv @ (Aw.T @ Aw) @ Ninv
    clustered = False
    if ring is not None:
        groups = np.unique(ring, return_inverse=True)[1]
        g = int(groups.max()) + 1
        if g >= 4:
            # delete-one-ring jackknife (less biased than the plain clustered sandwich with few rings)
            p = A.shape[1]
            Ng = np.zeros((g, p, p))
            np.add.at(Ng, groups, Aw[:, :, None] * A[:, None, :])
            bg = np.zeros((g, p))
            np.add.at(bg, groups, Aw * z[:, None])
            Nt, bt = Ng.sum(axis=0), bg.sum(axis=0)
            try:
                beta = np.linalg.solve(Nt[None] - Ng, (bt[None] - bg)[..., None])[..., 0]
                dev = beta - beta.mean(axis=0)
                cov_c = dev.T @ dev * (g - 1) / g
                # the larger of the two in every direction (a few rings make the jackknife alone
                # nearly singular in some direction): C_iid^1/2 V max(L, 1) V^T C_iid^1/2
                w, V = np.linalg.eigh(cov)
                half = V @ np.diag(np.sqrt(np.maximum(w, 1e-30))) @ V.T
                ihalf = V @ np.diag(1.0 / np.sqrt(np.maximum(w, 1e-30))) @ V.T
                lam, U = np.linalg.eigh(ihalf @ cov_c @ ihalf)
                clustered = bool(lam.max() > 1.0)
                cov = half @ U @ np.diag(np.maximum(lam, 1.0)) @ U.T @ half
            except np.linalg.LinAlgError:
                pass
    coef = np.append(sol, 0.0) if not use_dark else sol
    return PlaneFit(coef, cov[:3, :3], s, clustered)


def ray_coupling(b_xy: np.ndarray, u_board: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """K (3, 3): in-plane error (rz, tx, ty) caused by a plane error (rx, ry, tz), ray projection.

    A true board point sits at height ``h = tz + rx y - ry x`` above the fitted plane (board frame,
    first order). Moved along its ray ``u`` onto the plane it lands ``v = -h u_xy / u_z`` away, so
    the pattern the intensity fit sees is displaced by the field v; the fit follows the rigid part
    of it (weighted by where the fit takes its information from, ``weight``), and the in-plane
    error is minus that rigid motion: ``e_in = e_intensity + K e_plane``.

    b_xy: (N, 2) board coordinates, u_board: (N, 3) unit ray directions in the board frame,
    weight: (N,) non-negative.
    """
    x, y = b_xy[:, 0], b_xy[:, 1]
    uz = np.where(np.abs(u_board[:, 2]) > 0.1, u_board[:, 2], np.sign(u_board[:, 2] + 1e-12) * 0.1)
    sx, sy = u_board[:, 0] / uz, u_board[:, 1] / uz
    # rigid in-plane motion of a point: (-rz y + tx, rz x + ty)
    D = np.zeros((2 * len(x), 3))
    D[0::2, 0], D[0::2, 1] = -y, 1.0
    D[1::2, 0], D[1::2, 2] = x, 1.0
    w2 = np.repeat(np.maximum(weight, 0.0), 2) + 1e-12
    N = (D * w2[:, None]).T @ D
    K = np.zeros((3, 3))
    for k, h in enumerate((y, -x, np.ones_like(x))):  # d h / d (rx, ry, tz)
        v = np.empty(2 * len(x))
        v[0::2], v[1::2] = -h * sx, -h * sy
        K[:, k] = -np.linalg.solve(N, (D * w2[:, None]).T @ v)
    return K


def assemble_covariance(cov_out: np.ndarray, cov_in: np.ndarray, K: np.ndarray | None = None) -> np.ndarray:
    """(6, 6) Pose3 covariance (rx, ry, rz, tx, ty, tz) from (rx, ry, tz) and (rz, tx, ty) blocks.

    With the coupling K (see :func:`ray_coupling`) the in-plane error is ``e_in + K e_out``:
    in-plane block ``cov_in + K cov_out K^T`` and cross block ``K cov_out``.
    """
    C = np.zeros((6, 6))
    io, ii = [0, 1, 5], [2, 3, 4]
    C[np.ix_(io, io)] = cov_out
    if K is None:
        C[np.ix_(ii, ii)] = cov_in
    else:
        C[np.ix_(ii, ii)] = cov_in + K @ cov_out @ K.T
        C[np.ix_(ii, io)] = K @ cov_out
        C[np.ix_(io, ii)] = (K @ cov_out).T
    return 0.5 * (C + C.T)
