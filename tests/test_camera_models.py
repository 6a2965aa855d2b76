"""Camera models: interface.md spot checks, round trips, Jacobians, agreement with OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ilcc_graph.cameras import CameraModel, Equirectangular, Fisheye, Pinhole, make_camera

ACFR_K = [[1176.93, 0.0, 962.275], [0.0, 1177.72, 612.725], [0.0, 0.0, 1.0]]
ACFR_DIST = [-0.0540096, -0.0784275, 0.0959641, -0.0515253]
PIN_K = [[1400.0, 0.0, 955.3], [0.0, 1404.0, 610.1], [0.0, 0.0, 1.0]]

PANO = Equirectangular(4000, 2000)
ACFR = Fisheye(1920, 1208, ACFR_K, ACFR_DIST)
FISH0 = Fisheye(1920, 1208, ACFR_K, [0, 0, 0, 0])
# a wide lens whose image reaches beyond 90 degrees off axis
WIDE = Fisheye(
    1600, 1600, [[380.0, 0.0, 801.0], [0.0, 381.0, 798.0], [0.0, 0.0, 1.0]], [0.02, -0.004, 0.0005, 0.0]
)
PIN0 = Pinhole(1920, 1208, PIN_K, [])
PIN5 = Pinhole(1920, 1208, PIN_K, [-0.28, 0.075, 0.0006, -0.0004, -0.009])
PIN4 = Pinhole(1920, 1208, PIN_K, [-0.12, 0.03, -0.001, 0.0008])
PIN8 = Pinhole(1920, 1208, PIN_K, [0.6, -0.05, 0.0007, 0.0005, 0.002, 0.95, 0.03, 0.004])
LENSES = [ACFR, FISH0, WIDE, PIN0, PIN4, PIN5, PIN8]
ALL = [PANO, *LENSES]


def ids(cams):
    return [f"{c.kind}-{i}" for i, c in enumerate(cams)]


def image_pixels(cam: CameraModel, rng: np.random.Generator, n: int) -> np.ndarray:
    """Random pixels over the whole image plus its four corners and edge midpoints."""
    W, H = cam.width, cam.height
    edges = np.array(
        [[-0.5, -0.5], [W - 0.5, -0.5], [-0.5, H - 0.5], [W - 0.5, H - 0.5], [W / 2, -0.5], [-0.5, H / 2]]
    )
    return np.vstack([edges, np.c_[rng.uniform(-0.5, W - 0.5, n), rng.uniform(-0.5, H - 0.5, n)]])


def numeric_jacobian(cam: CameraModel, p: np.ndarray, h: float = 1e-6) -> np.ndarray:
    J = np.empty((len(p), 2, 3))
    scale = np.linalg.norm(p, axis=1)
    for j in range(3):
        d = np.zeros(3)
        d[j] = 1.0
        step = (h * scale)[:, None] * d
        J[:, :, j] = (cam.project(p + step) - cam.project(p - step)) / (2 * h * scale)[:, None]
    return J


# ------------------------------------------------------------------ equirectangular
def test_equirectangular_spot_checks() -> None:
    W, H = PANO.width, PANO.height
    uv = PANO.project(
        np.array([[1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0], [-1.0, 0, 0], [0, 0, 1.0], [0, 0, -1.0]])
    )
    np.testing.assert_allclose(uv[0], [W / 2 - 0.5, H / 2 - 0.5])  # +x is the centre column
    np.testing.assert_allclose(uv[1], [W / 4 - 0.5, H / 2 - 0.5])  # +y (left) is left of centre
    np.testing.assert_allclose(uv[2], [3 * W / 4 - 0.5, H / 2 - 0.5])
    np.testing.assert_allclose(uv[3], [-0.5, H / 2 - 0.5])  # az = +pi is the left edge
    assert uv[4, 1] == pytest.approx(-0.5) and uv[5, 1] == pytest.approx(H - 0.5)
    # -x with y = -0.0 still lands on the left edge: az in (-pi, pi]
    assert PANO.project(np.array([[-1.0, -0.0, 0.0]]))[0, 0] == pytest.approx(-0.5)
    b = PANO.bearing(np.array([[-0.5, H / 2 - 0.5], [W / 2 - 0.5, -0.5], [W / 2 - 0.5, H / 2 - 0.5]]))
    np.testing.assert_allclose(b, [[-1, 0, 0], [0, 0, 1], [1, 0, 0]], atol=1e-15)
    np.testing.assert_allclose(
        PANO.wrap_u(np.array([-0.5, W - 0.5, W + 1.0, -3.0])), [-0.5, -0.5, 1.0, W - 3.0]
    )
    np.testing.assert_allclose(PANO.wrap_du(np.array([W - 1.0, -W + 2.0, 5.0])), [-1.0, 2.0, 5.0])


@settings(max_examples=40, deadline=None, database=None)
@given(st.integers(0, 2**31 - 1))
def test_equirectangular_round_trip_seam_and_poles(seed: int) -> None:
    rng = np.random.default_rng(seed)
    W, H = PANO.width, PANO.height
    u = np.r_[
        rng.uniform(-0.5, W - 0.5, 200),
        -0.5,
        -0.5 + 1e-9,
        W - 0.5 - 1e-7,
        rng.uniform(-0.5, 0.5, 20),
        rng.uniform(W - 1.5, W - 0.5, 20),
    ]
    v = np.r_[rng.uniform(-0.5, H - 0.5, 200), rng.uniform(-0.5, H - 0.5, 3 + 40)]
    v[rng.integers(0, len(v), 20)] = rng.choice([-0.5, -0.5 + 1e-6, H - 0.5, H - 0.5 - 1e-6], 20)
    uv = np.c_[u, v]
    b = PANO.bearing(uv)
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-14)
    back = PANO.project(b)
    assert np.all(PANO.in_image(back))
    np.testing.assert_allclose(PANO.wrap_du(back[:, 0] - uv[:, 0]), 0.0, atol=1e-7)
    np.testing.assert_allclose(back[:, 1], uv[:, 1], atol=1e-9)
    # and point -> pixel -> bearing recovers the direction, points of any scale
    p = rng.normal(size=(300, 3)) * rng.uniform(0.1, 50, (300, 1))
    bp = PANO.bearing(PANO.project(p))
    np.testing.assert_allclose(bp, p / np.linalg.norm(p, axis=1, keepdims=True), atol=1e-12)


# --------------------------------------------------------------- lens round trips
@pytest.mark.parametrize("cam", LENSES, ids=ids(LENSES))
def test_lens_round_trip_whole_image(cam: CameraModel) -> None:
    rng = np.random.default_rng(7)
    uv = image_pixels(cam, rng, 3000)
    b = cam.bearing(uv)
    assert not np.any(np.isnan(b)), "every pixel of a realistic lens has a bearing"
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-13)
    np.testing.assert_allclose(cam.project(b), uv, atol=1e-7)
    # points -> pixels -> bearings, scale free
    uvs = cam.project(b * rng.uniform(0.2, 80.0, (len(b), 1)))
    np.testing.assert_allclose(uvs, uv, atol=1e-7)


def test_wide_fisheye_beyond_ninety_degrees() -> None:
    theta = np.deg2rad(np.r_[85.0, 90.0, 95.0, 105.0, 115.0])
    phi = np.deg2rad(np.r_[10.0, 100.0, 200.0, 290.0, 45.0])
    b = np.c_[np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]
    assert WIDE.theta_max > theta.max()
    uv = WIDE.project(b)
    assert np.all(WIDE.in_image(uv))
    np.testing.assert_allclose(WIDE.bearing(uv), b, atol=1e-12)
    # the model's radius: theta_d(theta) * f from the principal point
    k1, k2, k3, k4 = WIDE.dist
    td = theta * (1 + k1 * theta**2 + k2 * theta**4 + k3 * theta**6 + k4 * theta**8)
    np.testing.assert_allclose(
        np.hypot((uv[:, 0] - 801.0) / 380.0, (uv[:, 1] - 798.0) / 381.0), td, rtol=1e-12
    )


def test_not_imaged_is_nan() -> None:
    behind = np.array([[0.1, 0.2, -1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    assert np.all(np.isnan(PIN5.project(behind)))
    assert np.all(np.isnan(PIN5.d_uv_d_point(behind)))
    # beyond the fold of the ACFR fisheye polynomial (about 68 degrees) nothing is imaged
    assert 1.15 < ACFR.theta_max < 1.25
    t = np.array([ACFR.theta_max - 0.01, ACFR.theta_max + 0.01, 2.0, np.pi])
    p = np.c_[np.sin(t), np.zeros(4), np.cos(t)]
    uv = ACFR.project(p)
    assert np.all(np.isfinite(uv[0])) and np.all(np.isnan(uv[1:]))
    # pixels beyond the largest distorted radius have no bearing
    assert np.all(np.isnan(ACFR.bearing(np.array([[962.275 + 1176.93 * 1.0, 612.725]]))))
    assert np.isfinite(PIN5.r_max) and np.isinf(PIN0.r_max)
    a = PIN5.r_max * 1.01
    assert np.all(np.isnan(PIN5.project(np.array([[a, 0.0, 1.0]]))))
    assert np.all(np.isnan(PANO.project(np.zeros((1, 3)))))


# ------------------------------------------------------------------- Jacobians
def points_in_view(cam: CameraModel, rng: np.random.Generator, n: int) -> np.ndarray:
    b = cam.bearing(image_pixels(cam, rng, n)[6:])  # skip exact edges (poles of the panorama)
    return b * rng.uniform(0.3, 30.0, (n, 1))


@pytest.mark.parametrize("cam", ALL, ids=ids(ALL))
def test_jacobian_matches_central_differences(cam: CameraModel) -> None:
    rng = np.random.default_rng(3)
    p = points_in_view(cam, rng, 400)
    if isinstance(cam, Equirectangular):
        # keep away from the seam, where u jumps by W, and from the poles
        uv = cam.project(p)
        keep = (uv[:, 0] > 2) & (uv[:, 0] < cam.width - 3) & (uv[:, 1] > 2) & (uv[:, 1] < cam.height - 3)
        p = p[keep]
    uv, J = cam.project_with_jacobian(p)
    np.testing.assert_allclose(uv, cam.project(p))
    np.testing.assert_allclose(J, cam.d_uv_d_point(p))
    Jn = numeric_jacobian(cam, p)
    scale = np.abs(J).max(axis=(1, 2), keepdims=True)
    assert np.all(np.abs(J - Jn) <= 2e-6 * scale)
    # scale invariance: the Jacobian annihilates the point itself
    assert np.all(
        np.abs(np.einsum("nij,nj->ni", J, p)) <= 1e-9 * scale[:, :, 0] * np.linalg.norm(p, axis=1)[:, None]
    )


@settings(max_examples=30, deadline=None, database=None)
@given(
    st.floats(-1.0, 1.0),
    st.floats(-1.0, 1.0),
    st.floats(0.0, 2.0),
    st.sampled_from(LENSES[:3]),
)
def test_fisheye_jacobian_near_axis_and_wide(a: float, b: float, t: float, cam: Fisheye) -> None:
    """Includes the optical axis itself (t = 0) where the formula has a removable singularity."""
    t = min(t, cam.theta_max - 1e-3)
    n = np.hypot(a, b)
    d = np.array([a, b]) / n if n > 0 else np.array([1.0, 0.0])
    p = np.array([[np.sin(t) * d[0], np.sin(t) * d[1], np.cos(t)]]) * 3.0
    J = cam.d_uv_d_point(p)
    Jn = numeric_jacobian(cam, p, h=1e-6)
    assert np.all(np.isfinite(J))
    assert np.abs(J - Jn).max() <= 2e-6 * np.abs(J).max()


# ------------------------------------------------------------ agreement with OpenCV
@pytest.mark.parametrize("cam", [PIN0, PIN4, PIN5, PIN8], ids=ids([PIN0, PIN4, PIN5, PIN8]))
def test_pinhole_matches_opencv(cam: Pinhole) -> None:
    rng = np.random.default_rng(11)
    p = points_in_view(cam, rng, 2000)
    p = np.vstack([p, rng.normal(size=(500, 3)) + [0, 0, 4.0]])  # some outside the image too
    uv = cam.project(p)
    ok = np.isfinite(uv[:, 0])
    assert ok.sum() > 2200
    ref, _ = cv2.projectPoints(p[ok].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.array(cam.K), cam.dist)
    np.testing.assert_allclose(uv[ok], ref.reshape(-1, 2), atol=1e-6)


@pytest.mark.parametrize("cam", [ACFR, FISH0], ids=ids([ACFR, FISH0]))
def test_fisheye_matches_opencv(cam: Fisheye) -> None:
    rng = np.random.default_rng(12)
    p = points_in_view(cam, rng, 2000)
    uv = cam.project(p)
    ref, _ = cv2.fisheye.projectPoints(
        p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.array(cam.K), cam.dist
    )
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-6)


def test_bearing_beats_or_matches_opencv_undistort() -> None:
    """Our Newton inverse round-trips to 1e-7 px and is at least as good as cv2.fisheye.undistortPoints."""
    rng = np.random.default_rng(5)
    uv = image_pixels(ACFR, rng, 500)
    ours = np.abs(ACFR.project(ACFR.bearing(uv)) - uv).max()
    und = cv2.fisheye.undistortPoints(uv.reshape(-1, 1, 2), np.array(ACFR.K), ACFR.dist).reshape(-1, 2)
    theirs = np.abs(ACFR.project(np.c_[und, np.ones(len(und))]) - uv).max()
    assert ours < 1e-7 and ours <= theirs


# -------------------------------------------------------------- bearing covariance
@pytest.mark.parametrize("cam", [PANO, ACFR, WIDE, PIN5], ids=ids([PANO, ACFR, WIDE, PIN5]))
def test_bearing_tangent_cov(cam: CameraModel) -> None:
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(9)
    uv = image_pixels(cam, rng, 5)[6:]
    b = cam.bearing(uv)
    basis = np.stack([gtsam.Unit3(bi).basis() for bi in b])
    A = rng.normal(size=(len(b), 2, 2))
    cov_px = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(2)
    cov_t = cam.bearing_tangent_cov(b, cov_px, basis)
    Jt = cam.d_uv_d_point(b) @ basis
    np.testing.assert_allclose(Jt @ cov_t @ np.swapaxes(Jt, 1, 2), cov_px, rtol=1e-9, atol=1e-12)
    # Monte Carlo: pixel noise -> bearing -> tangent coordinates
    i = 0
    L = np.linalg.cholesky(cov_px[i] * 1e-2)
    noise = rng.normal(size=(20000, 2)) @ L.T
    bb = cam.bearing(uv[i] + noise)
    xi = (bb - b[i]) @ basis[i]
    emp = np.cov(xi.T)
    np.testing.assert_allclose(emp, cov_t[i] * 1e-2, rtol=0.05, atol=0.05 * np.abs(cov_t[i]).max() * 1e-2)


# ------------------------------------------------------------------ config dicts
@pytest.mark.parametrize("cam", ALL, ids=ids(ALL))
def test_to_dict_round_trip(cam: CameraModel) -> None:
    d = cam.to_dict()
    assert d["model"] == cam.kind and d["width"] == cam.width and d["height"] == cam.height
    assert all(isinstance(v, (list, int, str)) for v in d.values())
    again = make_camera(d)
    assert type(again) is type(cam) and again == cam and again.to_dict() == d


def test_make_camera_errors() -> None:
    with pytest.raises(ValueError, match="model"):
        make_camera({"model": "orthographic", "width": 10, "height": 10})
    with pytest.raises(ValueError, match="dist"):
        make_camera({"model": "pinhole", "width": 10, "height": 10, "K": PIN_K, "dist": [0.1, 0.2, 0.3]})
    with pytest.raises(ValueError, match="dist"):
        make_camera(
            {"model": "fisheye", "width": 10, "height": 10, "K": PIN_K, "dist": [0.1, 0.2, 0.3, 0, 0]}
        )
    with pytest.raises(ValueError, match="K"):
        make_camera({"model": "fisheye", "width": 10, "height": 10, "K": [[1, 0], [0, 1]], "dist": []})
    with pytest.raises(ValueError, match="width"):
        make_camera({"model": "equirectangular", "width": 0, "height": 10})
    assert (
        make_camera({"model": "Pinhole", "width": 10, "height": 8, "K": PIN_K, "dist": []}).kind == "pinhole"
    )


def test_vectorised_shapes_and_in_image() -> None:
    p = np.ones((4, 5, 3)) * [0.1, 0.2, 1.0]
    assert PIN5.project(p).shape == (4, 5, 2)
    assert PIN5.d_uv_d_point(p).shape == (4, 5, 2, 3)
    assert PIN5.bearing(np.zeros((2, 3, 2))).shape == (2, 3, 3)
    assert PIN5.fov_contains(p).shape == (4, 5) and PIN5.fov_contains(p).all()
    inside = PANO.in_image(
        np.array([[-0.5, -0.5], [3999.5, 1999.5], [-0.6, 3.0], [3.0, 2000.0], [np.nan, 1.0]])
    )
    np.testing.assert_array_equal(inside, [True, True, False, False, False])
    with pytest.raises(ValueError, match="p_cam"):
        PIN5.project(np.ones((3, 2)))


# ------------------------------------------------------------ random intrinsics
@st.composite
def random_lenses(draw) -> CameraModel:
    W = draw(st.integers(320, 2400))
    H = draw(st.integers(240, W))
    f = draw(st.floats(0.25, 1.5)) * W
    K = [
        [f, 0.0, W / 2 + draw(st.floats(-20, 20))],
        [0.0, f * draw(st.floats(0.98, 1.02)), H / 2 + 3.0],
        [0, 0, 1],
    ]
    if draw(st.booleans()):
        dist = [draw(st.floats(-0.06, 0.06)), draw(st.floats(-0.03, 0.03)), draw(st.floats(-0.01, 0.01)), 0.0]
        return Fisheye(W, H, K, dist)
    n = draw(st.sampled_from([4, 5, 8]))
    dist = [draw(st.floats(-0.35, 0.2)), draw(st.floats(-0.1, 0.1)), draw(st.floats(-2e-3, 2e-3))]
    dist += [draw(st.floats(-2e-3, 2e-3))] + [draw(st.floats(-0.02, 0.02)) for _ in range(n - 4)]
    return Pinhole(W, H, K, dist)


@settings(max_examples=60, deadline=None, database=None)
@given(random_lenses(), st.integers(0, 2**31 - 1))
def test_random_lens_round_trip_or_unreachable(cam: CameraModel, seed: int) -> None:
    """Every pixel either maps to a bearing that projects back onto it, or lies beyond the lens' reach."""
    rng = np.random.default_rng(seed)
    uv = image_pixels(cam, rng, 300)
    b = cam.bearing(uv)
    ok = ~np.isnan(b[:, 0])
    np.testing.assert_allclose(cam.project(b[ok]), uv[ok], atol=1e-6)
    xd = (uv[:, 0] - cam.K[0, 2]) / cam.K[0, 0]
    yd = (uv[:, 1] - cam.K[1, 2]) / cam.K[1, 1]
    if isinstance(cam, Fisheye):
        td_max = cam._theta_d(np.array([cam.theta_max]))[0][0]
        assert np.all(ok == (np.hypot(xd, yd) < td_max))
    else:
        r = min(cam.r_max, 1e6)
        g_max = r * cam._radial(np.array([r * r]))[0][0]
        # tangential terms move the reachable boundary by about p * r^2
        margin = 3 * (abs(cam.dist[2]) + abs(cam.dist[3])) * r * r
        assert np.all(ok[np.hypot(xd, yd) < g_max - margin])
        assert not np.any(ok[np.hypot(xd, yd) > g_max + margin])


def test_fisheye_skew_is_opencv_alpha() -> None:
    """K[0, 1] = alpha * fx reproduces cv2.fisheye.projectPoints(..., alpha=alpha)."""
    alpha = 0.01
    K = np.array(ACFR_K)
    K[0, 1] = alpha * K[0, 0]
    cam = Fisheye(1920, 1208, K, ACFR_DIST)
    rng = np.random.default_rng(4)
    p = points_in_view(ACFR, rng, 500)
    ref, _ = cv2.fisheye.projectPoints(
        p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.array(ACFR_K), cam.dist, alpha=alpha
    )
    np.testing.assert_allclose(cam.project(p), ref.reshape(-1, 2), atol=1e-6)
    np.testing.assert_allclose(
        cam.bearing(cam.project(p)), p / np.linalg.norm(p, axis=1, keepdims=True), atol=1e-12
    )
    Jn = numeric_jacobian(cam, p)
    J = cam.d_uv_d_point(p)
    assert np.all(np.abs(J - Jn) <= 2e-6 * np.abs(J).max(axis=(1, 2), keepdims=True))
