"""What one more board adds to a solved problem (``estimation.next_board``, issue 34 item 3), against
GTSAM itself: the solved graph with the new board's own factors added (its corners' bearing factor
and its range-offset board prior) gives, through ``gtsam.Marginals``, the extrinsic's covariance
after the board; the information the extrinsic's marginal gains must be what ``extrinsic_gain`` of
``board_information`` says. And the range offset is what the promise was missing: leaving it out
(the board's prior as the LiDAR stage's pose alone, as before) is not what the graph gives."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
from synthetic_graph import observe, random_board_pose, session_frames

from factors.range_offset import RangeOffsetBoardFactor, shifted_board_pose
from ilcc_graph.board import Board
from ilcc_graph.cameras import Equirectangular
from ilcc_graph.estimation import NoiseOptions
from ilcc_graph.estimation.graphs import frame_bearing_factor, samples_from_corners
from ilcc_graph.estimation.keys import B, O, X
from ilcc_graph.estimation.next_board import board_information, extrinsic_gain, solved_globals
from ilcc_graph.estimation.noise import solve_problem
from ilcc_graph.estimation.problem import frames_problem

BOARD = Board(6, 8, 0.075)
CAMERA = Equirectangular(4000, 2000)
T_TRUE = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.03, -0.05, 0.07), np.array([0.05, -0.03, -0.25]))


def _solved(offset: bool):  # noqa: ANN202 - noise.Solution
    rng = np.random.default_rng(11)
    frames, _ = session_frames(rng, 6, CAMERA, T_TRUE, BOARD, range_offset_m=0.02)
    problem = frames_problem(frames, CAMERA, T_TRUE.matrix())
    if offset:
        problem = dataclasses.replace(problem, range_offset_sigma_m=0.1)
    return solve_problem(problem, NoiseOptions(variance_components=False))


def _new_board(sol) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # noqa: ANN001
    rng = np.random.default_rng(5)
    while True:
        T = random_board_pose(rng, BOARD)
        obs = observe(
            rng, CAMERA, gtsam.Pose3(sol.values.atPose3(X(0)).matrix()), T, BOARD.corners_board(), 0.5
        )
        if obs is not None:
            cov = np.diag([2e-3, 2e-3, 1e-3, 3e-3, 3e-3, 2e-3]) ** 2
            return np.asarray(T.matrix()), cov, obs[0], obs[1]


def _gtsam_after(sol, T: np.ndarray, cov: np.ndarray, bearings: np.ndarray, cov_px: np.ndarray) -> np.ndarray:  # noqa: ANN001
    """The extrinsic's covariance once the board's own factors join the solved graph (GTSAM)."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values(sol.values)
    graph.push_back(sol.graph)
    n = len(sol.problem.boards)
    fac, _ = frame_bearing_factor(X(0), B(n), BOARD.corners_board(), bearings, cov_px, CAMERA)
    graph.add(fac.factor())
    if sol.values.exists(O(0)):
        b = float(sol.values.atVector(O(0))[0])
        samples = samples_from_corners(BOARD.corners_board())
        measured = shifted_board_pose(gtsam.Pose3(T), b, samples).matrix()
        graph.add(RangeOffsetBoardFactor(B(n), O(0), measured, cov, samples).factor())
    else:
        graph.add(gtsam.PriorFactorPose3(B(n), gtsam.Pose3(T), gtsam.noiseModel.Gaussian.Covariance(cov)))
    values.insert(B(n), gtsam.Pose3(T))
    return gtsam.Marginals(graph, values).marginalCovariance(X(0)) * sol.variance_factor


def test_the_gain_is_gtsams_with_and_without_a_range_offset() -> None:
    for offset in (False, True):
        sol = _solved(offset)
        g = solved_globals(sol)
        assert g.dim == 6 + offset and g.terms == (("offset",) if offset else ())
        before = gtsam.Marginals(sol.graph, sol.values).marginalCovariance(X(0)) * sol.variance_factor
        np.testing.assert_allclose(g.covariance[:6, :6], before, rtol=1e-6, atol=1e-14)
        T, cov, bearings, cov_px = _new_board(sol)
        a = np.ones(1) if offset else None
        info = board_information(g, T, cov, BOARD.corners_board(), bearings, cov_px, CAMERA, a)
        after = _gtsam_after(sol, T, cov, bearings, cov_px)
        want = np.linalg.inv(after) - np.linalg.inv(before)
        np.testing.assert_allclose(extrinsic_gain(g, info), want, rtol=1e-4, atol=1e-6 * np.abs(want).max())


def test_the_offset_left_out_is_not_gtsams() -> None:
    """With the offset in the graph, the board's prior taken as the LiDAR stage's pose alone (as the
    promise was made before: the offset's share in it forgotten) is not what GTSAM's graph gives."""
    sol = _solved(True)
    g = solved_globals(sol)
    T, cov, bearings, cov_px = _new_board(sol)
    before = g.covariance[:6, :6]
    want = np.linalg.inv(_gtsam_after(sol, T, cov, bearings, cov_px)) - np.linalg.inv(before)
    forgotten = extrinsic_gain(
        g, board_information(g, T, cov, BOARD.corners_board(), bearings, cov_px, CAMERA)
    )
    assert np.abs(forgotten - want).max() > 1e-3 * np.abs(want).max()
