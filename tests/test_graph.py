"""Tests of the estimation core's batch strategy on synthetic frames drawn from the stated covariances."""

from __future__ import annotations

import logging
from dataclasses import replace

import gtsam
import numpy as np
import pytest

from factors.testing import sample_bearing
from ilcc_graph.board import Board
from ilcc_graph.cameras import Equirectangular
from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem
from ilcc_graph.estimation import NoiseOptions, solve
from ilcc_graph.types import GraphFrame

CAMERA = Equirectangular(8000, 4000)
BOARD = Board(6, 8, 0.075)
T_TRUE = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.6, -0.4, 2.0), np.array([0.05, -0.12, -0.25]))


def random_spd(rng: np.random.Generator, sigmas: np.ndarray) -> np.ndarray:
    """SPD matrix with a random orientation and the given standard deviations."""
    Q, _ = np.linalg.qr(rng.standard_normal((len(sigmas), len(sigmas))))
    return Q @ np.diag(np.asarray(sigmas) ** 2) @ Q.T


def synthetic_problem(
    rng: np.random.Generator,
    n_frames: int,
    T_cam_lidar: gtsam.Pose3 = T_TRUE,
    board: Board = BOARD,
    camera=CAMERA,
    sigma_px: float = 0.5,
    board_sigmas: tuple[float, ...] = (2e-3, 2e-3, 1e-3, 3e-3, 3e-3, 2e-3),
) -> tuple[list[GraphFrame], dict[str, gtsam.Pose3]]:
    """Frames with boards 1.5-5 m around the LiDAR, bearings and board priors drawn from their covariances.

    Returns the frames and the true board poses. Bearings carry noise from ``cov_px`` mapped by
    ``camera.bearing_tangent_cov``; ``T_lidar_board`` is ``T_true * Expmap(xi)``, ``xi ~ N(0, board_cov)``.
    """
    frames, truth = [], {}
    p_board = board.corners_board()
    centre = p_board.mean(axis=0)
    for i in range(n_frames):
        az = rng.uniform(-np.pi, np.pi)
        el = rng.uniform(-0.35, 0.35)
        d = rng.uniform(1.5, 5.0)
        c_lidar = d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        z = -c_lidar / d  # the printed face looks back at the sensor
        tilt = gtsam.Rot3.Expmap(rng.normal(0, 0.4, 3))
        z = tilt.rotate(z)
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z])
        T_lb = gtsam.Pose3(gtsam.Rot3(R), c_lidar - R @ centre)
        p_cam = np.array([T_cam_lidar.transformFrom(T_lb.transformFrom(p)) for p in p_board])
        b_true = p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
        cov_px = np.stack([random_spd(rng, sigma_px * rng.uniform(0.6, 1.4, 2)) for _ in p_board])
        bases = np.stack([gtsam.Unit3(b).basis() for b in b_true])
        cov_t = camera.bearing_tangent_cov(b_true, cov_px, bases)
        b_meas = sample_bearing(rng, b_true, cov_t)
        board_cov = random_spd(rng, np.asarray(board_sigmas) * rng.uniform(0.7, 1.3, 6))
        xi = rng.multivariate_normal(np.zeros(6), board_cov)
        name = f"{i:04d}"
        frames.append(
            GraphFrame(name, (T_lb * gtsam.Pose3.Expmap(xi)).matrix(), board_cov, p_board, b_meas, cov_px)
        )
        truth[name] = T_lb
    return frames, truth


def perturbed(T: gtsam.Pose3, rng: np.random.Generator, rot: float = 0.03, trans: float = 0.05) -> np.ndarray:
    return (T * gtsam.Pose3.Expmap(np.concatenate([rng.normal(0, rot, 3), rng.normal(0, trans, 3)]))).matrix()


def nees(solution, T_true: gtsam.Pose3 = T_TRUE) -> float:
    xi = gtsam.Pose3(solution.T_cam_lidar).localCoordinates(T_true)
    return float(xi @ np.linalg.solve(solution.covariance, xi))


