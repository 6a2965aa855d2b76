"""FramePixelFactor: Jacobians against central differences, robust weighting as GTSAM's, the same
optimum and covariance as the bearing factor at fixed intrinsics, and intrinsics recovered with a
consistent extrinsic covariance when they are a variable with a prior."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, I, X
from scipy.stats import chi2

from factors import FrameBearingFactor, FramePixelFactor, tangent_bases
from factors.pixel import UNIMAGED_RESIDUAL
from factors.testing import factor_jacobian_error, factor_jacobians, numerical_factor_jacobians
from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel, Equirectangular
from ilcc_graph.simulate import default_camera, default_T_cam_lidar

BOARD = Board(6, 8, 0.075)  # 35 inner corners, 0.6 x 0.45 m
P_BOARD = BOARD.corners_board()
SIGMA_BOARD = np.full(6, 0.01)  # board prior: 0.01 rad, 10 mm (a LiDAR board fit's order)


def projection(cam: CameraModel):
    return lambda p, theta: cam.with_intrinsics(theta).project_with_intrinsics_jacobian(p)


def board_views(cam: CameraModel, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """``T_cam_board`` (4, 4) of ``n`` boards 0.8-2.2 m away, up to ~30 deg off the optical axis,
    facing the camera within 40 deg and turned at random in their plane, every corner in the image."""
    c0 = P_BOARD.mean(axis=0)
    out: list[np.ndarray] = []
    while len(out) < n:
        ang, az = rng.uniform(0.0, 0.5), rng.uniform(-np.pi, np.pi)
        ray = np.array([np.sin(ang) * np.cos(az), np.sin(ang) * np.sin(az), np.cos(ang)])
        z = -ray  # board z towards the camera
        x = np.cross([0.0, -1.0, 0.0], z)
        x /= np.linalg.norm(x)
        R = (
            np.c_[x, np.cross(z, x), z]
            @ gtsam.Rot3.Expmap(np.r_[rng.uniform(-0.7, 0.7, 2), rng.uniform(-np.pi, np.pi)]).matrix()
        )
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, rng.uniform(0.8, 2.2) * ray - R @ c0
        if np.all(cam.fov_contains(P_BOARD @ R.T + T[:3, 3])):
            out.append(T)
    return out


def random_cov_px(rng: np.random.Generator, k: int, sigma: float) -> np.ndarray:
    """(k, 2, 2) pixel covariances, correlated, sigma of order ``sigma`` px."""
    A = rng.normal(0.0, sigma, (k, 2, 2))
    return 0.5 * A @ np.swapaxes(A, 1, 2) + np.eye(2) * (0.2 * sigma) ** 2


def sample_px(rng: np.random.Generator, uv: np.ndarray, cov: np.ndarray) -> np.ndarray:
    return uv + np.einsum("kij,kj->ki", np.linalg.cholesky(cov), rng.standard_normal(uv.shape))


def _one_view(kind: str, seed: int, width: int = 1280):
    rng = np.random.default_rng(seed)
    cam = default_camera(kind, width)
    T_cl = gtsam.Pose3(default_T_cam_lidar(cam))
    T_cb = board_views(cam, rng, 1)[0]
    T_lb = T_cl.inverse().compose(gtsam.Pose3(T_cb))
    cov = random_cov_px(rng, len(P_BOARD), 0.3)
    uv = sample_px(rng, cam.project(P_BOARD @ T_cb[:3, :3].T + T_cb[:3, 3]), cov)
    return rng, cam, T_cl, T_lb, uv, cov


def _values(T_cl: gtsam.Pose3, T_lb: gtsam.Pose3, theta: np.ndarray | None) -> gtsam.Values:
    v = gtsam.Values()
    v.insert(X(0), T_cl)
    v.insert(B(0), T_lb)
    if theta is not None:
        v.insert(I(0), theta)
    return v


# ----------------------------------------------------------------------------- Jacobians
@pytest.mark.parametrize("kind", ["pinhole", "fisheye", "double_sphere", "unified"])
def test_jacobians_match_central_differences(kind: str) -> None:
    rng, cam, T_cl, T_lb, uv, cov = _one_view(kind, 1)
    # off the optimum, intrinsics a little off too: every block non-trivial
    T_cl, T_lb = T_cl.retract(rng.normal(0, 0.01, 6)), T_lb.retract(rng.normal(0, 0.01, 6))
    theta = cam.intrinsics() * (1 + rng.normal(0, 0.003, len(cam.intrinsic_names)))
    f = FramePixelFactor(X(0), B(0), I(0), P_BOARD, uv, cov, projection(cam))
    values = _values(T_cl, T_lb, theta)
    analytic = factor_jacobians(f.factor(), values)
    numeric = numerical_factor_jacobians(f.factor(), values)
    assert [a.shape for a in analytic] == [(70, 6), (70, 6), (70, len(theta))]
    for a, n in zip(analytic, numeric, strict=True):
        scale = np.abs(a).max(axis=0)  # per column: the intrinsics differ in scale by 1e5
        assert np.all(np.abs(a - n).max(axis=0) <= 1e-6 * scale + 1e-6), np.abs(a - n).max(axis=0) / scale
    # held fixed: the same two pose blocks
    fixed = FramePixelFactor(X(0), B(0), None, P_BOARD, uv, cov, projection(cam), intrinsics=theta)
    assert fixed.keys == (X(0), B(0))
    got = factor_jacobians(fixed.factor(), _values(T_cl, T_lb, None))
    np.testing.assert_allclose(got[0], analytic[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got[1], analytic[1], rtol=1e-12, atol=1e-12)
    assert factor_jacobian_error(fixed.factor(), _values(T_cl, T_lb, None)) < 1e-5 * np.abs(got[0]).max()


def test_a_theta_of_dimension_zero_works() -> None:
    """A panorama has no intrinsics: theta is an empty Vector, its Jacobian block has no column."""
    rng = np.random.default_rng(2)
    cam = Equirectangular(2000, 1000)
    T_cl = gtsam.Pose3(default_T_cam_lidar(cam))
    T_lb = gtsam.Pose3(gtsam.Rot3.Ypr(0.3, 0.1, -1.4), np.array([2.0, 0.4, -0.2]))
    T_cb = T_cl.compose(T_lb).matrix()
    cov = random_cov_px(rng, len(P_BOARD), 0.4)
    uv = sample_px(rng, cam.project(P_BOARD @ T_cb[:3, :3].T + T_cb[:3, 3]), cov)
    f = FramePixelFactor(X(0), B(0), I(0), P_BOARD, uv, cov, projection(cam))
    T_start = T_cl.retract(rng.normal(0, 0.01, 6))
    values = _values(T_start, T_lb, np.zeros(0))
    blocks = factor_jacobians(f.factor(), values)
    assert blocks[2].shape == (70, 0)
    # the pose blocks are those of the same factor without the empty key, checked numerically
    fixed = FramePixelFactor(X(0), B(0), None, P_BOARD, uv, cov, projection(cam), intrinsics=np.zeros(0))
    fixed_values = _values(T_start, T_lb, None)
    for a, b in zip(blocks[:2], factor_jacobians(fixed.factor(), fixed_values), strict=True):
        np.testing.assert_array_equal(a, b)
    assert factor_jacobian_error(fixed.factor(), fixed_values) < 1e-5 * np.abs(blocks[0]).max()
    graph = gtsam.NonlinearFactorGraph()
    graph.add(f.factor())
    graph.add(gtsam.PriorFactorPose3(B(0), T_lb, gtsam.noiseModel.Diagonal.Sigmas(SIGMA_BOARD)))
    res = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    assert 2 * graph.error(res) < chi2.ppf(0.999, 70 - 6)


# ------------------------------------------------------------------- values and helpers
def test_error_is_whitened_projection_minus_measurement() -> None:
    rng, cam, T_cl, T_lb, uv, cov = _one_view("fisheye", 3)
    theta = cam.intrinsics()
    f = FramePixelFactor(X(0), B(0), I(0), P_BOARD, uv, cov, projection(cam))
    assert f.dim == 70 and f.n_corners == 35 and f.keys == (X(0), B(0), I(0))
    p_cam = P_BOARD @ T_cl.compose(T_lb).matrix()[:3, :3].T + T_cl.compose(T_lb).translation()
    e = f.unwhitened(T_cl, T_lb, theta)[0]
    np.testing.assert_allclose(e, cam.project(p_cam) - uv, atol=1e-9)
    w = f.whitened(T_cl, T_lb, theta)
    chi = np.einsum("ki,kij,kj->k", e, np.linalg.inv(cov), e)
    np.testing.assert_allclose(np.sum(w * w, axis=1), chi, rtol=1e-9)
    np.testing.assert_allclose(2 * f.factor().error(_values(T_cl, T_lb, theta)), chi.sum(), rtol=1e-9)
    np.testing.assert_allclose(f.scaled(4.0).whitened(T_cl, T_lb, theta), w / 2, rtol=1e-12)
    assert f.with_robust(None).robust is None and f.sqrt_info is f.with_robust(None).sqrt_info
    with pytest.raises(ValueError, match="variance_scale must be > 0"):
        f.scaled(0.0)
    with pytest.raises(ValueError, match=r"need points_board \(K,3\), uv \(K,2\)"):
        FramePixelFactor(X(0), B(0), I(0), P_BOARD, uv[:3], cov, projection(cam))
    with pytest.raises(ValueError, match="need `intrinsics`"):
        FramePixelFactor(X(0), B(0), None, P_BOARD, uv, cov, projection(cam))
    with pytest.raises(ValueError, match="not positive definite"):
        FramePixelFactor(X(0), B(0), I(0), P_BOARD, uv, -cov, projection(cam))


def test_robust_matches_gtsam_robust_noise_model_per_corner() -> None:
    rng, cam, T_cl, T_lb, uv, _ = _one_view("pinhole", 4)
    theta = cam.intrinsics()
    uv[5] += [6.0, -4.0]  # one gross outlier
    sigma = 0.4
    cov = np.tile(np.eye(2) * sigma**2, (35, 1, 1))  # isotropic: both whitenings are the same matrix
    huber = gtsam.noiseModel.mEstimator.Huber.Create(1.345)
    group = FramePixelFactor(X(0), B(0), I(0), P_BOARD, uv, cov, projection(cam), robust=huber)
    plain = FramePixelFactor(X(0), B(0), I(0), P_BOARD, uv, cov, projection(cam))
    singles = []
    for k in range(35):
        one = FramePixelFactor(
            X(0), B(0), I(0), P_BOARD[k : k + 1], uv[k : k + 1], np.eye(2)[None], plain.project
        )

        def err(this, values, H, one=one):
            e, A, Bk, C = one.evaluate(
                values.atPose3(X(0)), values.atPose3(B(0)), values.atVector(I(0)), H is not None
            )
            if H is not None:
                H[0], H[1], H[2] = A, Bk, C
            return e

        noise = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Isotropic.Sigma(2, sigma))
        singles.append(gtsam.CustomFactor(noise, [X(0), B(0), I(0)], err))
    values = _values(T_cl, T_lb, theta)
    assert np.isclose(group.factor().error(values), sum(s.error(values) for s in singles), rtol=1e-10)
    A_g, b_g = group.factor().linearize(values).jacobian()
    lin = [s.linearize(values).jacobian() for s in singles]
    A_s, b_s = np.vstack([a for a, _ in lin]), np.concatenate([b for _, b in lin])
    np.testing.assert_allclose(A_g, A_s, rtol=1e-9, atol=1e-9 * np.abs(A_s).max())
    np.testing.assert_allclose(b_g, b_s, rtol=1e-9, atol=1e-12)
    w = group.whitened(T_cl, T_lb, theta)
    assert np.linalg.norm(w[5]) > 1.345  # the outlier is in Huber's linear part
    assert group.factor().error(values) < plain.factor().error(values)


def test_a_corner_that_cannot_be_imaged_gives_a_large_finite_residual() -> None:
    rng, cam, T_cl, T_lb, uv, cov = _one_view("pinhole", 5)
    theta = cam.intrinsics()
    f = FramePixelFactor(X(0), B(0), I(0), P_BOARD, uv, cov, projection(cam))
    # slide the (tilted) board along the optical axis until its centre is level with the camera:
    # part of it lies behind the camera
    T_cb = T_cl.compose(T_lb)
    depth = T_cb.transformFrom(P_BOARD.mean(axis=0))[2]
    T_cb = gtsam.Pose3(T_cb.rotation(), T_cb.translation() - np.array([0.0, 0.0, depth]))
    T_far = T_cl.inverse().compose(T_cb)
    e = f.unwhitened(T_cl, T_far, theta)[0]
    bad = np.isnan(e[:, 0])
    assert 0 < bad.sum() < 35
    r, A_cam, A_board, A_theta = f.evaluate(T_cl, T_far, theta, True)
    assert np.all(np.isfinite(r)) and np.all(r.reshape(-1, 2)[bad] == UNIMAGED_RESIDUAL)
    for A in (A_cam, A_board, A_theta):
        assert np.all(np.isfinite(A)) and np.all(A.reshape(35, 2, -1)[bad] == 0.0)
        assert np.any(A.reshape(35, 2, -1)[~bad] != 0.0)
    assert np.all(np.isfinite(f.evaluate(T_cl, T_far, theta, False)[0]))


# ---------------------------------------------------------------------- graphs
def _lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-14)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def _board_prior(rng: np.random.Generator, i: int, T_lb: gtsam.Pose3):
    measured = T_lb.retract(rng.normal(0.0, SIGMA_BOARD))
    noise = gtsam.noiseModel.Gaussian.Covariance(np.diag(SIGMA_BOARD**2), False)
    return measured, gtsam.PriorFactorPose3(B(i), measured, noise)


@pytest.mark.parametrize("kind", ["fisheye", "pinhole"])
def test_pixel_and_bearing_graphs_reach_the_same_optimum_and_covariance(kind: str) -> None:
    """At fixed intrinsics the two residuals are first-order equivalent (the bearing covariance is
    the pixel covariance mapped through the camera at the measured pixel)."""
    cam = default_camera(kind, 1280)
    T_cl = gtsam.Pose3(default_T_cam_lidar(cam))
    for seed in range(3):
        rng = np.random.default_rng(seed)
        g_px, g_b, values = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(X(0), T_cl.retract(rng.normal(0, 0.02, 6)))
        for i, T_cb in enumerate(board_views(cam, rng, 8)):
            measured, prior = _board_prior(rng, i, T_cl.inverse().compose(gtsam.Pose3(T_cb)))
            values.insert(B(i), measured)
            cov = random_cov_px(rng, 35, 0.3)
            uv = sample_px(rng, cam.project(P_BOARD @ T_cb[:3, :3].T + T_cb[:3, 3]), cov)
            b = cam.bearing(uv)
            g_px.add(prior)
            g_px.add(
                FramePixelFactor(
                    X(0), B(i), None, P_BOARD, uv, cov, projection(cam), intrinsics=cam.intrinsics()
                ).factor()
            )
            g_b.add(prior)
            g_b.add(
                FrameBearingFactor(
                    X(0), B(i), P_BOARD, b, cam.bearing_tangent_cov(b, cov, tangent_bases(b))
                ).factor()
            )
        r_px, r_b = _lm(g_px, values), _lm(g_b, values)
        C_px = gtsam.Marginals(g_px, r_px).marginalCovariance(X(0))
        C_b = gtsam.Marginals(g_b, r_b).marginalCovariance(X(0))
        d = r_px.atPose3(X(0)).localCoordinates(r_b.atPose3(X(0)))
        assert np.sqrt(d @ np.linalg.solve(C_px, d)) < 2e-3  # optima apart by < 0.002 sigma
        L = np.linalg.cholesky(np.linalg.inv(C_px))
        assert np.abs(np.linalg.eigvalsh(L.T @ C_b @ L) - 1).max() < 1e-4  # covariances within 1e-4
        assert abs(g_px.error(r_px) / g_b.error(r_b) - 1) < 3e-4  # chi-squares: second-order apart


def _recovery(kind: str, seed: int, sigma_dist: list[float], n_views: int = 10, px: float = 0.3):
    """One synthetic calibration with the intrinsics a variable: stated intrinsics drawn from their
    prior around the truth, board priors, noisy pixels. Returns the extrinsic's NEES, the intrinsics'
    NEES, their errors in posterior sigmas, the stated ones' in prior sigmas and sigma ratios."""
    rng = np.random.default_rng(seed)
    cam = default_camera(kind, 1280)
    T_cl = gtsam.Pose3(default_T_cam_lidar(cam))
    truth = cam.intrinsics()
    sigma = np.r_[0.005 * truth[0], 0.005 * truth[1], 3.0, 3.0, sigma_dist]
    stated = truth + rng.normal(0.0, sigma)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorVector(I(0), stated, gtsam.noiseModel.Diagonal.Sigmas(sigma)))
    values.insert(I(0), stated)
    values.insert(X(0), T_cl.retract(rng.normal(0, 0.02, 6)))
    project = projection(cam)
    for i, T_cb in enumerate(board_views(cam, rng, n_views)):
        measured, prior = _board_prior(rng, i, T_cl.inverse().compose(gtsam.Pose3(T_cb)))
        values.insert(B(i), measured)
        graph.add(prior)
        cov = random_cov_px(rng, 35, px)
        uv = sample_px(rng, cam.project(P_BOARD @ T_cb[:3, :3].T + T_cb[:3, 3]), cov)
        graph.add(FramePixelFactor(X(0), B(i), I(0), P_BOARD, uv, cov, project).factor())
    res = _lm(graph, values)
    marg = gtsam.Marginals(graph, res)
    C, C_t = marg.marginalCovariance(X(0)), marg.marginalCovariance(I(0))
    xi = res.atPose3(X(0)).localCoordinates(T_cl)  # T_true = T_est * Expmap(xi)
    d_t = truth - res.atVector(I(0))
    return (
        float(xi @ np.linalg.solve(C, xi)),
        float(d_t @ np.linalg.solve(C_t, d_t)),
        d_t / np.sqrt(np.diag(C_t)),
        (truth - stated) / sigma,
        np.sqrt(np.diag(C_t)) / sigma,
    )


