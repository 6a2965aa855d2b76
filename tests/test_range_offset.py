"""Tests of factors/range_offset.py and the range offset in the sessions strategy."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, O
from synthetic_graph import lidar_board_pose, random_board_pose, random_spd, session_frames

from factors.range_offset import (
    RangeOffsetBoardFactor,
    range_offset_direction,
    range_offset_error,
    shifted_board_pose,
)
from factors.testing import factor_jacobian_error, numerical_jacobian, random_pose
from ilcc_graph.board import Board
from ilcc_graph.cameras import Equirectangular
from ilcc_graph.estimation import NoiseOptions
from ilcc_graph.estimation.graphs import board_face_samples
from ilcc_graph.estimation.sessions import JointOptions, Session, solve_sessions

BOARD = Board(6, 8, 0.075)
SAMPLES = board_face_samples(BOARD)
CAMERA = Equirectangular(8000, 4000)
T_TRUE = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.03, -0.05, 0.07), np.array([0.05, -0.03, -0.25]))


@pytest.mark.parametrize("offset", [0.0, 0.03, -0.2])
def test_jacobians_match_numerical(offset: float) -> None:
    rng = np.random.default_rng(3)
    for _ in range(5):
        T = random_board_pose(rng, BOARD)
        T_meas = T.compose(random_pose(rng, 0.05, 0.05))
        H_T = np.zeros((6, 6), order="F")
        H_b = np.zeros((6, 1), order="F")
        range_offset_error(T_meas, T, offset, SAMPLES, H_T, H_b)

        def f(T_: gtsam.Pose3, b_: np.ndarray, T_meas: gtsam.Pose3 = T_meas) -> np.ndarray:
            return range_offset_error(T_meas, T_, float(b_[0]), SAMPLES)

        args = [T, np.array([offset])]
        assert np.abs(H_T - numerical_jacobian(f, args, 0)).max() < 1e-7
        assert np.abs(H_b - numerical_jacobian(f, args, 1)).max() < 1e-7
        H_o = np.zeros((6, 3))
        o = T.transformTo(np.zeros(3))
        range_offset_direction(o, SAMPLES, H_o)
        H_num = numerical_jacobian(lambda v: range_offset_direction(v, SAMPLES), [o], 0)
        assert np.abs(H_o - H_num).max() < 1e-7


def test_custom_factor_jacobians_and_zero_offset_is_prior() -> None:
    rng = np.random.default_rng(4)
    T = random_board_pose(rng, BOARD)
    T_meas = T.compose(random_pose(rng, 0.02, 0.02))
    cov = random_spd(rng, np.array([2e-3, 2e-3, 1e-3, 3e-3, 3e-3, 2e-3]))
    fac = RangeOffsetBoardFactor(B(0), O(0), T_meas.matrix(), cov, SAMPLES).factor()
    values = gtsam.Values()
    values.insert(B(0), T)
    values.insert(O(0), np.array([0.03]))
    assert factor_jacobian_error(fac, values) < 1e-4  # whitened: 1/sigma ~ 1e3 times the raw Jacobian
    values.update(O(0), np.array([0.0]))
    prior = gtsam.PriorFactorPose3(B(0), T_meas, gtsam.noiseModel.Gaussian.Covariance(cov))
    assert fac.error(values) == pytest.approx(prior.error(values), rel=1e-12)
    A_ours = np.asarray(fac.linearize(values).jacobian()[0])[:, :6]
    A_prior = np.asarray(prior.linearize(values).jacobian()[0])
    assert np.abs(A_ours - A_prior).max() < 1e-9 * np.abs(A_prior).max()


def test_model_matches_exact_rigid_fit_of_shifted_points() -> None:
    """The first-order model against a Kabsch fit of the board's face pushed b along each ray."""
    rng = np.random.default_rng(5)
    b = 0.03
    for _ in range(10):
        T = random_board_pose(rng, BOARD)
        exact = lidar_board_pose(T, BOARD, b)
        model = shifted_board_pose(T, b, SAMPLES)
        shift = T.localCoordinates(exact)
        err = model.localCoordinates(exact)
        # the shift is ~b (translation) and up to a few mrad (tilt); the model leaves < 1 % of it
        assert 0.8 * b < np.linalg.norm(shift[3:]) < 1.2 * b
        assert np.abs(err[3:]).max() < 0.01 * b
        assert np.abs(err[:3]).max() < 0.01 * b / 1.5 + 1e-6


def test_head_on_board_shifts_along_its_normal_only() -> None:
    """A board facing the LiDAR square on: the fit moves b away along the ray and does not tilt."""
    x_b, z_b = np.array([0.0, 1.0, 0.0]), np.array([-1.0, 0.0, 0.0])  # printed face towards the LiDAR
    R = np.column_stack([x_b, np.cross(z_b, x_b), z_b])
    centre = np.array([3.0, 0.0, 0.0])
    c_board = SAMPLES.mean(axis=0)
    T = gtsam.Pose3(gtsam.Rot3(R), centre - R @ c_board)
    g = range_offset_direction(T.transformTo(np.zeros(3)), SAMPLES)
    assert np.abs(g[:3]).max() < 1e-12
    v_lidar = R @ g[3:]
    # the mean cosine between the rays to the face and the normal
    expected = np.mean(3.0 / np.linalg.norm(SAMPLES - c_board + [0.0, 0.0, 3.0], axis=1))
    assert v_lidar[0] == pytest.approx(expected, rel=1e-9)
    assert np.abs(v_lidar[1:]).max() < 1e-12


def test_rejects_collinear_samples() -> None:
    with pytest.raises(ValueError, match="collinear"):
        range_offset_direction(np.zeros(3), np.column_stack([np.arange(5.0), np.zeros(5), np.zeros(5)]))


@pytest.mark.parametrize(("offset", "seed"), [(0.03, 11), (-0.015, 12)])
def test_graph_recovers_offset_and_extrinsic(offset: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    frames, _ = session_frames(rng, 15, CAMERA, T_TRUE, BOARD, range_offset_m=offset)
    sess = [Session("A", frames, CAMERA, board=BOARD)]
    with_offset = solve_sessions(sess, JointOptions(range_offset=True))
    ro = with_offset.range_offsets["lidar"]
    assert ro.sigma_m < 3e-3
    assert abs(ro.value_m - offset) < 3 * ro.sigma_m
    xi = T_TRUE.localCoordinates(with_offset.joint.pose)
    assert np.all(np.abs(xi) < 4 * with_offset.joint.sigmas)
    if abs(offset) >= 0.03:  # ignoring a 30 mm offset biases the extrinsic well beyond its sigma
        # against the stated noise: the graph's variance components would otherwise widen the
        # covariance to cover part of the unmodelled offset (which is what they are for)
        plain = JointOptions(
            range_offset=False, noise=NoiseOptions(chi2_gate_prob=None, variance_components=False)
        )
        without = solve_sessions(sess, plain)
        xi0 = T_TRUE.localCoordinates(without.joint.pose)
        assert xi0 @ np.linalg.solve(without.joint.covariance, xi0) > 25.0
