"""Every minimum of a quartic form on the unit quaternions, S^3 / {+-1} (UPnP's rotation search).

``T`` (4, 4, 4, 4) fully symmetric, ``f(q) = T(q, q, q, q)``. A vectorised Riemannian Newton method
(saddle-free: the step uses |eigenvalues| of the Riemannian Hessian, with a line search) starts
from a deterministic set of quaternions covering S^3 / {+-1} (the 600-cell's vertices, optionally
with rotated copies) and is run to machine precision; the distinct limits that are minima are
returned. Quaternions are (w, x, y, z); ``ROTATION_QUADRICS`` writes R(q) as quadratic forms in q.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["ROTATION_QUADRICS", "cached_starts", "quartic_minima", "quat_to_rotation", "quaternion_starts"]


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
    off_diagonal = [
        (1, (x, y, 2.0), (w, z, -2.0)),  # R01 = 2(xy - wz)
        (2, (x, z, 2.0), (w, y, 2.0)),  # R02 = 2(xz + wy)
        (3, (x, y, 2.0), (w, z, 2.0)),  # R10 = 2(xy + wz)
        (5, (y, z, 2.0), (w, x, -2.0)),  # R12 = 2(yz - wx)
        (6, (x, z, 2.0), (w, y, -2.0)),  # R20 = 2(xz - wy)
        (7, (y, z, 2.0), (w, x, 2.0)),  # R21 = 2(yz + wx)
    ]
    for k, *terms in off_diagonal:
        for i, j, value in terms:
            put(k, i, j, value)
    return A


#: (9, 4, 4): entry k = 3 * row + col of R(q) is ``q^T ROTATION_QUADRICS[k] q`` for a unit q
ROTATION_QUADRICS = _rotation_quadrics()
_A = ROTATION_QUADRICS


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
def cached_starts(copies: int) -> np.ndarray:
    """``quaternion_starts(copies)``, computed once per ``copies`` (read-only: do not modify)."""
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


def _eval(T64: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


def _riemannian(T64: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """f, tangent basis B (K,4,3), Riemannian gradient (K,3) and Hessian (K,3,3) at unit rows of Q."""
    f, g4, h12 = _eval(T64, Q)
    B = (Q @ _LQ).reshape(-1, 4, 4)[:, :, 1:]  # orthonormal tangent basis q * e_x, q * e_y, q * e_z
    Bt = B.transpose(0, 2, 1)
    g = 4.0 * (Bt @ g4[:, :, None])[:, :, 0]
    Hr = 12.0 * (Bt @ h12 @ B)
    Hr[:, [0, 1, 2], [0, 1, 2]] -= 4.0 * f[:, None]
    return f, B, g, Hr


def quartic_minima(
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