@pytest.mark.parametrize(
    ("kind", "sigma_dist"),
    [("fisheye", [0.005, 0.002, 0.001, 0.0005]), ("pinhole", [0.01, 0.005, 5e-4, 5e-4, 0.002])],
)
def test_intrinsics_as_a_variable_are_recovered_and_the_extrinsic_stays_consistent(
    kind: str, sigma_dist: list[float]
) -> None:
    runs = [_recovery(kind, seed, sigma_dist) for seed in range(24)]
    nees = np.array([r[0] for r in runs])
    nees_t = np.array([r[1] for r in runs])
    z = np.array([r[2] for r in runs])
    z_stated = np.array([r[3] for r in runs])
    shrink = np.array([r[4] for r in runs])
    n, dof = len(runs), z.shape[1]
    # NEES summed over the seeds is chi-square with 6 n (extrinsic) and dof n (intrinsics) dof
    lo, hi = chi2.ppf([0.001, 0.999], 6 * n)
    assert lo < nees.sum() < hi, nees.mean()
    lo, hi = chi2.ppf([0.001, 0.999], dof * n)
    assert lo < nees_t.sum() < hi, nees_t.mean()
    # every recovered intrinsic within 4 of its posterior sigmas, and those sigmas honest (RMS ~1)
    assert np.abs(z).max() < 4.0
    assert np.all(np.abs(np.sqrt((z**2).mean(axis=0)) - 1) < 0.5), np.sqrt((z**2).mean(axis=0))
    # the views inform f and c: posterior sigma well below the prior's, errors smaller than stated
    assert np.all(shrink[:, :4] < 0.9)
    err_f = np.abs(z[:, 0] * shrink[:, 0])  # recovered fx error in prior sigmas
    assert err_f.mean() < 0.8 * np.abs(z_stated[:, 0]).mean()
