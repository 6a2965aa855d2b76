"""The variance components' own uncertainty in the covariances (``estimation/components.py``)."""

from __future__ import annotations

import gtsam
import numpy as np
from scipy.special import polygamma
from test_board_plane import CAMERA, T_TRUE, bent_frames

from ilcc_graph.estimation import NoiseOptions, plane
from ilcc_graph.estimation.components import MIN_POSTERIOR_REDUNDANCY
from ilcc_graph.estimation.keys import X
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.noise import solve_problem
from ilcc_graph.estimation.problem import frames_problem


def _solved(seed: int, n_frames: int, bend=(0.004, np.radians(0.4)), errors=True):
    rng = np.random.default_rng(seed)
    frames = bent_frames(rng, n_frames, bend)
    T0 = T_TRUE.compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6))).matrix()
    lo = LidarErrorOptions(board_plane_estimate=True) if errors else None
    problem = frames_problem(frames, CAMERA, T0, lidar_errors=lo)
    return solve_problem(problem, NoiseOptions())


def _extrinsic_log(sol, scales) -> np.ndarray:
    """The extrinsic (tangent at ``sol``'s) of a re-solve with the components fixed at ``scales``."""
    names = [sol.problem.boards[i].name for i in sol.boards]
    again = solve_problem(sol.problem, NoiseOptions(), boards=names, scales=scales,
                          variance_factor=sol.variance_factor, gate=False)  # fmt: skip
    T0 = sol.values.atPose3(X(0))
    return np.asarray(gtsam.Pose3.Logmap(T0.between(again.values.atPose3(X(0)))))


def test_component_shifts_match_re_solves_with_the_component_moved() -> None:
    """Each spread entry's extrinsic shift per unit of log s is what re-solving with that component
    moved (central differences, +-0.1 in log s) gives, to a tenth of the shift."""
    sol = _solved(5, 8)
    keys = [k for k, s in sol.scales.items() if k[0] != "bearing" and sol.covariance_scales[k] != s]
    assert len(sol.spread) == len(keys) >= 3, (keys, sol.scales)  # in-plane, points and planes' kinds
    checked = 0
    for (w, d), key in zip(sol.spread, keys, strict=True):
        r = sol.redundancy[key]
        assert np.isclose(w, polygamma(1, r / 2)) and 2.0 / r < w < 2.0 / (r - 1.0), (key, w, r)
        h = 0.1
        up = _extrinsic_log(sol, {**sol.scales, key: sol.scales[key] * np.exp(h)})
        down = _extrinsic_log(sol, {**sol.scales, key: sol.scales[key] * np.exp(-h)})
        numeric = (up - down) / (2 * h)
        if np.linalg.norm(numeric) < 1e-7:  # moves nothing (to the solver's tolerance)
            continue
        assert np.linalg.norm(d[X(0)] - numeric) < 0.1 * np.linalg.norm(numeric), (key, d[X(0)], numeric)
        checked += 1
    assert checked >= 2


def test_covariances_use_the_components_posterior_means_and_add_their_spread() -> None:
    sol = _solved(5, 8)
    post = sol.covariance_scales
    assert post is not None
    for key, s in sol.scales.items():
        r = sol.redundancy.get(key, 0.0)
        if post[key] == s:
            continue  # at its floor, or told nothing
        expected = r / (r - 2.0) if r > MIN_POSTERIOR_REDUNDANCY else 2.0
        assert np.isclose(post[key] / s, expected), (key, s, post[key], r)
    est = sol.extrinsic()
    plain = sol.marginals.covariance(X(0), "T")
    spread = sol.spread_of([X(0)], [6])
    assert np.allclose(est.covariance, plain + spread)
    assert np.linalg.eigvalsh(spread).min() > -1e-18 and np.trace(spread) > 0
    # the same solve with the components fixed at the ones found: no posterior, no spread, a
    # covariance no larger (the inflation only adds)
    names = [sol.problem.boards[i].name for i in sol.boards]
    fixed = solve_problem(sol.problem, NoiseOptions(), boards=names, scales=sol.scales,
                          variance_factor=sol.variance_factor, gate=False)  # fmt: skip
    assert fixed.covariance_scales is None and fixed.spread == []
    C0 = fixed.extrinsic().covariance
    assert np.linalg.eigvalsh(est.covariance - C0).min() > -1e-12 * np.trace(C0)


def test_components_at_their_floor_are_left_as_they_are() -> None:
    """Flat boards: a plane component at its floor is not estimated and gets neither a posterior
    mean nor a spread; the terms-off graph's board component (estimated) gets both."""
    sol = _solved(22, 24, bend=(0.0, 0.0))
    opts = sol.problem.lidar_errors
    floored = [k for k in sol.scales if k[0] in plane.KINDS and plane.at_floor(opts, k, sol.scales[k])]
    assert floored, sol.scales  # the flat boards' plane falls to its floor (test_board_plane.py)
    for k in floored:
        assert sol.covariance_scales[k] == sol.scales[k], (k, sol.scales[k], sol.covariance_scales[k])
    n_shifts = sum(1 for k, s in sol.scales.items() if k[0] != "bearing" and sol.covariance_scales[k] != s)
    assert len(sol.spread) == n_shifts
    off = _solved(5, 8, errors=False)
    board = ("board", "")
    assert off.scales[board] > 1.0, off.scales
    assert off.covariance_scales[board] > off.scales[board]
    assert len(off.spread) == 1
