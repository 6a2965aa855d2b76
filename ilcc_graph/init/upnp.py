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
vertices, optionally with rotated copies) and is run to machine precision (``init/quartic.py``);
distinct limits that are minima are returned, sorted by the full cost. docs/init.md argues the choice and
docs/bench_upnp.md measures it against random-start local minimisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcc_graph.init.quartic import (
    ROTATION_QUADRICS,
    cached_starts,
    quartic_minima,
    quat_to_rotation,
    quaternion_starts,
)

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


def _check(
    points: np.ndarray, bearings: np.ndarray, weights: np.ndarray | None, origins: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """The inputs checked and as float64: points P (N, 3), unit bearings F (N, 3), weights W (N,),
    origins C (N, 3) or None; ValueError saying what is wrong."""
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
    G = np.einsum("kl,kab,lcd->abcd", red.M, ROTATION_QUADRICS, ROTATION_QUADRICS)
    Bq = np.einsum("k,kab->ab", red.b, ROTATION_QUADRICS)
    G -= np.einsum("ab,cd->abcd", Bq, I4) + np.einsum("ab,cd->abcd", I4, Bq)
    G += red.c * np.einsum("ab,cd->abcd", I4, I4)
    return (G + G.transpose(0, 2, 1, 3) + G.transpose(0, 3, 2, 1)) / 3.0


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
    Qs, _ = quartic_minima(T, cached_starts(start_copies))
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

    def residual(Tm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
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
