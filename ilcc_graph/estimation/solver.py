"""The one solver of the estimation core: input checks, the robust-kernel table, Levenberg-Marquardt,
and the marginals wrapper.

Every strategy (batch, sessions, rig, incremental's final solve) optimises through :func:`optimize`
and reads covariances through :class:`MarginalCovariances`, so that an indeterminate system is
always the same clear ``IndeterminateSystem`` error and never a crash.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from factors.grouped import MEstimator
from ilcc_graph.errors import IndeterminateSystem

log = logging.getLogger(__name__)

__all__ = [
    "KERNELS",
    "MAX_SIGMA",
    "MarginalCovariances",
    "SolverOptions",
    "check_covariance",
    "check_pose",
    "gaussian",
    "optimize",
    "robust_kernel",
]

#: m-estimators by name: (GTSAM's ``Create`` of the kernel at a threshold, that threshold in sigmas
#: giving 95 % efficiency on Gaussian data).
KERNELS: dict[str, tuple[Callable[[float], MEstimator], float]] = {
    "huber": (gtsam.noiseModel.mEstimator.Huber.Create, 1.345),
    "cauchy": (gtsam.noiseModel.mEstimator.Cauchy.Create, 2.3849),
    "tukey": (gtsam.noiseModel.mEstimator.Tukey.Create, 4.6851),
    "geman_mcclure": (gtsam.noiseModel.mEstimator.GemanMcClure.Create, 2.9846),
    "welsch": (gtsam.noiseModel.mEstimator.Welsch.Create, 2.9846),
}
#: Largest 1-sigma (rad or m) we still call a determined estimate.
MAX_SIGMA = 10.0


def robust_kernel(name: str | None, k: float | None = None) -> MEstimator | None:
    """The m-estimator ``name`` (None: none) at threshold ``k`` sigmas (None: its default)."""
    if name is None:
        return None
    key = name.lower().replace("-", "_")
    if key not in KERNELS:
        raise ValueError(f"robust: unknown kernel {name!r}; choose from {sorted(KERNELS)}")
    create, k_default = KERNELS[key]
    k = k_default if k is None else float(k)
    if not k > 0:
        raise ValueError(f"robust_k must be > 0, got {k!r}")
    return create(k)


def check_pose(T: np.ndarray | gtsam.Pose3, what: str) -> gtsam.Pose3:
    """A finite rigid (4, 4) transform (or a Pose3) as ``gtsam.Pose3``; ValueError naming ``what``."""
    if isinstance(T, gtsam.Pose3):
        return T
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{what}: expected a finite (4, 4) rigid transform, got shape {T.shape}")
    R = T[:3, :3]
    if (
        np.abs(R.T @ R - np.eye(3)).max() > 1e-6
        or np.linalg.det(R) < 0
        or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9
    ):
        raise ValueError(f"{what}: not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)")
    return gtsam.Pose3(gtsam.Rot3(R), T[:3, 3])


def check_covariance(C: np.ndarray, n: int, what: str) -> np.ndarray:
    """A finite, symmetric positive-definite (n, n) covariance (symmetrised); ValueError naming ``what``."""
    C = np.asarray(C, dtype=np.float64)
    if C.shape != (n, n) or not np.all(np.isfinite(C)):
        raise ValueError(f"{what}: expected a finite ({n}, {n}) covariance, got shape {C.shape}")
    C = 0.5 * (C + C.T)
    if np.linalg.eigvalsh(C).min() <= 0:
        raise ValueError(f"{what}: covariance is not positive definite")
    return C


def gaussian(cov: np.ndarray) -> gtsam.noiseModel.Base:
    """A full Gaussian noise model that keeps every correlation.

    ``smart=False``: GTSAM's default treats off-diagonals below 1e-9 (absolute) as zero, which drops
    real correlations of covariances in rad^2 and m^2.
    """
    return gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov, dtype=np.float64), False)


@dataclass(frozen=True)
class SolverOptions:
    """Levenberg-Marquardt stopping rules and damping (GTSAM's ``LevenbergMarquardtParams`` defaults)."""

    max_iterations: int = 100
    relative_error_tol: float = 1e-10
    absolute_error_tol: float = 1e-12
    lambda_initial: float = 1e-5
    lambda_factor: float = 10.0
    lambda_upper_bound: float = 1e5
    min_model_fidelity: float = 1e-3


def _converged(options: SolverOptions, current: float, new: float) -> bool:
    """GTSAM's ``checkConvergence`` (error tolerance 0): the decrease is below either tolerance."""
    decrease = current - new
    return (
        new <= 0.0
        or decrease <= options.absolute_error_tol
        or decrease / current <= options.relative_error_tol
    )


def optimize(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, options: SolverOptions = SolverOptions()
) -> tuple[gtsam.Values, int]:
    """Levenberg-Marquardt from ``values``: (result, steps taken). IndeterminateSystem when it cannot run.

    GTSAM's algorithm and defaults (``LevenbergMarquardtOptimizer``: damping ``lambda I`` on every
    variable, a fixed lambda factor, a step taken when the cost falls by more than
    ``min_model_fidelity`` of what the linearisation promised; the same result and step count),
    driven from Python so that every linearisation and cost runs on a ``Values`` that Python owns:
    inside GTSAM's own optimizer each Python ``CustomFactor`` callback gets a copy of the optimizer's
    whole ``Values`` (docs/factors.md), an iteration O(factors x variables).
    """
    current = float(graph.error(values))
    if not math.isfinite(current):
        raise IndeterminateSystem("Levenberg-Marquardt cannot start: the graph's error is not finite")
    damping = [(int(k), int(d)) for k, d in values.dims().items()]
    unit = {d: gtsam.noiseModel.Unit.Create(d) for _, d in damping}
    ordering = gtsam.Ordering.ColamdNonlinearFactorGraph(graph)
    lam, steps, solved = float(options.lambda_initial), 0, False
    while steps < options.max_iterations and current > 0.0:
        linear = graph.linearize(values)
        step: tuple[gtsam.Values, float] | None = None
        while step is None:
            damped = linear.clone()
            for key, dim in damping:
                damped.add(key, math.sqrt(lam) * np.eye(dim), np.zeros(dim), unit[dim])
            try:
                delta = damped.optimize(ordering)
            except RuntimeError:  # indeterminate even with this damping: damp more
                delta = None
            small = False
            if delta is not None:
                solved = True
                promised = current - float(linear.error(delta))
                if promised >= 0.0:
                    trial = values.retract(delta)
                    new = float(graph.error(trial))
                    fidelity = (current - new) / promised if promised > 1e-15 * current else 1.0
                    if math.isfinite(new) and fidelity > options.min_model_fidelity:
                        step = (trial, new)
                        lam /= options.lambda_factor
                        break
                    small = abs(current - new) < options.relative_error_tol * current
            lam *= options.lambda_factor
            if small or lam >= options.lambda_upper_bound:
                break  # no damping lowers the cost by more than the tolerance: converged
        if not solved:
            raise IndeterminateSystem("Levenberg-Marquardt failed on an indeterminate system")
        if step is None:
            break
        previous, (values, current) = current, step
        steps += 1
        if _converged(options, previous, current):
            break
    if steps >= options.max_iterations:
        log.warning("Levenberg-Marquardt stopped at the iteration limit (%d) before converging", steps)
    return values, steps


class MarginalCovariances:
    """``gtsam.Marginals`` of a solved graph, with an indeterminate system turned into a clear error.

    ``scale`` multiplies every covariance returned (the noise policy's a-posteriori variance factor).
    """

    def __init__(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, scale: float = 1.0) -> None:
        try:
            self._m = gtsam.Marginals(graph, values)
        except (RuntimeError, IndexError, ValueError) as exc:
            raise IndeterminateSystem(f"the graph does not determine its variables: {exc}") from None
        self.scale = float(scale)

    def covariance(self, key: int, what: str) -> np.ndarray:
        """The checked marginal covariance of one variable (``what`` names it in messages)."""
        try:
            C = np.asarray(self._m.marginalCovariance(key), dtype=np.float64)
        except (RuntimeError, IndexError, ValueError) as exc:
            raise IndeterminateSystem(f"the graph does not determine {what}: {exc}") from None
        return _checked(self.scale * 0.5 * (C + C.T), what)

    def joint(self, keys: Sequence[int], dims: Sequence[int]) -> np.ndarray:
        """The joint marginal covariance of ``keys`` (each of dimension ``dims``), in that order."""
        jm = self._m.jointMarginalCovariance(gtsam.KeyVector(list(keys)))
        off = np.concatenate([[0], np.cumsum(dims)])
        C = np.zeros((off[-1], off[-1]))
        for a, ka in enumerate(keys):
            for b, kb in enumerate(keys):
                C[off[a] : off[a + 1], off[b] : off[b + 1]] = jm.at(ka, kb)
        return self.scale * 0.5 * (C + C.T)


def _checked(C: np.ndarray, what: str) -> np.ndarray:
    if not np.all(np.isfinite(C)):
        raise IndeterminateSystem(f"the marginal covariance of {what} is not finite")
    eig = np.linalg.eigvalsh(C)
    if eig.min() <= 0 or math.sqrt(eig.max()) > MAX_SIGMA:
        raise IndeterminateSystem(
            f"the data barely determine {what} (covariance eigenvalues {eig.min():.3g} .. {eig.max():.3g})"
        )
    return C
