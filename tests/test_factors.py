"""Tests of factors/: Jacobians against central differences, grouped vs single factors, and
agreement with GTSAM's own SphericalCamera factors."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, L, X

from factors import (
    FrameBearingFactor,
    bearing_error,
    bearing_factor,
    bearing_point_factor,
    board_bearing_error,
    sqrt_information,
    tangent_bases,
)
from factors.testing import (
    factor_jacobian_error,
    factor_jacobians,
    numerical_jacobian,
    random_pose,
    sample_bearing,
)


def _scene(rng: np.random.Generator, n: int = 6, noise_rad: float = 1e-2):
    """A random extrinsic, board pose, corners and noisy bearings over the whole sphere."""
    T_cl = random_pose(rng, trans_sigma=0.3)
    T_lb = random_pose(rng, trans_sigma=2.0)
    p_board = np.column_stack([rng.uniform(0, 0.6, n), rng.uniform(0, 0.4, n), np.zeros(n)])
    p_cam = np.array([T_cl.transformFrom(T_lb.transformFrom(p)) for p in p_board])
    b = p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
    b = sample_bearing(rng, b, np.tile(np.eye(2) * noise_rad**2, (n, 1, 1)))
    return T_cl, T_lb, p_board, b


def _random_cov2(rng: np.random.Generator, n: int) -> np.ndarray:
    A = rng.normal(0, 1e-3, (n, 2, 2))
    return A @ np.swapaxes(A, 1, 2) + np.eye(2) * 1e-7


def test_single_corner_jacobians_match_central_differences() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        T_cl, T_lb, p_board, b = _scene(rng, 1)
        u = gtsam.Unit3(b[0])
        H_cam, H_board = np.zeros((2, 6), order="F"), np.zeros((2, 6), order="F")
        board_bearing_error(T_cl, T_lb, p_board[0], u, H_cam, H_board)

        def f(T1, T2, p=p_board[0], u=u):
            return board_bearing_error(T1, T2, p, u)

        assert np.allclose(H_cam, numerical_jacobian(f, [T_cl, T_lb], 0), atol=1e-7)
        assert np.allclose(H_board, numerical_jacobian(f, [T_cl, T_lb], 1), atol=1e-7)
        p_lidar = T_lb.transformFrom(p_board[0])
        H_T, H_p = np.zeros((2, 6), order="F"), np.zeros((2, 3), order="F")
        bearing_error(T_cl, p_lidar, u, H_T, H_p)

        def g(T, p, u=u):
            return bearing_error(T, p, u)

        assert np.allclose(H_T, numerical_jacobian(g, [T_cl, p_lidar], 0), atol=1e-7)
        assert np.allclose(H_p, numerical_jacobian(g, [T_cl, p_lidar], 1), atol=1e-7)


def test_error_is_tangent_projection_without_wrap_or_pole_singularity() -> None:
    """Across the azimuth seam and at the poles the error stays small and smooth."""
    T = gtsam.Pose3()
    for b_meas, p in [
        (np.array([-1.0, 1e-4, 0.0]), np.array([-2.0, -2e-4, 0.0])),  # either side of az = +-pi
        (np.array([1e-5, 0.0, 1.0]), np.array([0.0, 1e-5, 3.0])),  # at the north pole
        (np.array([0.0, 0.0, -1.0]), np.array([2e-5, 0.0, -1.0])),  # exactly the south pole
    ]:
        u = gtsam.Unit3(b_meas)
        e = bearing_error(T, p, u)
        angle = np.arccos(np.clip(u.point3() @ p / np.linalg.norm(p), -1, 1))
        assert np.isclose(np.linalg.norm(e), np.sin(angle), rtol=1e-6, atol=1e-12)
        H_T, H_p = np.zeros((2, 6), order="F"), np.zeros((2, 3), order="F")
        bearing_error(T, p, u, H_T, H_p)
        assert np.all(np.isfinite(H_T)) and np.allclose(
            H_p, numerical_jacobian(lambda q, u=u: bearing_error(T, q, u), [p], 0), atol=1e-6
        )


def test_custom_factors_jacobians() -> None:
    rng = np.random.default_rng(1)
    T_cl, T_lb, p_board, b = _scene(rng, 5)
    values = gtsam.Values()
    values.insert(X(0), T_cl)
    values.insert(B(0), T_lb)
    cov = _random_cov2(rng, 5)
    noise = gtsam.noiseModel.Gaussian.Covariance(cov[0])
    assert factor_jacobian_error(bearing_factor(X(0), B(0), p_board[0], b[0], noise), values) < 1e-5
    values.insert(L(0), T_lb.transformFrom(p_board[0]))
    assert factor_jacobian_error(bearing_point_factor(X(0), L(0), b[0], noise), values) < 1e-5
    group = FrameBearingFactor(X(0), B(0), p_board, b, cov)
    A = factor_jacobians(group.factor(), values)
    assert max(np.abs(a).max() for a in A) > 10  # whitened: the check is not trivially small
    assert factor_jacobian_error(group.factor(), values) < 1e-5 * max(np.abs(a).max() for a in A)


def test_grouped_factor_equals_stacked_single_factors() -> None:
    rng = np.random.default_rng(2)
    T_cl, T_lb, p_board, b = _scene(rng, 8)
    cov = _random_cov2(rng, 8)
    values = gtsam.Values()
    values.insert(X(0), T_cl)
    values.insert(B(0), T_lb)
    group = FrameBearingFactor(X(0), B(0), p_board, b, cov)
    singles = [
        bearing_factor(X(0), B(0), p_board[k], b[k], gtsam.noiseModel.Gaussian.Covariance(cov[k]))
        for k in range(8)
    ]
    whitened = np.concatenate([f.whitenedError(values) for f in singles])
    assert np.allclose(group.factor().whitenedError(values), whitened, atol=1e-12)
    assert np.isclose(group.factor().error(values), sum(f.error(values) for f in singles), rtol=1e-12)
    assert np.allclose(group.whitened(T_cl, T_lb).reshape(-1), whitened, atol=1e-12)
    H_group = factor_jacobians(group.factor(), values)
    H_single = [factor_jacobians(f, values) for f in singles]
    # GTSAM's Gaussian model whitens with a different (but equivalent) square root: compare J^T J
    for i in range(2):
        for j in range(2):
            lhs = H_group[i].T @ H_group[j]
            rhs = sum(h[i].T @ h[j] for h in H_single)
            assert np.allclose(lhs, rhs, rtol=1e-9, atol=1e-9 * np.abs(rhs).max())


def test_grouped_robust_matches_gtsam_robust_noise_model() -> None:
    rng = np.random.default_rng(3)
    T_cl, T_lb, p_board, b = _scene(rng, 6)
    b[2] = gtsam.Unit3(b[2]).retract(np.array([0.05, -0.03])).point3()  # one gross outlier
    cov = np.tile(np.eye(2) * 1e-4, (6, 1, 1))  # isotropic: both whitenings are the same matrix
    values = gtsam.Values()
    values.insert(X(0), T_cl)
    values.insert(B(0), T_lb)
    huber = gtsam.noiseModel.mEstimator.Huber.Create(1.345)
    group = FrameBearingFactor(X(0), B(0), p_board, b, cov, robust=huber)
    singles = [
        bearing_factor(
            X(0),
            B(0),
            p_board[k],
            b[k],
            gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Isotropic.Sigma(2, 1e-2)),
        )
        for k in range(6)
    ]
    assert np.isclose(group.factor().error(values), sum(f.error(values) for f in singles), rtol=1e-10)
    lin_g = group.factor().linearize(values)
    A_g, b_g = lin_g.jacobian()
    A_s = np.vstack([f.linearize(values).jacobian()[0] for f in singles])
    b_s = np.concatenate([f.linearize(values).jacobian()[1] for f in singles])
    assert np.allclose(A_g, A_s, rtol=1e-9, atol=1e-9) and np.allclose(b_g, b_s, rtol=1e-9, atol=1e-12)
    w = group.whitened(T_cl, T_lb)
    assert np.linalg.norm(w[2]) > 1.345 > np.linalg.norm(w[0])  # the outlier is in Huber's linear part


def test_helpers() -> None:
    rng = np.random.default_rng(4)
    cov = _random_cov2(rng, 5)
    R = sqrt_information(cov)
    assert np.allclose(np.swapaxes(R, 1, 2) @ R @ cov, np.eye(2), atol=1e-9)
    assert np.allclose(np.tril(R, -1), 0)
    with pytest.raises(ValueError, match="positive definite"):
        sqrt_information(np.array([[1.0, 0.0], [0.0, -1.0]]))
    b = rng.normal(size=(4, 3))
    Bs = tangent_bases(b)
    assert Bs.shape == (4, 3, 2)
    assert np.allclose(np.swapaxes(Bs, 1, 2) @ Bs, np.eye(2), atol=1e-12)
    assert np.allclose(np.einsum("kij,ki->kj", Bs, b), 0, atol=1e-12)
    with pytest.raises(ValueError, match="K>0"):
        FrameBearingFactor(X(0), B(0), np.zeros((3, 3)), np.ones((2, 3)), np.tile(np.eye(2), (3, 1, 1)))


def test_sample_bearing_covariance() -> None:
    rng = np.random.default_rng(5)
    b = np.tile([[0.3, -0.2, 0.9]], (20000, 1))
    cov = np.tile([[4e-6, 1e-6], [1e-6, 1e-6]], (20000, 1, 1))
    noisy = sample_bearing(rng, b, cov)
    u = gtsam.Unit3(b[0])
    d = np.array([u.localCoordinates(gtsam.Unit3(x)) for x in noisy])
    assert np.allclose(np.cov(d.T), cov[0], rtol=0.05, atol=5e-8)


def _spherical_problem(rng: np.random.Generator, n_points: int = 30):
    """Points around the sensor (LiDAR frame) seen as full-sphere bearings by the camera."""
    T_cl = random_pose(rng, trans_sigma=0.3)
    p_lidar = rng.normal(0, 3.0, (n_points, 3))
    p_cam = np.array([T_cl.transformFrom(p) for p in p_lidar])
    b = sample_bearing(
        rng, p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True), np.tile(np.eye(2) * 1e-6, (n_points, 1, 1))
    )
    p_noisy = p_lidar + rng.normal(0, 0.01, p_lidar.shape)
    return T_cl, p_noisy, b


def test_point_factor_agrees_with_gtsam_spherical_camera() -> None:
    """Same problem, our factor on T_cam_lidar vs GeneralSFMFactorSphericalCamera on T_lidar_cam."""
    rng = np.random.default_rng(6)
    T_cl, p_lidar, b = _spherical_problem(rng)
    start = T_cl * gtsam.Pose3.Expmap(np.r_[0.05, -0.04, 0.03, 0.1, -0.1, 0.05])
    bearing_noise = gtsam.noiseModel.Isotropic.Sigma(2, 1e-3)
    point_noise = gtsam.noiseModel.Isotropic.Sigma(3, 0.01)
    ours, theirs = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    v_ours, v_theirs = gtsam.Values(), gtsam.Values()
    v_ours.insert(X(0), start)
    v_theirs.insert(X(0), gtsam.SphericalCamera(start.inverse()))
    for k, (p, bk) in enumerate(zip(p_lidar, b, strict=True)):
        ours.add(bearing_point_factor(X(0), L(k), bk, bearing_noise))
        theirs.add(gtsam.GeneralSFMFactorSphericalCamera(gtsam.Unit3(bk), bearing_noise, X(0), L(k)))
        for g, v in ((ours, v_ours), (theirs, v_theirs)):
            g.add(gtsam.PriorFactorPoint3(L(k), p, point_noise))
            v.insert(L(k), p)
    # GTSAM's factor measures the arc (Unit3.localCoordinates), ours its sine (Unit3.errorVector):
    # same direction in the same basis, lengths theta vs sin(theta)
    for k in range(len(b)):
        e_ours = ours.at(2 * k).unwhitenedError(v_ours)
        e_theirs = theirs.at(2 * k).unwhitenedError(v_theirs)
        s = np.linalg.norm(e_ours)
        assert np.allclose(e_theirs, e_ours * np.arcsin(s) / s, rtol=1e-9, atol=1e-14)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-15)
    r_ours = gtsam.LevenbergMarquardtOptimizer(ours, v_ours, params).optimize()
    r_theirs = gtsam.LevenbergMarquardtOptimizer(theirs, v_theirs, params).optimize()
    T_ours = r_ours.atPose3(X(0))
    T_theirs = r_theirs.atSphericalCamera(X(0)).pose().inverse()
    cov_ours = gtsam.Marginals(ours, r_ours).marginalCovariance(X(0))
    # the costs differ by O(theta^4) terms (residuals of a few mrad): optima within 1e-3 sigma
    assert np.all(np.abs(T_ours.localCoordinates(T_theirs)) < 1e-3 * np.sqrt(np.diag(cov_ours)))
    assert np.isclose(ours.error(r_ours), theirs.error(r_theirs), rtol=1e-4)
    # same uncertainty: their camera covariance is the adjoint-mapped inverse pose's
    cov_theirs = gtsam.Marginals(theirs, r_theirs).marginalCovariance(X(0))
    Ad = T_ours.AdjointMap()  # xi of T_lidar_cam = -Ad(T_cam_lidar) xi of T_cam_lidar
    assert np.allclose(Ad @ cov_ours @ Ad.T, cov_theirs, rtol=1e-3, atol=1e-3 * np.abs(cov_theirs).max())


def test_board_factor_agrees_with_spherical_camera_on_fixed_corners() -> None:
    """Grouped board factor with the board held by a tight prior vs SphericalCamera on fixed landmarks."""
    rng = np.random.default_rng(8)
    T_cl, T_lb, p_board, b = _scene(rng, 12, noise_rad=1e-3)
    cov = np.tile(np.eye(2) * 1e-6, (12, 1, 1))
    start = T_cl * gtsam.Pose3.Expmap(np.r_[0.02, -0.01, 0.03, 0.05, -0.02, 0.01])
    ours, theirs = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    v_ours, v_theirs = gtsam.Values(), gtsam.Values()
    ours.add(FrameBearingFactor(X(0), B(0), p_board, b, cov).factor())
    ours.add(gtsam.NonlinearEqualityPose3(B(0), T_lb))
    v_ours.insert(X(0), start)
    v_ours.insert(B(0), T_lb)
    v_theirs.insert(X(0), gtsam.SphericalCamera(start.inverse()))
    for k in range(12):
        p = T_lb.transformFrom(p_board[k])
        theirs.add(
            gtsam.GeneralSFMFactorSphericalCamera(
                gtsam.Unit3(b[k]), gtsam.noiseModel.Isotropic.Sigma(2, 1e-3), X(0), L(k)
            )
        )
        theirs.add(gtsam.NonlinearEqualityPoint3(L(k), p))
        v_theirs.insert(L(k), p)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-15)
    r_ours = gtsam.LevenbergMarquardtOptimizer(ours, v_ours, params).optimize()
    r_theirs = gtsam.LevenbergMarquardtOptimizer(theirs, v_theirs, params).optimize()
    T_theirs = r_theirs.atSphericalCamera(X(0)).pose().inverse()
    cov_ours = gtsam.Marginals(ours, r_ours).marginalCovariance(X(0))
    assert np.all(np.abs(r_ours.atPose3(X(0)).localCoordinates(T_theirs)) < 1e-3 * np.sqrt(np.diag(cov_ours)))
    assert np.isclose(ours.error(r_ours), theirs.error(r_theirs), rtol=1e-4)


def test_tiny_covariances_keep_their_correlations() -> None:
    """Bearing covariances are ~1e-7 rad^2: GTSAM's smart Gaussian model would drop their
    off-diagonals (absolute tolerance 1e-9); the grouped factor and smart=False keep them."""
    rng = np.random.default_rng(9)
    T_cl, T_lb, p_board, b = _scene(rng, 4)
    cov = np.tile(np.array([[1.0e-7, 8e-10], [8e-10, 4.0e-8]]), (4, 1, 1))
    values = gtsam.Values()
    values.insert(X(0), T_cl)
    values.insert(B(0), T_lb)
    group = FrameBearingFactor(X(0), B(0), p_board, b, cov).factor()

    def chi2(smart: bool) -> float:
        noise = gtsam.noiseModel.Gaussian.Covariance(cov[0], smart)
        return sum(2 * bearing_factor(X(0), B(0), p_board[k], b[k], noise).error(values) for k in range(4))

    e = np.array([board_bearing_error(T_cl, T_lb, p_board[k], gtsam.Unit3(b[k])) for k in range(4)])
    exact = float(np.einsum("ki,kij,kj->", e, np.linalg.inv(cov), e))
    assert np.isclose(2 * group.error(values), exact, rtol=1e-10)
    assert np.isclose(chi2(False), exact, rtol=1e-10)
    assert not np.isclose(chi2(True), exact, rtol=1e-3)  # the trap this guards against
