"""Checks of factor Jacobians against central differences on the manifold, and test geometry.

Only gtsam and numpy. Derivatives are taken in GTSAM's tangent convention: for a variable ``x``,
``d f / d xi`` at ``xi = 0`` of ``f(x.retract(xi))`` (Pose3: ``x * Expmap(xi)``; Point3: ``x + xi``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gtsam
import numpy as np

__all__ = [
    "factor_jacobian_error",
    "factor_jacobians",
    "numerical_factor_jacobians",
    "numerical_jacobian",
    "random_pose",
    "sample_bearing",
]


def _retract(x: Any, xi: np.ndarray) -> Any:
    if isinstance(x, np.ndarray):
        return x + xi
    return x.retract(xi)


def _local(a: Any, b: Any) -> np.ndarray:
    if isinstance(a, np.ndarray):
        return np.asarray(b - a, dtype=np.float64).reshape(-1)
    return np.asarray(a.localCoordinates(b), dtype=np.float64).reshape(-1)


def _dim(x: Any) -> int:
    return int(np.size(x)) if isinstance(x, np.ndarray) else len(_local(x, x))


def numerical_jacobian(
    f: Callable[..., np.ndarray], args: Sequence[Any], which: int, delta: float = 1e-6
) -> np.ndarray:
    """Central-difference Jacobian of the vector function ``f(*args)`` w.r.t. ``args[which]``.

    ``args[which]`` is a GTSAM manifold object (Pose3, Rot3, Unit3, ...) or a numpy vector; the
    output of ``f`` must be a flat vector. Returns (len(f), dim(args[which])).
    """
    x = args[which]
    y0 = np.asarray(f(*args), dtype=np.float64).reshape(-1)
    n = _dim(x)
    J = np.zeros((y0.size, n))
    for j in range(n):
        xi = np.zeros(n)
        xi[j] = delta
        a_plus, a_minus = list(args), list(args)
        a_plus[which] = _retract(x, xi)
        a_minus[which] = _retract(x, -xi)
        y_plus = np.asarray(f(*a_plus), dtype=np.float64).reshape(-1)
        y_minus = np.asarray(f(*a_minus), dtype=np.float64).reshape(-1)
        J[:, j] = (y_plus - y_minus) / (2.0 * delta)
    return J


def _single(key: int, vector: np.ndarray) -> gtsam.VectorValues:
    vv = gtsam.VectorValues()
    vv.insert(key, vector)
    return vv


def factor_jacobians(factor: gtsam.NonlinearFactor, values: gtsam.Values) -> list[np.ndarray]:
    """Whitened analytic Jacobian blocks of ``factor`` at ``values``, one per key in ``factor.keys()``."""
    linear = factor.linearize(values)
    A = np.asarray(linear.jacobian()[0])
    dims = [int(values.zeroVectors().at(k).size) for k in factor.keys()]
    return list(np.split(A, np.cumsum(dims)[:-1], axis=1))


def numerical_factor_jacobians(
    factor: gtsam.NoiseModelFactor, values: gtsam.Values, delta: float = 1e-6
) -> list[np.ndarray]:
    """Central differences of ``factor.whitenedError`` w.r.t. each key, retracting that key only."""
    blocks = []
    for key in factor.keys():
        n = int(values.zeroVectors().at(key).size)
        cols = []
        for j in range(n):
            out = []
            for sign in (1.0, -1.0):
                delta_vv = gtsam.VectorValues()
                for other in values.keys():
                    delta_vv.insert(other, np.zeros(values.zeroVectors().at(other).size))
                step = np.zeros(n)
                step[j] = sign * delta
                delta_vv.update(_single(key, step))
                out.append(np.asarray(factor.whitenedError(values.retract(delta_vv)), dtype=np.float64))
            cols.append((out[0] - out[1]) / (2.0 * delta))
        blocks.append(np.stack(cols, axis=1))
    return blocks


def factor_jacobian_error(factor: gtsam.NoiseModelFactor, values: gtsam.Values, delta: float = 1e-6) -> float:
    """Largest absolute difference between analytic and numerical whitened Jacobians of ``factor``.

    Valid for factors without a robust kernel (a robust one linearises with IRLS weights).
    """
    analytic = factor_jacobians(factor, values)
    numeric = numerical_factor_jacobians(factor, values, delta)
    return max(
        float(np.max(np.abs(a - n))) if a.size else 0.0 for a, n in zip(analytic, numeric, strict=True)
    )


def random_pose(rng: np.random.Generator, rot_sigma: float = np.pi, trans_sigma: float = 1.0) -> gtsam.Pose3:
    """A random Pose3 ``Expmap([r, t])`` with ``r ~ N(0, rot_sigma^2 I)``, ``t ~ N(0, trans_sigma^2 I)``."""
    return gtsam.Pose3.Expmap(np.concatenate([rng.normal(0, rot_sigma, 3), rng.normal(0, trans_sigma, 3)]))


def sample_bearing(rng: np.random.Generator, b: np.ndarray, cov_tangent: np.ndarray) -> np.ndarray:
    """Noisy unit bearings (K, 3): ``Unit3(b_k).retract(d_k)``, ``d_k ~ N(0, cov_tangent[k])`` in ``basis()``.

    ``cov_tangent[k]`` is expressed in ``Unit3(b[k]).basis()`` (GTSAM's basis, which depends on the
    point only); ``retract`` is the exponential map of the sphere, so the geodesic error has that
    covariance exactly.
    """
    b = np.asarray(b, dtype=np.float64).reshape(-1, 3)
    cov = np.asarray(cov_tangent, dtype=np.float64).reshape(-1, 2, 2)
    L = np.linalg.cholesky(cov)
    d = np.einsum("kij,kj->ki", L, rng.standard_normal((len(b), 2)))
    return np.stack([gtsam.Unit3(bk).retract(dk).point3() for bk, dk in zip(b, d, strict=True)])
