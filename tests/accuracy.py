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


def mean_band(dof: int, n: int, p: float = 0.001) -> tuple[float, float]:
    """Two-sided band of the mean of ``n`` independent chi-square(``dof``) draws, probability ``p``
    outside it: ``chi2(dof n) / n`` at ``p / 2`` and ``1 - p / 2`` (mean ``dof``, SD ``sqrt(2 dof / n)``).
    The mean NEES of honest runs stays inside; a covariance k x too small multiplies it by k, one k x
    too large divides it by k."""
    return float(chi2.ppf(p / 2, dof * n) / n), float(chi2.ppf(1 - p / 2, dof * n) / n)


def assert_two_sided(nees, what: str = "") -> None:  # noqa: ANN001 - a sequence of NEES
    """Runs' NEES (6 dof) honest both ways: each under one draw's bound, their mean in
    ``mean_band(6, n)``; and that band has power on these very runs: the same NEES with the covariance
    scaled by 9 and by 1/9 fall outside it (test_cli_honesty.py's docstring gives the numbers)."""
    nees = np.asarray(nees, dtype=np.float64)
    lo, hi = mean_band(6, len(nees))
    assert np.all(nees < NEES_BOUND), (what, nees)
    assert lo < nees.mean() < hi, (what, nees, (lo, hi))
    assert np.mean(nees / 9) < lo and np.mean(9 * nees) > hi, (what, nees)


#: the seeds of the two-sided honesty checks through the command line (a band of 1.48 .. 14.8)
HONESTY_SEEDS = (1, 2, 3)


def cli_nees(simulated, calibrated, camera: str, *flags: str) -> list[float]:  # noqa: ANN001
    """NEES against the truth of ``simulate --camera CAMERA FLAGS`` + ``calibrate`` (conftest's
    factories: 640 px, 1200 for a panorama, 5 frames) on each of ``HONESTY_SEEDS``; every run uses 3
    or more frames."""
    import yaml

    out = []
    for seed in HONESTY_SEEDS:
        data = simulated(camera, *flags, seed=seed)
        cal = yaml.safe_load((calibrated(data) / "calibration.yaml").read_text())
        assert sum(f["used"] for f in cal["frames"]) >= 3, (camera, flags, seed)
        truth = yaml.safe_load((data / "ground_truth.yaml").read_text())["T_cam_lidar"]
        out.append(pose_nees(cal["T_cam_lidar"], cal["covariance"], truth))
    return out