def test_recovers_truth_and_reports_stats() -> None:
    rng = np.random.default_rng(1)
    frames, truth = synthetic_problem(rng, 8)
    sol = solve(frames, CAMERA, perturbed(T_TRUE, rng))
    assert sol.dropped == []
    assert set(sol.per_frame) == {f.name for f in frames} == set(sol.T_lidar_board)
    xi = gtsam.Pose3(sol.T_cam_lidar).localCoordinates(T_TRUE)
    sig = np.sqrt(np.diag(sol.covariance))
    assert np.all(np.abs(xi) < 5 * sig)
    assert sig[:3].max() < 1e-3 and sig[3:].max() < 5e-3  # < 0.06 deg, < 5 mm with 8 frames
    for f in frames:
        s = sol.per_frame[f.name]
        assert s.dof == 2 * BOARD.n_corners
        assert 0.1 < s.chi2 / s.dof < 2.5
        assert 0.1 < s.rms_bearing_error_mrad < 1.5  # 0.5 px ~ 0.4 mrad per axis
    assert np.allclose(np.linalg.det(sol.T_cam_lidar[:3, :3]), 1.0)
    assert sol.iterations > 0 and sol.timings["total"] > 0
    assert isinstance(sol.pose, gtsam.Pose3)


def test_covariance_convention_and_nees() -> None:
    """Monte Carlo: xi = Logmap(T_est^-1 T_true) has the reported covariance (interface.md).

    The mean NEES under the right convention is ~6; under the left one (``T_true = Expmap(xi) * T_est``,
    ``xi_left = Ad(T_est) xi``) the same covariance would be clearly wrong for this rig, which the
    test checks first so that it can tell the two apart.
    """
    rng = np.random.default_rng(7)
    right, left, expected_left = [], [], []
    for _ in range(30):
        frames, _ = synthetic_problem(rng, 5)
        sol = solve(frames, CAMERA, perturbed(T_TRUE, rng))
        T_est = gtsam.Pose3(sol.T_cam_lidar)
        info = np.linalg.inv(sol.covariance)
        xi = T_est.localCoordinates(T_TRUE)
        xi_left = gtsam.Pose3.Logmap(T_TRUE * T_est.inverse())
        assert np.allclose(xi_left, T_est.AdjointMap() @ xi, atol=1e-9)
        right.append(xi @ info @ xi)
        left.append(xi_left @ info @ xi_left)
        Ad = T_est.AdjointMap()
        expected_left.append(np.trace(info @ Ad @ sol.covariance @ Ad.T))
    assert np.mean(expected_left) > 12.0  # the rig tells the conventions apart
    # 30 runs of chi2(6): mean 6 with standard error 0.63
    assert 4.2 < np.mean(right) < 7.8, np.mean(right)
    assert np.mean(left) > 9.0, np.mean(left)


@pytest.mark.parametrize("robust", [None, "huber"])
def test_outlier_frame_is_dropped(robust: str | None) -> None:
    rng = np.random.default_rng(11)
    frames, _ = synthetic_problem(rng, 7)
    bad = frames[3]
    # the image corners of frame 3 belong to a board 4 cm away: a gross correspondence error
    shifted = gtsam.Pose3(bad.T_lidar_board) * gtsam.Pose3(gtsam.Rot3(), np.array([0.04, 0.0, 0.0]))
    b_bad = np.array([T_TRUE.transformFrom(shifted.transformFrom(p)) for p in bad.points_board])
    frames[3] = replace(bad, bearings=b_bad / np.linalg.norm(b_bad, axis=1, keepdims=True))
    sol = solve(frames, CAMERA, perturbed(T_TRUE, rng), NoiseOptions(robust=robust))
    assert [name for name, _ in sol.dropped] == [bad.name]
    assert "chi-square" in sol.dropped[0][1]
    assert bad.name not in sol.per_frame and len(sol.per_frame) == 6
    xi = gtsam.Pose3(sol.T_cam_lidar).localCoordinates(T_TRUE)
    assert np.all(np.abs(xi) < 5 * np.sqrt(np.diag(sol.covariance)))


def test_few_frames_warn_and_none_is_impossible(caplog: pytest.LogCaptureFixture) -> None:
    rng = np.random.default_rng(5)
    frames, _ = synthetic_problem(rng, 2)
    with caplog.at_level(logging.WARNING, logger="ilcc_graph.estimation"):
        sol = solve(frames, CAMERA, perturbed(T_TRUE, rng))
    assert any("only 2 usable frame" in r.getMessage() for r in caplog.records)
    assert np.all(np.isfinite(sol.covariance))
    with pytest.raises(CalibrationImpossible):
        solve([], CAMERA, T_TRUE.matrix())
    # a frame whose bearings are all unusable is dropped before the graph: nothing is left
    f = frames[0]
    nan_frame = replace(f, bearings=np.full_like(f.bearings, np.nan))
    with pytest.raises(CalibrationImpossible, match="only 0 corners"):
        solve([nan_frame], CAMERA, T_TRUE.matrix())


