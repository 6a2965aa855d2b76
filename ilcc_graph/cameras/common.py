"""Numerics and config helpers shared by the camera model files (no model knowledge here)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..checks import MISSING, Checker
from ..errors import quote

_FLU_AXIS_NAMES = (("backward", "forward"), ("right", "left"), ("down", "up"))


def as_points(p: np.ndarray, dim: int, what: str) -> tuple[np.ndarray, tuple[int, ...]]:
    """Coerce to float64 (N, dim); return it with the leading shape to restore."""
    a = np.asarray(p, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != dim:
        raise ValueError(f"{what} must have shape (..., {dim}), got {a.shape}")
    return a.reshape(-1, dim), a.shape[:-1]


def check_K(K: Any) -> np.ndarray:
    """K as a read-only float64 [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0; ValueError else."""
    K = np.array(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"K must be a finite 3x3 matrix, got {K.tolist() if K.size <= 16 else K.shape}")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise ValueError(
            f"K must be [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K.tolist()}"
        )
    K.setflags(write=False)
    return K


def check_size(width: Any, height: Any) -> tuple[int, int]:
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise ValueError(f"camera {name} must be a positive integer (pixels), got {quote(v)}")
    return int(width), int(height)


def finite_vector(v: Any, what: str) -> np.ndarray:
    """A read-only float64 1-D copy of ``v``; ValueError when not finite."""
    d = np.array(v, dtype=np.float64).ravel()
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{what} must be finite, got {d.tolist()}")
    d.setflags(write=False)
    return d


def solve_increasing(
    f: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], target: np.ndarray, hi: float, iters: int = 100
) -> np.ndarray:
    """Solve f(x) = target for x in [0, hi], f increasing there with f(0) = 0; safeguarded Newton.

    ``f(x) -> (value, derivative)``. Targets outside [0, f(hi)] must be masked by the caller.
    """
    lo_b = np.zeros_like(target)
    hi_b = np.full_like(target, hi)
    x = np.clip(target, 0.0, hi)  # f(x) ~ x near 0 for every lens here
    for _ in range(iters):
        fx, dfx = f(x)
        r = fx - target
        lo_b = np.where(r < 0, x, lo_b)
        hi_b = np.where(r > 0, x, hi_b)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_new = x - r / dfx
        bad = ~np.isfinite(x_new) | (x_new <= lo_b) | (x_new >= hi_b)
        x_new = np.where(r == 0, x, np.where(bad, 0.5 * (lo_b + hi_b), x_new))  # a root stays put
        done = np.abs(x_new - x) <= 1e-15 * np.maximum(1.0, np.abs(x))
        x = x_new
        if np.all(done | (r == 0)):
            break
    return x


def first_fold(dfdx: Callable[[np.ndarray], np.ndarray], hi: float, n: int = 20001) -> float:
    """Smallest x in (0, hi) where dfdx(x) <= 0 (bisection-refined), or ``hi`` when there is none."""
    xs = np.linspace(0.0, hi, n)
    bad = ~(dfdx(xs) > 0)
    if not bad.any():
        return hi
    k = int(np.argmax(bad))
    lo, up = xs[max(k - 1, 0)], xs[k]
    for _ in range(60):
        mid = 0.5 * (lo + up)
        if dfdx(np.array([mid]))[0] > 0:
            lo = mid
        else:
            up = mid
    return float(lo)


def config_K(c: Checker, v: Any, key: str) -> np.ndarray:
    """A config value for K: 3x3 nested or 9 numbers row-major, [[fx, s, cx], [0, fy, cy], [0, 0, 1]];
    (3, 3) float64."""
    if isinstance(v, (list, tuple)) and len(v) == 9 and not any(isinstance(x, (list, tuple)) for x in v):
        v = [list(v[0:3]), list(v[3:6]), list(v[6:9])]
    if not (
        isinstance(v, (list, tuple))
        and len(v) == 3
        and all(isinstance(r, (list, tuple)) and len(r) == 3 for r in v)
    ):
        raise c.fail(key, v, "a 3x3 matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
    K = [c.numbers(r, f"{key}[{i}]", 3) for i, r in enumerate(v)]
    if not (K[0][0] > 0 and K[1][1] > 0 and K[1][0] == 0 and K[2] == [0.0, 0.0, 1.0]):
        raise c.fail(key, v, "[[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    return np.array(K, dtype=np.float64)


def config_dist(c: Checker, d: dict, lengths: tuple[int, ...], missing: list[float]) -> np.ndarray:
    """The ``dist`` key of a camera section as float64 (n,): ``missing`` when absent, empty when
    empty, else numbers of one of ``lengths``."""
    dist = d.get("dist")
    if dist is None:
        return np.array(missing, dtype=np.float64)
    if isinstance(dist, (list, tuple)) and len(dist) == 0:
        return np.zeros(0)
    return np.array(c.numbers(dist, "camera.dist", lengths), dtype=np.float64)


def axes_text(R_flu_cam: np.ndarray) -> str:
    """The camera axes in words, e.g. ``x right, y down, z forward`` for OpenCV's."""
    words = []
    for j, name in enumerate("xyz"):
        col = R_flu_cam[:, j]
        i = int(np.argmax(np.abs(col)))
        words.append(f"{name} {_FLU_AXIS_NAMES[i][int(col[i] > 0)] if abs(col[i]) == 1.0 else 'tilted'}")
    return ", ".join(words)


def check_intrinsics_sigma(sigma: Any, names: tuple[str, ...], what: str) -> np.ndarray | None:
    """A stated intrinsics uncertainty as a read-only (n,) float64 array in ``names`` order, or None.

    ``sigma``: None, a sequence of n numbers in ``names`` order, or a mapping with exactly those
    names as keys; every value finite and >= 0. ValueError naming ``what`` otherwise.
    """
    if sigma is None:
        return None
    if isinstance(sigma, dict):
        if set(sigma) != set(names):
            raise ValueError(f"{what} intrinsics_sigma must name exactly {list(names)}, got {sorted(sigma)}")
        sigma = [sigma[n] for n in names]
    s = np.array(sigma, dtype=np.float64).ravel()
    if not names:
        if s.size:
            raise ValueError(f"{what} has no intrinsics to refine; intrinsics_sigma must be None")
        return None
    if s.shape != (len(names),) or not np.all(np.isfinite(s)) or np.any(s < 0):
        raise ValueError(
            f"{what} intrinsics_sigma must be {len(names)} finite numbers >= 0 ({', '.join(names)}), "
            f"got {s.tolist()}"
        )
    s.setflags(write=False)
    return s


def config_intrinsics_sigma(c: Checker, v: Any, key: str, names: tuple[str, ...]) -> np.ndarray:
    """A config value for ``intrinsics_sigma``: a mapping {name: sigma >= 0} naming every intrinsic."""
    expected = f"a mapping {{name: sigma >= 0}} with exactly the keys {list(names)}"
    if not names:
        raise c.fail(key, v, "no such key: this camera model has no intrinsics to refine")
    if not isinstance(v, dict):
        raise c.fail(key, v, expected)
    for k in v:
        if k not in names:
            raise c.fail(f"{key}.{k}", v[k], f"no such intrinsic; this camera's are {list(names)}")
    for n in names:
        if n not in v:
            raise c.fail(f"{key}.{n}", MISSING, f"a number >= 0 ({expected})")
    return np.array([c.number(v[n], f"{key}.{n}", lo=0.0) for n in names])
