"""The board's outline as evidence of its in-plane pose (rz, tx, ty), with or without a visible print.

Every ray of the scan that crosses the board's plane near the board samples the board's occupancy
at its crossing point (moved onto the plane along the ray, so range noise does not move it):

- **in**: the return lies on the plane (within ``thr_in``): the board is there;
- **out**: the return lies well behind the plane (``thr_out``): the ray passed where the board is not;
  so does a ray a beam fired there that returned nothing at all (``silent.silent_rays``: the sky, an
  open scene), counted as lost with the share the LiDAR loses on the board;
- a return in front of the plane (an occluder: a hand, a person) or just behind it says nothing, and
  rays the beams never fired (above the top beam, below the lowest) are no samples at all: the
  unscanned part of a board is unknown, not empty.

Likelihood (a soft-edged occupancy model): ``P(in | b) = Phi(d(b) / sigma_i)`` made robust (below),
``d`` the signed distance of the crossing from the outline of the physical board (margin included,
positive inside), in the board frame moved by ``xi = (rz, tx, ty)`` (GTSAM's Pose3 tangent,
``T = T0 * Expmap((0, 0, rz, tx, ty, 0))``); ``sigma_i`` from the beam's footprint, the in-plane
noise and, for returns on the board, the plane noise seen through the incidence angle. A return on
the plane outside the board may be something else (``EPS_IN``: a stand's head, a clamp), a ray
through the board a glitch (``EPS_OUT``, rarer). Between the last return on the board and the next
sample of a scanline the likelihood is flat: the posterior is the set of poses that put the
outline between them, which is what the scan determines (a VLP-16's few rings along a board's
edges leave its position across them known to a ring spacing). Its mean and covariance come from
adaptive importance sampling (:func:`outline_posterior`), not from a curvature: a flat-topped
posterior has none. :func:`outline_start` finds the in-plane pose from the outline alone (no print
needed; up to the half turn, and to a quarter turn on a square board).
Frames: the board frame of the pose the samples were taken in, metres, radians.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np
from scipy.special import ndtr

from ..board import Board
from ..lidars import LidarModel
from .silent import silent_rays

__all__ = [
    "OutlineSamples",
    "edge_z",
    "growth_prior",
    "outline_mode",
    "ShapeFit",
    "outline_loglik",
    "outline_posterior",
    "outline_samples",
    "signed_distance",
]

#: smallest in-plane sigma of a sample (m)
SIGMA_MIN_M = 0.001
#: extra sigma (m) of the smoothed likelihood whose mode and curvature scale the importance sampling
TEMPER_M = 0.004
#: the chance that a return on the board's plane outside the board is something else (a stand's head,
#: a clamp, coplanar clutter: common), and that a ray passes where the board is (rare: a hole)
EPS_IN, EPS_OUT = 0.05, 0.01
#: beam diameter at the sensor (m) for the footprint (most spinning LiDARs: 5-15 mm)
APERTURE_M = 0.01


@dataclass(frozen=True)
class OutlineSamples:
    """Rays crossing the board's plane near the board, in the board frame of the pose ``T``.

    b: (N, 2) crossing points (m). inside: (N,) True for a return on the plane, False for a ray that
    passed it. sigma: (N, 2) in-plane sigma of each along the board's x and y (m; a return's height
    noise moves its crossing along the ray's own in-plane direction). u: (N, 3) unit ray directions.
    n_front: returns in front of the plane there (occluders, not used). foot: (N,) footprint radius (m).
    eps: (N,) the chance that the sample says nothing about the board (``outline_loglik``).
    """

    b: np.ndarray
    inside: np.ndarray
    sigma: np.ndarray
    u: np.ndarray
    n_front: int
    foot: np.ndarray
    eps: np.ndarray

    def subset(self, keep: np.ndarray) -> OutlineSamples:
        """The samples ``keep`` (bool or index array)."""
        return OutlineSamples(
            self.b[keep], self.inside[keep], self.sigma[keep], self.u[keep], self.n_front, self.foot[keep],
            self.eps[keep],
        )  # fmt: skip

    def widened(self, extra: float) -> OutlineSamples:
        """The same samples with every sigma widened by ``extra`` (m), in quadrature."""
        return OutlineSamples(self.b, self.inside, np.sqrt(self.sigma**2 + extra**2), self.u, self.n_front,
                              self.foot, self.eps)  # fmt: skip


def outline_samples(
    points: np.ndarray,
    T: np.ndarray,
    board: Board,
    model: LidarModel,
    sigma_z: float,
    blur: float = 0.1,
    grow: float | None = None,
) -> OutlineSamples:
    """The in/out samples of the scan's points (N, 3) (LiDAR frame) about the board at ``T`` (4, 4).

    sigma_z: the returns' noise along the board's normal (m): sets the in/out thresholds
    (``thr_in = max(3 cm, 3 sigma_z)``, ``thr_out = max(6 cm, 2 thr_in)``) and, seen through the
    incidence angle, the in-plane noise of a return on the plane. blur: the footprint's share
    of the edge's blur, in footprint radii. grow: how far beyond the board's outline rays are
    taken (m; None: 2.5 ring spacings at the board's range, 15-60 cm).
    """
    R, t = T[:3, :3], T[:3, 3]
    P = np.asarray(points, dtype=np.float64)
    # the beams leave from their own origin (an Ouster's lies ~36 mm above its points' origin): a ray
    # that passed the board and returned from a wall metres behind crosses the board's plane where
    # that origin's ray does, not the points' origin's
    o = np.array([0.0, 0.0, float(model.beam_origin_z_m)])
    r = np.linalg.norm(P - o, axis=1)
    ok = r > 1e-6
    P, r = P[ok], r[ok]
    ub = ((P - o) / r[:, None]) @ R  # ray directions in the board frame
    ob = (o - t) @ R  # the beams' origin in the board frame (z > 0: in front)
    pz = P @ R[:, 2] - t @ R[:, 2]  # height of each return above the plane
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(ub[:, 2] < -0.1, -ob[2] / ub[:, 2], -1.0)
    c = ob[:2] + lam[:, None] * ub[:, :2]
    x0, x1, y0, y1 = board.extent()
    dist = float(np.linalg.norm(R @ board.pattern_centre + t))
    if grow is None:  # (a scanline-free pattern is dense everywhere: its table is its field's cone)
        el = np.sort(model.vertical_angles_rad)
        gap = float(np.median(np.diff(el))) if el.size > 1 and not model.ringless else np.deg2rad(0.5)
        grow = min(max(0.15, 2.5 * dist * gap), 0.6)
    near = (lam > 0.3) & (c[:, 0] > x0 - grow) & (c[:, 0] < x1 + grow) & (c[:, 1] > y0 - grow)
    near &= c[:, 1] < y1 + grow
    thr_in = max(0.03, 3.0 * sigma_z)
    thr_out = max(0.06, 2.0 * thr_in)
    inside = near & (np.abs(pz) < thr_in)
    out = near & (pz < -thr_out)
    silent, lost = silent_rays(P - o, inside, T, o, board, model, grow)
    keep = inside | out
    n_silent = len(silent)
    ub = np.vstack([ub[keep], silent])
    c = np.vstack([c[keep], ob[:2] - (ob[2] / silent[:, 2])[:, None] * silent[:, :2]])
    lam_k = np.concatenate([lam[keep], -ob[2] / silent[:, 2]])
    pz_k = np.concatenate([pz[keep], np.full(n_silent, -np.inf)])
    inside_k = np.concatenate([inside[keep], np.zeros(n_silent, bool)])
    u = ub
    slope = np.abs(u[:, :2]) / np.abs(u[:, 2:3])  # in-plane shift per unit of height, along x and y
    foot = 0.5 * (APERTURE_M + model.beam_divergence_rad * lam_k)
    var = (
        SIGMA_MIN_M**2
        + (blur * foot[:, None]) ** 2
        + np.where(inside_k[:, None], (sigma_z * slope) ** 2, 0.0)
    )
    # a return on the plane may be an attachment (a stand's head, a clamp) rather than the board: the
    # farther behind the board's plane it lies (in its noise), the likelier
    h = pz_k / max(sigma_z, 1e-4)
    behind = np.where(h < 0, 1.0 - np.exp(-0.5 * np.minimum(h * h, 1e6)), 0.0)
    eps = np.where(inside_k, EPS_IN + (1.0 - EPS_IN) * behind, EPS_OUT)
    eps[len(eps) - n_silent :] = max(EPS_OUT, lost)  # a ray without return: passed, or lost
    return OutlineSamples(c, inside_k, np.sqrt(var), u, int((near & (pz > thr_in)).sum()), foot, eps)


def _moved(xis: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, N) board coordinates x, y of the points b (N, 2) for each in-plane correction xi (M, 3):
    ``b' = Exp(xi)^-1 b`` (SE(2) part of Pose3.Expmap)."""
    xis = np.atleast_2d(xis)
    w, tx, ty = xis[:, 0], xis[:, 1], xis[:, 2]
    small = np.abs(w) < 1e-9
    ws = np.where(small, 1.0, w)
    a = np.where(small, 1.0, np.sin(ws) / ws)
    e = np.where(small, 0.5 * w, (1.0 - np.cos(ws)) / ws)
    vx, vy = a * tx - e * ty, e * tx + a * ty
    cw, sw = np.cos(w)[:, None], np.sin(w)[:, None]
    dx, dy = b[None, :, 0] - vx[:, None], b[None, :, 1] - vy[:, None]
    return cw * dx + sw * dy, cw * dy - sw * dx


def signed_distance(xis: np.ndarray, b: np.ndarray, board: Board) -> np.ndarray:
    """(M, N) signed distance (m, positive inside) of the points b (N, 2) from the board's outline,
    for each in-plane correction xi (M, 3)."""
    x, y = _moved(xis, b)
    x0, x1, y0, y1 = board.extent()
    return np.minimum(np.minimum(x - x0, x1 - x), np.minimum(y - y0, y1 - y))


def edge_z(xis: np.ndarray, s: OutlineSamples, board: Board) -> np.ndarray:
    """(M, N) signed distance from the outline in sigmas of each sample (the x edges' distance in its
    sigma along x, the y edges' along y; the nearest edge counts), for corrections xi (M, 3) or (M, 4)
    with the outline's growth."""
    xis = np.atleast_2d(xis)
    x, y = _moved(xis[:, :3], s.b)
    g = xis[:, 3:4] if xis.shape[1] > 3 else 0.0
    x0, x1, y0, y1 = board.extent()
    zx = (np.minimum(x - x0, x1 - x) + g) / s.sigma[:, 0]
    zy = (np.minimum(y - y0, y1 - y) + g) / s.sigma[:, 1]
    return np.minimum(zx, zy)


def outline_loglik(
    xis: np.ndarray, s: OutlineSamples, board: Board, growth_sd: float | None = None
) -> np.ndarray:
    """(M,) log-likelihood of the samples for each in-plane correction xi (M, 3), or (M, 4) with the
    outline's growth g (m, the board as the beams see it larger by g on every side: footprints that
    straddle the edge return from the board) and its zero-mean prior of sigma ``growth_sd``: a return
    on the plane ``eps + (1 - eps) Phi(d / sigma)``, a ray that passed ``eps + (1 - eps) Phi(-d / sigma)``
    (``eps``: ``EPS_IN``, more for a return behind the plane, ``EPS_OUT``)."""
    xis = np.atleast_2d(xis)
    z = edge_z(xis, s, board)
    p = ndtr(np.where(s.inside, z, -z))
    out = np.log(s.eps + (1.0 - s.eps) * p).sum(axis=1)
    if xis.shape[1] > 3 and growth_sd:
        out = out - 0.5 * (xis[:, 3] / growth_sd) ** 2
    return out


@dataclass(frozen=True)
class ShapeFit:
    """The outline's posterior of the in-plane correction (board frame of the samples' pose).

    xi: (3,) posterior mean (rz, tx, ty). cov: (3, 3) posterior covariance (the outline's growth
    marginalised). growth, growth_sd: the outline's growth (m; the board as the beams see it is
    larger by this on every side), its posterior sigma and its prior sigma. log_evidence: log of the mean
    likelihood under the proposal (for comparing orientations). ess: effective sample size of the
    last round. n_in, n_out: samples that took part (near the outline). bad_in, bad_out: returns on
    the plane clearly outside the board, rays that passed clearly inside it (3 sigma and 1 cm
    beyond the outline), at the mean. edges_seen: rays passing just outside each edge (x0, x1, y0,
    y1 of ``Board.extent``): an edge without any was not seen (beyond the beams, empty background).
    """

    xi: np.ndarray
    cov: np.ndarray
    growth: float
    growth_sd: float
    growth_prior: float
    log_evidence: float
    ess: float
    n_in: int
    n_out: int
    bad_in: int
    bad_out: int
    edges_seen: tuple[int, int, int, int] = (0, 0, 0, 0)

    @property
    def size_ok(self) -> bool:
        """The outline's growth within what footprints explain (3 prior sigmas, and 2 of its own)."""
        return abs(self.growth) <= 3.0 * self.growth_prior + 2.0 * self.growth_sd

    @property
    def opposite_edges_seen(self) -> bool:
        """At least one edge seen along each of the board's two axes."""
        e = self.edges_seen
        return (e[0] > 0 or e[1] > 0) and (e[2] > 0 or e[3] > 0)

    @property
    def agreement(self) -> float:
        """Share of the samples near the outline that the fitted board explains."""
        n = max(self.n_in + self.n_out, 1)
        return 1.0 - (self.bad_in + self.bad_out) / n


def _stencil(h: np.ndarray) -> np.ndarray:
    """(1 + 2n + 2n(n-1), n) offsets of the central-difference stencil for a gradient and Hessian
    with steps h (n,)."""
    n = len(h)
    rows = [np.zeros(n)]
    for k in range(n):
        for sg in (1.0, -1.0):
            e = np.zeros(n)
            e[k] = sg * h[k]
            rows.append(e)
    for i in range(n):
        for j in range(i + 1, n):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                e = np.zeros(n)
                e[i], e[j] = si * h[i], sj * h[j]
                rows.append(e)
    return np.array(rows)


def _grad_hess(f: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient and Hessian from the function values f on ``_stencil(h)``."""
    n = len(h)
    g, H = np.zeros(n), np.zeros((n, n))
    for k in range(n):
        fp, fm = f[1 + 2 * k], f[2 + 2 * k]
        g[k] = (fp - fm) / (2 * h[k])
        H[k, k] = (fp - 2 * f[0] + fm) / h[k] ** 2
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    for m, (i, j) in enumerate(pairs):
        fpp, fpm, fmp, fmm = f[1 + 2 * n + 4 * m : 5 + 2 * n + 4 * m]
        H[i, j] = H[j, i] = (fpp - fpm - fmp + fmm) / (4 * h[i] * h[j])
    return g, H


def _mode(fun: Callable[[np.ndarray], np.ndarray], mu: np.ndarray, h: np.ndarray,
          max_var: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Newton's method on ``fun`` (a log-density of (M, n) points; central differences, all stencil
    points at once), each step at most ``sqrt(max_var) / 5`` per coordinate and searched along its
    line: the mode and the negative inverse Hessian there (eigenvalues clipped to ``max_var``)."""
    st = _stencil(h)
    S = np.diag(max_var)
    trust = np.sqrt(max_var) / 5.0
    for _ in range(30):
        g, H = _grad_hess(fun(mu + st), h)
        lam, V = np.linalg.eigh(-H)
        lam = np.maximum(lam, 1.0 / max_var.max())
        S = V @ np.diag(1.0 / lam) @ V.T
        step = S @ g
        step *= min(1.0, float(np.min(trust / np.maximum(np.abs(step), 1e-15))))
        alphas = np.array([1.0, 0.5, 0.25, 0.1, 0.03, 0.0])
        f = fun(mu + alphas[:, None] * step)
        k = int(np.argmax(f))
        mu = mu + alphas[k] * step
        if alphas[k] == 0.0 or np.all(np.abs(alphas[k] * step) < 0.05 * h):
            break
    return mu, 0.5 * (S + S.T)


def _importance(
    fun: Callable[[np.ndarray], np.ndarray],
    mu: np.ndarray,
    C: np.ndarray,
    rng: np.random.Generator,
    n_draws: int,
    max_rounds: int = 8,
    dof: float = 4.0,
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Moments of the density ``exp(fun)`` by importance sampling from a Student-t about (mu, C),
    twice as wide, each round about the last's weighted moments (when few draws carry the weight,
    the proposal shrinks by at most 4 in variance per round), until a fifth of the draws carry it
    (at least two rounds). Returns (mean, covariance, log of the mean weight, effective sample size
    of the last round)."""
    n = len(mu)
    floor = np.eye(n) * 1e-14
    lw, w, ess = np.zeros(1), np.ones(1), 1.0
    for r in range(max_rounds):
        Lc = np.linalg.cholesky(2.0 * C + floor)
        z = rng.standard_normal((n_draws, n))
        g = rng.chisquare(dof, n_draws) / dof
        X = mu + (z / np.sqrt(g)[:, None]) @ Lc.T
        m = np.linalg.solve(Lc, (X - mu).T)
        logq = -0.5 * (dof + n) * np.log1p((m * m).sum(axis=0) / dof) - np.log(np.diag(Lc)).sum()
        lw = fun(X) - logq
        w = np.exp(lw - lw.max())
        w /= w.sum()
        ess = float(1.0 / np.sum(w**2))
        mu = w @ X
        d = X - mu
        C_w = (d * w[:, None]).T @ d
        if r >= 1 and ess >= 0.2 * n_draws:
            C = C_w
            break
        C = C_w + C / 4.0
    log_ev = float(np.log(np.mean(np.exp(lw - lw.max()))) + lw.max())
    return mu, C, log_ev, ess


def growth_prior(s: OutlineSamples) -> float:
    """Prior sigma of the outline's growth (m): the samples' median footprint radius, at least 2 mm."""
    return max(0.002, float(np.median(s.foot))) if len(s.foot) else 0.002


def _edges_seen(
    xi: np.ndarray, s: OutlineSamples, board: Board, band: float = 0.05
) -> tuple[int, int, int, int]:
    """Rays that passed within ``band`` (m) outside each edge (x0, x1, y0, y1) at the correction xi,
    and not beyond the neighbouring edges."""
    x, y = (v[0] for v in _moved(xi, s.b[~s.inside]))
    x0, x1, y0, y1 = board.extent()
    along_x, along_y = (x > x0) & (x < x1), (y > y0) & (y < y1)
    return (
        int((along_y & (x < x0) & (x > x0 - band)).sum()), int((along_y & (x > x1) & (x < x1 + band)).sum()),
        int((along_x & (y < y0) & (y > y0 - band)).sum()), int((along_x & (y > y1) & (y < y1 + band)).sum()),
    )  # fmt: skip


def outline_mode(
    s: OutlineSamples, board: Board, xi0: np.ndarray | None = None,
    scale0: tuple[float, float] = (np.deg2rad(1.5), 0.03), growth_sd: float | None = None,
) -> tuple[np.ndarray, np.ndarray, OutlineSamples, float]:  # fmt: skip
    """The mode of the outline's posterior (rz, tx, ty, growth) from ``xi0`` by Newton's method on a
    smoothed likelihood (every sample's sigma widened by ``TEMPER_M``, so that the walls an exact
    pass-through sets are smooth enough), its negative inverse Hessian, the samples within reach of
    the outline there, and the growth's prior sigma. scale0 (rz rad, translation m) bounds the steps
    and which samples take part."""
    mu = np.zeros(3) if xi0 is None else np.asarray(xi0, np.float64)[:3].copy()
    x0, x1, y0, y1 = board.extent()
    half_diag = 0.5 * float(np.hypot(x1 - x0, y1 - y0))
    reach = 4.0 * (scale0[1] + half_diag * scale0[0]) + 4.0 * s.sigma.max(axis=1)
    sub = s.subset(np.abs(signed_distance(mu, s.b, board)[0]) < reach)
    g_sd = growth_prior(s) if growth_sd is None else growth_sd
    soft = sub.widened(TEMPER_M)
    h_t = 0.3 * float(np.median(soft.sigma)) if len(soft.sigma) else 0.003
    h = np.array([h_t / half_diag, h_t, h_t, h_t])
    max_var = np.array([scale0[0] ** 2, scale0[1] ** 2, scale0[1] ** 2, g_sd**2]) * 25.0
    mu, S = _mode(lambda X: outline_loglik(X, soft, board, g_sd), np.append(mu, 0.0), h, max_var)
    sd = np.sqrt(np.diag(S))
    band = 8.0 * (sd[1:3].max() + half_diag * sd[0]) + 4.0 * sub.sigma.max(axis=1)
    return mu, S, sub.subset(np.abs(signed_distance(mu[:3], sub.b, board)[0]) < band), g_sd


def outline_posterior(
    s: OutlineSamples,
    board: Board,
    rng: np.random.Generator,
    xi0: np.ndarray | None = None,
    scale0: tuple[float, float] = (np.deg2rad(1.5), 0.03),
    n_draws: int = 300,
    growth_sd: float | None = None,
) -> ShapeFit:
    """Posterior mean and covariance of the in-plane correction (flat prior) and the outline's growth.

    The mode and curvature (:func:`outline_mode`, from ``xi0``) give the proposal of importance
    sampling (:func:`_importance`): on a flat-topped posterior (an edge between two samples) the
    moments are the top's, which the curvature at the mode is not. When few draws carry the weight
    (the mass lies away from that mode), the mode is sought again from the weighted mean (twice).

    growth_sd: the prior sigma of the outline's growth (m; None: ``growth_prior``). Only samples
    within reach of the outline take part (the others' likelihood does not change over the
    proposal's range).
    """
    start, tries = xi0, 1
    while True:  # when the mass lies away from the mode found (a far corner of a flat top), again
        mu, S, sub, g_sd = outline_mode(s, board, start, scale0, growth_sd)
        fun = partial(outline_loglik, s=sub, board=board, growth_sd=g_sd)
        mu, C, log_ev, ess = _importance(fun, mu, S, rng, n_draws)
        if ess >= 0.1 * n_draws or tries == 3:
            break
        start, tries = mu[:3], tries + 1
    dm = signed_distance(mu[:3], sub.b, board)[0] + mu[3]
    margin = 3.0 * sub.sigma.max(axis=1) + 0.01
    return ShapeFit(
        xi=mu[:3],
        cov=0.5 * (C[:3, :3] + C[:3, :3].T),
        growth=float(mu[3]),
        growth_sd=float(np.sqrt(C[3, 3])),
        growth_prior=g_sd,
        log_evidence=log_ev,
        ess=ess,
        n_in=int(sub.inside.sum()),
        n_out=int((~sub.inside).sum()),
        bad_in=int((sub.inside & (dm < -margin)).sum()),
        bad_out=int((~sub.inside & (dm > margin)).sum()),
        edges_seen=_edges_seen(mu[:3], sub, board),
    )