def test_indeterminate_system_is_reported() -> None:
    """Three corners on one line through the camera centre cannot fix the extrinsic."""
    rng = np.random.default_rng(2)
    frames, _ = synthetic_problem(rng, 1)
    f = frames[0]
    # a board prior that is nearly free and corners that all lie on one ray: rank-deficient
    line = np.array([[0.1, 0.1, 0.0], [0.2, 0.1, 0.0], [0.3, 0.1, 0.0]])
    T_lb = gtsam.Pose3(f.T_lidar_board)
    p_cam = np.array([T_TRUE.transformFrom(T_lb.transformFrom(p)) for p in line])
    b = p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
    frame = GraphFrame(
        "line", f.T_lidar_board, np.eye(6) * 1e4, line, b, np.tile(np.eye(2) * 0.25, (3, 1, 1))
    )
    with pytest.raises(IndeterminateSystem):
        solve([frame], CAMERA, T_TRUE.matrix(), NoiseOptions(chi2_gate_prob=None))


def test_bad_input_is_named() -> None:
    rng = np.random.default_rng(4)
    frames, _ = synthetic_problem(rng, 1)
    with pytest.raises(ValueError, match="T_init"):
        solve(frames, CAMERA, np.eye(3))
    with pytest.raises(ValueError, match="0000"):
        solve([replace(frames[0], cov_px=frames[0].cov_px[:, :1])], CAMERA, T_TRUE.matrix())
    with pytest.raises(ValueError, match="robust"):
        solve(frames, CAMERA, T_TRUE.matrix(), NoiseOptions(robust="nope"))
    with pytest.raises(ValueError, match="unique"):
        solve(frames + frames, CAMERA, T_TRUE.matrix())


def test_robust_kernel_keeps_frame_with_one_bad_corner() -> None:
    """One corner 20 mrad off: the plain gate drops its frame, a redescending kernel keeps it."""
    rng = np.random.default_rng(13)
    frames, _ = synthetic_problem(rng, 6)
    f = frames[2]
    b = f.bearings.copy()
    b[10] = gtsam.Unit3(b[10]).retract(np.array([0.02, 0.0])).point3()
    frames[2] = replace(f, bearings=b)
    T0 = perturbed(T_TRUE, rng)
    plain = solve(frames, CAMERA, T0)
    assert [name for name, _ in plain.dropped] == [f.name]
    robust = solve(frames, CAMERA, T0, NoiseOptions(robust="tukey"))
    assert robust.dropped == []
    s = robust.per_frame[f.name]
    assert s.chi2 > 1000 and s.chi2_robust is not None and s.chi2_robust < s.chi2
    for sol in (plain, robust):
        xi = gtsam.Pose3(sol.T_cam_lidar).localCoordinates(T_TRUE)
        assert np.all(np.abs(xi) < 5 * np.sqrt(np.diag(sol.covariance)))


def test_pinhole_camera_and_corners_it_cannot_see() -> None:
    """Bearings in OpenCV's frame; a board behind the camera has no usable corner and is dropped."""
    from ilcc_graph.cameras import Pinhole

    camera = Pinhole(
        1280, 960, np.array([[800.0, 0, 640], [0, 800.0, 480], [0, 0, 1]]), np.array([-0.1, 0.01, 0, 0])
    )
    # LiDAR x forward, y left, z up -> OpenCV z forward, x right, y down; camera 10 cm above
    R_cv_lidar = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    T_cl = gtsam.Pose3(gtsam.Rot3(R_cv_lidar) * gtsam.Rot3.Rz(0.02), np.array([0.02, -0.1, 0.05]))
    rng = np.random.default_rng(17)
    frames = []
    while len(frames) < 6:  # keep boards whose corners all land in the image
        f, _ = synthetic_problem(rng, 1, T_cam_lidar=T_cl, camera=camera)
        p_cam = np.array(
            [T_cl.transformFrom(gtsam.Pose3(f[0].T_lidar_board).transformFrom(p)) for p in f[0].points_board]
        )
        if np.all(camera.in_image(camera.project(p_cam))):
            frames.append(replace(f[0], name=f"{len(frames):04d}"))
    behind = replace(frames[0], name="behind", bearings=-frames[0].bearings)
    sol = solve(frames + [behind], camera, perturbed(T_cl, rng, rot=0.01, trans=0.02))
    assert sol.dropped[0][0] == "behind" and "only 0 corners" in sol.dropped[0][1]
    xi = gtsam.Pose3(sol.T_cam_lidar).localCoordinates(T_cl)
    assert np.all(np.abs(xi) < 5 * np.sqrt(np.diag(sol.covariance)))
