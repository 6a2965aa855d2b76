"""What the grouped factors share: one GTSAM ``CustomFactor`` per board or view, computed with numpy.

A grouped factor holds its measurements and gives ``evaluate(*variables, jacobians) -> (error,
*Jacobians)`` (error (dim,), already whitened; ``order="F"`` Jacobians or None); ``factor()`` wraps
it in a ``CustomFactor`` with a unit noise model of that dimension (see docs/factors.md for why few,
large Python factors). ``CornerGroupFactor`` adds what the bearing and pixel factors share: each
corner's 2-vector whitened by its own 2x2 covariance, an optional m-estimator per corner, variance
scaling. ``pose_chain``: a point error's Jacobians through ``p_cam = T_cam_lidar * T_lidar_board * p``.
"""

from __future__ import annotations

import copy
import sys
from collections.abc import Sequence
from typing import Generic, Protocol

import gtsam
import numpy as np

if sys.version_info >= (3, 11):
    from typing import Self, TypeVarTuple, Unpack
else:
    from typing_extensions import Self, TypeVarTuple, Unpack

POSE3_DOF = 6

#: The types of a factor's variables, in the order ``evaluate`` takes them (before ``jacobians``).
Variables = TypeVarTuple("Variables")
#: What ``evaluate`` returns: the whitened error (dim,), then one Jacobian per variable (or None).
Evaluation = tuple[np.ndarray, Unpack[tuple[np.ndarray | None, ...]]]

__all__ = [
    "POSE3_DOF",
    "CornerGroupFactor",
    "Evaluation",
    "GroupedFactor",
    "MEstimator",
    "pose_chain",
    "skew",
    "sqrt_information",
]


class MEstimator(Protocol):
    """A GTSAM m-estimator (``gtsam.noiseModel.mEstimator.Huber``, ``Cauchy``, ``Tukey``, ...): its
    weight and loss of a whitened error norm are what the corner factors use. GTSAM binds both on
    each kernel, not on ``mEstimator.Base``, so a ``Base`` is not enough here."""

    def weight(self, error: float) -> float: ...

    def loss(self, error: float) -> float: ...


