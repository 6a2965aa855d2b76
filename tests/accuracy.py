"""Accuracy checks shared by the tests: a pose error judged against the run's own covariance."""

from __future__ import annotations

import gtsam
import numpy as np
from scipy.stats import chi2

#: chi-square bound of a 6-dof NEES at 99.9 %: a test at it fails by chance once in 1000 seeds
NEES_BOUND = float(chi2.ppf(0.999, 6))


def pose_nees(T: np.ndarray, C: np.ndarray, T_true: np.ndarray) -> float:
    """NEES of the estimate ``T`` (4, 4) with covariance ``C`` (6, 6, GTSAM's Pose3 tangent) against
    ``T_true``: ``xi^T C^-1 xi`` with ``T_true = T Exp(xi)``."""
    xi = gtsam.Pose3(np.asarray(T, dtype=np.float64)).localCoordinates(gtsam.Pose3(np.asarray(T_true)))
    return float(xi @ np.linalg.solve(np.asarray(C, dtype=np.float64), xi))
