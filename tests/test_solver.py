"""The core's Levenberg-Marquardt (estimation.solver.optimize) against GTSAM's own optimizer."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from ilcc_graph.errors import IndeterminateSystem
from ilcc_graph.estimation.solver import SolverOptions, optimize

N = 12


def _loop(seen: list | None = None) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """A noisy loop of N poses (built-in between factors) with a Python range factor per pose to a
    beacon, started far off: a nonlinear problem with Python and C++ factors. ``seen`` collects the
    ``Values`` objects the Python callbacks receive."""
    rng = np.random.default_rng(7)
    truth = [gtsam.Pose3(gtsam.Rot3.Rz(2 * np.pi * i / N), np.array([3 * np.cos(2 * np.pi * i / N),
             3 * np.sin(2 * np.pi * i / N), 0.1 * i])) for i in range(N)]  # fmt: skip
    beacon = np.array([0.5, -0.4, 2.0])
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(0, truth[0], gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    between = gtsam.noiseModel.Diagonal.Sigmas(np.r_[0.02, 0.02, 0.02, 0.05, 0.05, 0.05])
    for i in range(N):
        d = truth[i].between(truth[(i + 1) % N]).compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6)))
        graph.add(gtsam.BetweenFactorPose3(i, (i + 1) % N, d, between))
    unit = gtsam.noiseModel.Isotropic.Sigma(1, 0.02)
    for i in range(N):
        rho = np.linalg.norm(truth[i].transformTo(beacon)) + rng.normal(0, 0.02)

        def err(
            this: gtsam.CustomFactor, values: gtsam.Values, H: list | None, rho: float = rho
        ) -> np.ndarray:  # noqa: E501
            if seen is not None:
                seen.append(values)
            T = values.atPose3(this.keys()[0])
            Hp = np.zeros((3, 6), order="F")
            p = T.transformTo(beacon, Hp)
            r = np.linalg.norm(p)
            if H is not None:
                H[0] = (p / r)[None, :] @ Hp
            return np.array([r - rho])

        graph.add(gtsam.CustomFactor(unit, [i], err))
    values = gtsam.Values()
    for i in range(N):
        values.insert(i, truth[i].compose(gtsam.Pose3.Expmap(rng.normal(0, 0.3, 6))))
    return graph, values


def test_same_optimum_as_gtsam_levenberg_marquardt() -> None:
    graph, values = _loop()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    gt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    theirs = gt.optimize()
    ours, steps = optimize(graph, values, SolverOptions())
    assert graph.error(values) > 1e3 * graph.error(theirs)  # the start was far off
    assert graph.error(ours) == pytest.approx(graph.error(theirs), rel=1e-9)
    for i in range(N):
        d = gtsam.Pose3.Logmap(theirs.atPose3(i).between(ours.atPose3(i)))
        assert np.abs(d).max() < 1e-7
    assert abs(steps - gt.iterations()) <= 1
    again, more = optimize(graph, ours)  # from the optimum: at most a step below the tolerance
    assert more <= 1 and graph.error(again) == pytest.approx(graph.error(ours), rel=1e-12)


def test_callbacks_see_the_python_values_not_copies() -> None:
    """GTSAM's optimizer hands each Python callback a copy of its whole Values; ours one object per
    linearisation or cost evaluation."""
    seen: list = []
    graph, values = _loop(seen)
    gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    theirs = len({id(v) for v in seen}) / len(seen)
    seen.clear()
    optimize(graph, values)
    ours = len({id(v) for v in seen}) / len(seen)
    assert theirs > 0.8  # a copy per callback (all but the cost at the start)
    assert ours <= 1.5 / N  # all N callbacks of one evaluation share it


def test_non_finite_start_is_indeterminate() -> None:
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [0], lambda f, v, H: np.array([np.nan])))
    values = gtsam.Values()
    values.insert(0, np.zeros(1))
    with pytest.raises(IndeterminateSystem, match="not finite"):
        optimize(graph, values)