def skew(v: np.ndarray) -> np.ndarray:
    """(K, 3) -> (K, 3, 3) cross-product matrices."""
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -v[:, 2], v[:, 1]
    S[:, 1, 0], S[:, 1, 2] = v[:, 2], -v[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -v[:, 1], v[:, 0]
    return S


def sqrt_information(cov: np.ndarray) -> np.ndarray:
    """Upper-triangular square roots ``R`` with ``R.T @ R = inv(cov)`` for covariances (..., n, n).

    Raises ``ValueError`` when a covariance is not symmetric positive definite.
    """
    cov = np.asarray(cov, dtype=np.float64)
    if not np.all(np.isfinite(cov)):
        raise ValueError("sqrt_information: covariance has non-finite entries")
    try:
        info = np.linalg.inv(cov)
        L = np.linalg.cholesky(0.5 * (info + np.swapaxes(info, -1, -2)))
    except np.linalg.LinAlgError as exc:
        raise ValueError(f"sqrt_information: covariance is not positive definite ({exc})") from None
    return np.swapaxes(L, -1, -2).copy()


def pose_chain(
    D_e_pl: np.ndarray, R_lb: np.ndarray, p_lidar: np.ndarray, p_board: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians (K, m, 6) of point errors w.r.t. ``T_cam_lidar`` and ``T_lidar_board`` (GTSAM Pose3
    tangents, as ``transformFrom``) from ``d e / d p_lidar`` (K, m, 3) already chained through R_cl.

    ``d p_cam / d T_cam_lidar = [-R_cl [p_lidar]x, R_cl]``, ``d p_cam / d T_lidar_board =
    R_cl [-R_lb [p_board]x, R_lb]``; p_lidar, p_board (K, 3), R_lb (3, 3).
    """
    K, m = D_e_pl.shape[:2]
    H_cam = np.empty((K, m, POSE3_DOF))
    H_cam[:, :, :3] = -D_e_pl @ skew(p_lidar)
    H_cam[:, :, 3:] = D_e_pl
    D_e_pb = D_e_pl @ R_lb
    H_board = np.empty((K, m, POSE3_DOF))
    H_board[:, :, :3] = -D_e_pb @ skew(p_board)
    H_board[:, :, 3:] = D_e_pb
    return H_cam, H_board


class GroupedFactor(Generic[Unpack[Variables]]):
    """Base of the grouped factors: ``keys``, ``dim``, ``_variables``, ``evaluate`` in; a GTSAM factor out.

    A subclass names the types of its variables, e.g. ``GroupedFactor[gtsam.Pose3, np.ndarray]``, and
    its ``evaluate(T, lidar, jacobians)`` and ``_variables`` are checked against them.
    """

    keys: tuple[int, ...]

    @property
    def dim(self) -> int:
        """Error dimension."""
        raise NotImplementedError

    def _variables(self, values: gtsam.Values, keys: Sequence[int]) -> tuple[Unpack[Variables]]:
        """The variables' current values from ``values``, in the order ``evaluate`` takes them."""
        raise NotImplementedError

    def evaluate(self, *args: Unpack[tuple[Unpack[Variables], bool]]) -> Evaluation:
        """(error (dim,), one Jacobian per variable, each None without ``jacobians``) at the variables
        (``*args``: each factor's own variables, then ``jacobians``)."""
        raise NotImplementedError

    def _error(
        self, this: gtsam.CustomFactor, values: gtsam.Values, H: gtsam.JacobianVector | None
    ) -> np.ndarray:
        keys = this.keys()
        r, *A = self.evaluate(*self._variables(values, keys), H is not None)
        if H is not None:
            for i in range(len(keys)):
                A_i = A[i]
                if A_i is None:
                    raise TypeError(
                        f"{type(self).__name__}.evaluate gave no Jacobian {i} with jacobians=True"
                    )
                H[i] = A_i
        return r

    def factor(self) -> gtsam.CustomFactor:
        """The GTSAM factor (unit noise model of dimension ``dim``, whitening done inside)."""
        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(self.dim), list(self.keys), self._error)


class CornerGroupFactor(GroupedFactor[Unpack[Variables]]):
    """Corners with a 2-vector error each, whitened by ``sqrt_info`` (K, 2, 2); an optional GTSAM
    m-estimator ``robust`` per corner, exactly as ``noiseModel.Robust`` would do for a single-corner
    factor: linearisation scaled by ``sqrt(w(|r_k|))``, cost ``sum_k rho(|r_k|)``."""

    sqrt_info: np.ndarray
    robust: MEstimator | None
    n_corners: int

    def with_robust(self, robust: MEstimator | None) -> Self:
        """The same measurements with another (or no) m-estimator; shares the arrays."""
        other = copy.copy(self)
        other.robust = robust
        return other

    def scaled(self, variance_scale: float) -> Self:
        """The same measurements with every corner covariance multiplied by ``variance_scale`` (> 0)."""
        if not variance_scale > 0:
            raise ValueError(
                f"{type(self).__name__}.scaled: variance_scale must be > 0, got {variance_scale!r}"
            )
        other = copy.copy(self)
        other.sqrt_info = self.sqrt_info / np.sqrt(variance_scale)
        return other

    @property
    def dim(self) -> int:
        """Error dimension 2K."""
        return 2 * self.n_corners

    def _robust_scales(self, r: np.ndarray, jacobians: bool) -> np.ndarray | None:
        """Per corner the factor on its whitened error r (K, 2): ``sqrt(2 rho(|r_k|)) / |r_k|`` for the
        cost, ``sqrt(w(|r_k|))`` for linearisation (rows too); None without an m-estimator."""
        if self.robust is None:
            return None
        norms = np.linalg.norm(r, axis=1)
        if jacobians:
            return np.sqrt([self.robust.weight(float(x)) for x in norms])
        loss = np.array([self.robust.loss(float(x)) for x in norms])
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(norms > 0, np.sqrt(2.0 * loss) / norms, 1.0)
