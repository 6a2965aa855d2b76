"""UPnP: the absolute pose from 3D points and unit bearings (Kneip, Li and Seo, ECCV 2014).

The object-space cost over all pairs,

    E(R, t) = sum_i w_i || (I - f_i f_i^T) (R p_i + t - c_i) ||^2,

(points ``p_i`` in the points' frame, e.g. the LiDAR's; unit bearings ``f_i`` in the camera frame;
``c_i`` the centre of the camera that saw bearing i, zero for a central camera) is quadratic in t,
so t is eliminated in closed form. What is left is quadratic in the nine entries of R, hence a
quartic form in the unit quaternion q. Every minimum of that quartic on the sphere S^3 (q and -q
being the same rotation) is a candidate pose.

The paper finds the stationary points with a Groebner-basis solver. Here a vectorised Riemannian
Newton method (saddle-free: the step uses |eigenvalues| of the Riemannian Hessian, with a line
search) starts from a deterministic set of quaternions covering S^3 / {+-1} (the 600-cell's
vertices, optionally with rotated copies) and is run to machine precision; distinct limits that are
minima are returned, sorted by the full cost. docs/init.md argues the choice and
docs/bench_upnp.md measures it against random-start local minimisation.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

__all__ = [
    "UpnpSolution",
    "object_space_cost",
    "quat_to_rotation",
    "quaternion_starts",
    "refine_angular",
    "upnp",
]


@dataclass(frozen=True)
class UpnpSolution:
    """One candidate pose.

    T_cam_points: (4, 4) with ``p_cam = T[:3, :3] @ p + T[:3, 3]`` (for LiDAR points: T_cam_lidar).
    cost: the object-space cost E(R, t) at this pose (square metres, weighted).
    front_fraction: weighted fraction of points with positive depth ``f_i . (R p_i + t - c_i) > 0``.
    """

    T_cam_points: np.ndarray
    cost: float
    front_fraction: float

    @property
    def T_cam_lidar(self) -> np.ndarray:
        """Alias of ``T_cam_points`` for LiDAR points."""
        return self.T_cam_points


# R(q) entries as quadratic forms q^T A_k q, q = (w, x, y, z), k = 3 * row + col.
def _rotation_quadrics() -> np.ndarray:
    A = np.zeros((9, 4, 4))
    w, x, y, z = range(4)

    def put(k: int, i: int, j: int, c: float) -> None:
        A[k, i, j] += c / 2.0
        A[k, j, i] += c / 2.0

    for k, (a, b, c, d) in {0: (1, 1, -1, -1), 4: (1, -1, 1, -1), 8: (1, -1, -1, 1)}.items():
        for idx, coef in zip((w, x, y, z), (a, b, c, d), strict=True):
            put(k, idx, idx, coef)
    put(1, x, y, 2.0), put(1, w, z, -2.0)  # R01 = 2(xy - wz)
    put(2, x, z, 2.0), put(2, w, y, 2.0)  # R02 = 2(xz + wy)
    put(3, x, y, 2.0), put(3, w, z, 2.0)  # R10 = 2(xy + wz)
    put(5, y, z, 2.0), put(5, w, x, -2.0)  # R12 = 2(yz - wx)
    put(6, x, z, 2.0), put(6, w, y, -2.0)  # R20 = 2(xz - wy)
    put(7, y, z, 2.0), put(7, w, x, 2.0)  # R21 = 2(yz + wx)
    return A


_A = _rotation_quadrics()


def quat_to_rotation(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (w, x, y, z), any norm -> (..., 3, 3) rotation matrices."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.einsum("...a,kab,...b->...k", q, _A, q).reshape(*q.shape[:-1], 3, 3)


def _left_matrix(q: np.ndarray) -> np.ndarray:
    """(K, 4) -> (K, 4, 4) with ``L(q) @ p = q * p`` (Hamilton product); orthogonal for unit q."""
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([w, -x, -y, -z], -1),
            np.stack([x, w, -z, y], -1),
            np.stack([y, z, w, -x], -1),
            np.stack([z, -y, x, w], -1),
        ],
        axis=1,
    )


@lru_cache(maxsize=8)
def _starts_cached(copies: int) -> np.ndarray:
    return quaternion_starts(copies)


def quaternion_starts(copies: int = 1) -> np.ndarray:
    """Deterministic starts covering S^3 / {+-1}: the 600-cell's 120 vertices, one of each +-pair.

    ``copies > 1`` adds copies turned by fixed quaternions. Returns (60 * copies, 4) unit rows.
    """
    phi = (1.0 + np.sqrt(5.0)) / 2.0
    verts = [np.eye(4)[i] * s for i in range(4) for s in (1.0, -1.0)]
    verts += [np.array(s) / 2.0 for s in np.array(np.meshgrid(*[[1.0, -1.0]] * 4)).reshape(4, -1).T]
    base = np.array([phi, 1.0, 1.0 / phi, 0.0]) / 2.0
    even_perms = [p for p in _permutations4() if _parity(p) == 0]
    for p in even_perms:
        for signs in np.array(np.meshgrid(*[[1.0, -1.0]] * 3)).reshape(3, -1).T:
            v = base.copy()
            v[:3] *= signs
            verts.append(v[list(p)])
    V = np.unique(np.round(np.array(verts), 12), axis=0)
    # one of each antipodal pair: first non-zero coordinate positive
    first = V[np.arange(len(V)), np.argmax(np.abs(V) > 1e-9, axis=1)]
    V = V[first > 0]
    out = [V]
    rng = np.random.default_rng(12345)  # fixed: the copies are part of the method's definition
    for _ in range(copies - 1):
        r = rng.normal(size=4)
        out.append((_left_matrix((r / np.linalg.norm(r))[None])[0] @ V.T).T)
    return np.vstack(out)


def _permutations4() -> list[tuple[int, ...]]:
    from itertools import permutations

    return list(permutations(range(4)))


def _parity(p: tuple[int, ...]) -> int:
    inv = sum(1 for i in range(len(p)) for j in range(i + 1, len(p)) if p[i] > p[j])
    return inv % 2


def _check(points: np.ndarray, bearings: np.ndarray, weights, origins):
    P = np.asarray(points, dtype=np.float64)
    F = np.asarray(bearings, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or F.shape != P.shape:
        raise ValueError(f"points and bearings must both be (N, 3); got {P.shape} and {F.shape}")
    if P.shape[0] < 3:
        raise ValueError(f"need at least 3 point-bearing pairs, got {P.shape[0]}")
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(F))):
        raise ValueError("points or bearings contain non-finite numbers")
    nrm = np.linalg.norm(F, axis=1)
    if np.any(nrm < 1e-12):
        raise ValueError("a bearing has zero length")
    F = F / nrm[:, None]
    W = np.ones(len(P)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if W.shape != (len(P),) or np.any(W < 0) or not np.all(np.isfinite(W)):
        raise ValueError(f"weights must be (N,) = ({len(P)},) finite and non-negative")
    C = None
    if origins is not None:
        C = np.asarray(origins, dtype=np.float64)
        if C.shape != P.shape or not np.all(np.isfinite(C)):
            raise ValueError(f"origins must be (N, 3) = {P.shape} and finite; got {C.shape}")
    return P, F, W, C


@dataclass(frozen=True)
class _Reduced:
    """E(R, t*(R)) = r^T M r - 2 b^T r + c with r = vec(R) row-major; t*(R) = -Hinv (A r - g)."""

    M: np.ndarray
    b: np.ndarray
    c: float
    Hinv: np.ndarray
    A: np.ndarray
    g: np.ndarray
    mean: np.ndarray


def _reduce(P: np.ndarray, F: np.ndarray, W: np.ndarray, C: np.ndarray | None) -> _Reduced:
    mean = np.average(P, axis=0, weights=W) if W.sum() > 0 else P.mean(axis=0)
    Pc = P - mean  # the minimum is invariant to shifting the points; centring helps conditioning
    V = np.eye(3)[None] - F[:, :, None] * F[:, None, :]  # (N, 3, 3) projectors
    WV = W[:, None, None] * V
    H = WV.sum(axis=0)
    if np.linalg.cond(H) > 1e12:
        raise ValueError("the bearings are (nearly) all parallel: translation is not determined")
    Hinv = np.linalg.inv(H)
    A = np.einsum("nab,nc->abc", WV, Pc).reshape(3, 9)
    M = np.einsum("nab,nc,nd->acbd", WV, Pc, Pc).reshape(9, 9) - A.T @ Hinv @ A
    if C is None:
        g = np.zeros(3)
        b = np.zeros(9)
        c = 0.0
    else:
        VC = np.einsum("nab,nb->na", WV, C)
        g = VC.sum(axis=0)
        b = np.einsum("na,nc->ac", VC, Pc).reshape(9) - A.T @ Hinv @ g
        c = float(np.einsum("na,na->", VC, C) - g @ Hinv @ g)
    return _Reduced(0.5 * (M + M.T), b, c, Hinv, A, g, mean)


def _quartic_tensor(red: _Reduced) -> np.ndarray:
    """Fully symmetric T (4,4,4,4) with T(q,q,q,q) = E on the unit sphere (homogenised)."""
    I4 = np.eye(4)
    G = np.einsum("kl,kab,lcd->abcd", red.M, _A, _A)
    Bq = np.einsum("k,kab->ab", red.b, _A)
    G -= np.einsum("ab,cd->abcd", Bq, I4) + np.einsum("ab,cd->abcd", I4, Bq)
    G += red.c * np.einsum("ab,cd->abcd", I4, I4)
    return (G + G.transpose(0, 2, 1, 3) + G.transpose(0, 3, 2, 1)) / 3.0


def _eval(T64: np.ndarray, Q: np.ndarray):
    """Batched f, Euclidean gradient/4 and Hessian/12 of the quartic at rows of Q (K, 4)."""
    X2 = ((Q @ T64.T).reshape(-1, 16, 4) @ Q[:, :, None]).reshape(-1, 4, 4)  # T q q  (Hessian / 12)
    X3 = (X2 @ Q[:, :, None])[:, :, 0]  # T q q q (gradient / 4)
    f = np.sum(X3 * Q, axis=1)
    return f, X3, X2


def _f_only(T64: np.ndarray, Q: np.ndarray) -> np.ndarray:
    X2 = ((Q @ T64.T).reshape(-1, 16, 4) @ Q[:, :, None]).reshape(-1, 4, 4)
    return (Q[:, None, :] @ X2 @ Q[:, :, None])[:, 0, 0]


# L(q) = sum_a q_a _LQ[a]: the Hamilton product's left matrix, L(q) @ p = q * p
_LQ = np.stack([_left_matrix(np.eye(4)[a][None])[0] for a in range(4)]).reshape(4, 16)
_STEPS = np.array([1.0, 0.5, 0.25, 0.1, 0.02])


def _riemannian(T64: np.ndarray, Q: np.ndarray):
    """f, tangent basis B (K,4,3), Riemannian gradient (K,3) and Hessian (K,3,3) at unit rows of Q."""
    f, g4, h12 = _eval(T64, Q)
    B = (Q @ _LQ).reshape(-1, 4, 4)[:, :, 1:]  # orthonormal tangent basis q * e_x, q * e_y, q * e_z
    Bt = B.transpose(0, 2, 1)
    g = 4.0 * (Bt @ g4[:, :, None])[:, :, 0]
    Hr = 12.0 * (Bt @ h12 @ B)
    Hr[:, [0, 1, 2], [0, 1, 2]] -= 4.0 * f[:, None]
    return f, B, g, Hr


def _newton_minima(
    T: np.ndarray, starts: np.ndarray, max_iter: int = 60, max_step: float = 0.6
) -> tuple[np.ndarray, np.ndarray]:
    """Saddle-free Riemannian Newton from every start; returns distinct minima (m, 4) and their f.

    f is scaled so that thresholds are relative. Starts that come within ``merge`` of each other
    or of a converged minimum are merged (Newton's basin is much wider than that).
    """
    T64 = T.reshape(64, 4) / (float(np.abs(T).max()) or 1.0)
    Q = starts.copy()
    done: list[np.ndarray] = []
    merge = 1e-3
    for _ in range(max_iter):
        if len(Q) == 0:
            break
        f, B, g, Hr = _riemannian(T64, Q)
        lam, U = np.linalg.eigh(Hr)
        coef = (g[:, None, :] @ U)[:, 0, :] / np.maximum(np.abs(lam), 1e-12)
        delta = -(U @ coef[:, :, None])[:, :, 0]
        nrm = np.sqrt(np.sum(delta * delta, axis=1))
        delta *= np.minimum(1.0, max_step / np.maximum(nrm, 1e-300))[:, None]
        step = (B @ delta[:, :, None])[:, :, 0]
        conv = (nrm < 1e-10) & (lam[:, 0] > -1e-9)
        cand = Q[:, None, :] + _STEPS[None, :, None] * step[:, None, :]
        cand /= np.sqrt(np.sum(cand * cand, axis=2, keepdims=True))
        fc = _f_only(T64, cand.reshape(-1, 4)).reshape(len(Q), -1)
        best = np.argmin(fc, axis=1)
        improve = fc[np.arange(len(Q)), best] < f
        Qn = np.where(improve[:, None], cand[np.arange(len(Q)), best], Q)
        stuck = ~improve
        neg = stuck & (lam[:, 0] < -1e-9)
        if np.any(neg):  # a saddle or maximum: leave along the most negative curvature
            Qn[neg] = Q[neg] + 0.05 * (B[neg] @ U[neg, :, :1])[:, :, 0]
            Qn[neg] /= np.linalg.norm(Qn[neg], axis=1, keepdims=True)
            stuck &= ~neg
        fin = conv | stuck
        if np.any(fin):
            done.append(_dedupe(Qn[fin], merge))
        Q = Qn[~fin]
        if len(Q) > 1:
            Q = _dedupe(Q, merge)
        if len(Q) and done:
            Dq = np.vstack(done)
            near = np.max(np.abs(Q @ Dq.T), axis=1) > 1.0 - merge * merge / 2.0
            Q = Q[~near]
    if len(Q):
        done.append(Q)
    if not done:
        return np.zeros((0, 4)), np.zeros(0)
    Qd = _dedupe(np.vstack(done), merge)
    for _ in range(2):  # plain Newton steps: q to machine precision (f itself is flat there)
        f, B, g, Hr = _riemannian(T64, Qd)
        lam, U = np.linalg.eigh(Hr)
        ok = lam[:, 0] > 1e-12
        if not np.any(ok):
            break
        d = np.zeros((len(Qd), 3))
        d[ok] = -np.linalg.solve(Hr[ok], g[ok][:, :, None])[:, :, 0]
        d *= np.minimum(1.0, 1e-3 / np.maximum(np.linalg.norm(d, axis=1), 1e-300))[:, None]
        Qd = Qd + (B @ d[:, :, None])[:, :, 0]
        Qd /= np.linalg.norm(Qd, axis=1, keepdims=True)
    Qd = _dedupe(Qd, 1e-6)
    f, B, g, Hr = _riemannian(T64, Qd)
    lam_min = np.linalg.eigvalsh(Hr)[:, 0]
    keep = lam_min > -1e-7
    order = np.argsort(f[keep])
    return Qd[keep][order], f[keep][order]


def _dedupe(Q: np.ndarray, tol: float) -> np.ndarray:
    """Keep the first of each group of unit quaternions within ``tol`` radians (q ~ -q)."""
    if len(Q) < 2:
        return Q
    close = np.abs(Q @ Q.T) > 1.0 - tol * tol / 2.0
    close = np.triu(close, 1)
    keep = ~np.any(close, axis=0)  # drop any that has an earlier near-duplicate
    return Q[keep]


def object_space_cost(
    T_cam_points: np.ndarray,
    points: np.ndarray,
    bearings: np.ndarray,
    weights: np.ndarray | None = None,
    origins: np.ndarray | None = None,
) -> float:
    """E(R, t) evaluated directly from its definition (square metres)."""
    P, F, W, C = _check(points, bearings, weights, origins)
    X = P @ T_cam_points[:3, :3].T + T_cam_points[:3, 3]
    if C is not None:
        X = X - C
    r = X - F * np.sum(F * X, axis=1, keepdims=True)
    return float(np.sum(W * np.sum(r * r, axis=1)))


def upnp(
    points: np.ndarray,
    bearings: np.ndarray,
    weights: np.ndarray | None = None,
    origins: np.ndarray | None = None,
    *,
    prefer_front: bool = False,
    tie_rtol: float = 1.0,
    start_copies: int = 1,
) -> list[UpnpSolution]:
    """Every minimum of the object-space cost, best first.

    Parameters
    ----------
    points : (N, 3) points in their own frame (e.g. LiDAR), metres; N >= 3 (4+ for a unique pose).
    bearings : (N, 3) unit bearings in the camera frame (any direction on the sphere).
    weights : (N,) non-negative weights, default ones.
    origins : (N, 3) centre of the camera that saw each bearing, in the camera (body) frame;
        None for a central camera (the non-central case is the general UPnP).
    prefer_front : put first the candidates with a majority of points in front
        (``f_i . (R p_i + t - c_i) > 0``) whose cost is within ``tie_rtol`` (relative) of the
        best. The cost cannot tell a ray from a line: a planar target has a twin minimum with
        every point behind the camera, of equal cost for exact data and of a slightly different
        cost with noise (off-plane noise: 10-35 % apart was seen for one board at 3-6 m, hence the
        default 1.0, i.e. within twice the best cost). Use ``tie_rtol=np.inf`` to put every
        front-majority candidate first whatever its cost (what one wants for a single board).
    start_copies : 1 gives the 600-cell's 60 starts; more adds turned copies (slower, even safer).

    Returns
    -------
    list of UpnpSolution, sorted by cost (with ``prefer_front``: front-majority ones within the
    tie first).
    """
    P, F, W, C = _check(points, bearings, weights, origins)
    red = _reduce(P, F, W, C)
    T = _quartic_tensor(red)
    Qs, _ = _newton_minima(T, _starts_cached(start_copies))
    sols = []
    for q in Qs:
        R = quat_to_rotation(q)
        t = -red.Hinv @ (red.A @ R.reshape(9) - red.g)
        t = t - R @ red.mean
        Tm = np.eye(4)
        Tm[:3, :3] = R
        Tm[:3, 3] = t
        X = P @ R.T + t
        if C is not None:
            X = X - C
        depth = np.sum(F * X, axis=1)
        r = X - F * depth[:, None]
        cost = float(np.sum(W * np.sum(r * r, axis=1)))
        front = float(np.sum(W * (depth > 0)) / max(W.sum(), 1e-300))
        sols.append(UpnpSolution(Tm, cost, front))
    sols.sort(key=lambda s: s.cost)
    if prefer_front and sols:
        # cost within tie_rtol of the best and a majority of points in front: these come first
        limit = np.inf
        if np.isfinite(tie_rtol):
            limit = sols[0].cost * (1.0 + tie_rtol) + 1e-12 * float(
                np.sum(W * np.sum((P - red.mean) ** 2, axis=1))
            )
        sols.sort(key=lambda s: (not (s.front_fraction > 0.5 and s.cost <= limit), s.cost))
    return sols


def refine_angular(
    T_cam_points: np.ndarray,
    points: np.ndarray,
    bearings: np.ndarray,
    weights: np.ndarray | None = None,
    iterations: int = 10,
) -> np.ndarray:
    """Gauss-Newton on the angular (tangent-plane) error of a central camera; returns (4, 4).

    Residual of pair i: the component of the unit vector u_i = X_i / |X_i| (X_i = R p_i + t)
    orthogonal to f_i, in an orthonormal basis of f_i's tangent plane (radians for small errors,
    no wrap, no pole). Pose update ``T <- Exp(xi) T`` (left, camera frame), xi = (w, v).
    """
    P, F, W, _ = _check(points, bearings, weights, None)
    T = np.array(T_cam_points, dtype=np.float64)
    # tangent basis of each f
    a = np.where(np.abs(F[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    b1 = np.cross(F, a)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    b2 = np.cross(F, b1)
    Bt = np.stack([b1, b2], axis=1)  # (N, 2, 3)
    sw = np.sqrt(W)

    def residual(Tm):
        X = P @ Tm[:3, :3].T + Tm[:3, 3]
        n = np.linalg.norm(X, axis=1)
        u = X / n[:, None]
        return X, n, u, np.einsum("nij,nj->ni", Bt, u)

    X, n, u, e = residual(T)
    cost = float(np.sum(W * np.sum(e * e, axis=1)))
    for _ in range(iterations):
        # du/dX = (I - u u^T)/|X|; dX/dxi = [-[X]x, I]
        Du = (np.eye(3)[None] - u[:, :, None] * u[:, None, :]) / n[:, None, None]
        DX = np.concatenate([-_skew(X), np.broadcast_to(np.eye(3), (len(X), 3, 3))], axis=2)
        J = np.einsum("nij,njk,nkl->nil", Bt, Du, DX) * sw[:, None, None]
        r = e * sw[:, None]
        JJ = np.einsum("nia,nib->ab", J, J)
        Jr = np.einsum("nia,ni->a", J, r)
        try:
            xi = -np.linalg.solve(JJ + 1e-12 * np.trace(JJ) * np.eye(6), Jr)
        except np.linalg.LinAlgError:
            break
        Tn = _exp_se3(xi) @ T
        Xn, nn, un, en = residual(Tn)
        cn = float(np.sum(W * np.sum(en * en, axis=1)))
        if cn > cost:
            break
        T, X, n, u, e, converged = Tn, Xn, nn, un, en, cost - cn <= 1e-15 + 1e-12 * cost
        cost = cn
        if converged:
            break
    return T


def _skew(v: np.ndarray) -> np.ndarray:
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return S


def _exp_se3(xi: np.ndarray) -> np.ndarray:
    """(6,) (rotation vector, translation) -> 4x4 with R = exp([w]x), t = v (first-order)."""
    w, v = xi[:3], xi[3:]
    th = np.linalg.norm(w)
    K = _skew(w[None])[0]
    if th < 1e-12:
        R = np.eye(3) + K
    else:
        R = np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th**2 * K @ K
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = v
    return T
