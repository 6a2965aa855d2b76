"""Camera intrinsics as a vector: names, round trips, the analytic Jacobian w.r.t. them, and the
stated uncertainty ``intrinsics_sigma`` (constructor, config.yaml, back)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from camera_checks import assert_intrinsics_jacobian, directions
from hypothesis import given, settings
from hypothesis import strategies as st

from ilcc_graph.cameras import (
    CameraModel,
    DoubleSphere,
    Equirectangular,
    Fisheye,
    Pinhole,
    Unified,
    camera_from_config,
    camera_kinds,
    make_camera,
)
from ilcc_graph.errors import InputError
from ilcc_graph.simulate import default_camera

NAMES = {
    "pinhole": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"),
    "fisheye": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
    "double_sphere": ("fx", "fy", "cx", "cy", "xi", "alpha"),
    "unified": ("fx", "fy", "cx", "cy", "xi", "k1", "k2", "p1", "p2"),
    "equirectangular": (),
}


# ------------------------------------------------------------------------- strategies
def _K(draw, w: int, h: int, f_lo: float, f_hi: float) -> np.ndarray:
    fx = draw(st.floats(f_lo, f_hi))
    fy = fx * draw(st.floats(0.97, 1.03))
    cx = (w - 1) / 2 + draw(st.floats(-0.05, 0.05)) * w
    cy = (h - 1) / 2 + draw(st.floats(-0.05, 0.05)) * h
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


@st.composite
def pinholes(draw) -> Pinhole:
    n = draw(st.sampled_from((0, 4, 5, 8)))
    lims = (0.3, 0.1, 2e-3, 2e-3, 0.03, 0.3, 0.05, 0.01)
    dist = [draw(st.floats(-lim, lim)) for lim in lims[:n]]
    return Pinhole(1280, 800, _K(draw, 1280, 800, 400.0, 1600.0), dist)


@st.composite
def fisheyes(draw) -> Fisheye:
    dist = [draw(st.floats(-lim, lim)) for lim in (0.05, 0.01, 0.005, 0.001)]
    return Fisheye(1280, 1024, _K(draw, 1280, 1024, 250.0, 500.0), dist)


@st.composite
def double_spheres(draw) -> DoubleSphere:
    return DoubleSphere(
        1280, 1024, _K(draw, 1280, 1024, 250.0, 500.0), draw(st.floats(-0.6, 0.6)), draw(st.floats(0.2, 0.8))
    )


@st.composite
def unifieds(draw) -> Unified:
    dist = [draw(st.floats(-lim, lim)) for lim in (0.2, 0.05, 1e-3, 1e-3)]
    return Unified(1280, 1024, _K(draw, 1280, 1024, 400.0, 900.0), draw(st.floats(0.01, 1.5)), dist)


def imaged_points(cam: CameraModel, seed: int, n: int = 60, max_deg: float = 80.0) -> np.ndarray:
    """Points (n', 3) at random depths on rays up to ``max_deg`` off +z that ``cam`` images within
    the picture, kept clear of the edge of its valid region (their images stay finite under small
    intrinsics changes)."""
    rng = np.random.default_rng(seed)
    theta = np.radians(max_deg) * np.sqrt(rng.uniform(0.0, 1.0, 4 * n))
    p = directions(theta, rng.uniform(-np.pi, np.pi, 4 * n)) * rng.uniform(0.3, 30.0, (4 * n, 1))
    ok = cam.fov_contains(p)
    th = cam.intrinsics()
    for s in (1e-3, -1e-3):
        ok &= np.isfinite(cam.with_intrinsics(th * (1 + s)).project(p)[:, 0])
    return p[ok][:n]


# ------------------------------------------------------------------ names, round trip
@pytest.mark.parametrize("kind", camera_kinds())
def test_names_length_and_round_trip(kind: str) -> None:
    cam = default_camera(kind, 640)
    assert cam.intrinsic_names == NAMES[kind]
    th = cam.intrinsics()
    assert th.dtype == np.float64 and th.shape == (len(NAMES[kind]),)
    again = cam.with_intrinsics(th)
    assert again == cam and type(again) is type(cam) and (again.width, again.height) == (640, cam.height)
    th[:] = 0.0  # a copy: the camera is untouched
    assert cam.with_intrinsics(cam.intrinsics()) == cam
    with pytest.raises(ValueError, match="intrinsics must be"):
        cam.with_intrinsics(np.zeros(len(NAMES[kind]) + 1))
    uv, J_p, J_t = cam.project_with_intrinsics_jacobian(np.array([[[0.3, 0.2, 1.0]]]))  # leading shape kept
    assert uv.shape == (1, 1, 2) and J_p.shape == (1, 1, 2, 3) and J_t.shape == (1, 1, 2, len(NAMES[kind]))


def test_pinhole_names_follow_the_length_of_dist() -> None:
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    for n in (0, 4, 5, 8):
        cam = Pinhole(640, 480, K, np.linspace(0.01, 0.02, n))
        assert (
            cam.intrinsic_names
            == ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")[: 4 + n]
        )
        np.testing.assert_array_equal(cam.intrinsics(), [500.0, 500.0, 320.0, 240.0, *cam.dist])


def test_with_intrinsics_sets_k_and_keeps_skew_and_sigma() -> None:
    K = np.array([[500.0, 1.5, 320], [0, 505.0, 240], [0, 0, 1]])
    cam = Fisheye(640, 480, K, [0.01, 0.0, 0.0, 0.0], intrinsics_sigma=np.full(8, 0.5))
    other = cam.with_intrinsics([510.0, 511.0, 321.0, 239.0, 0.02, 0.001, 0.0, 0.0])
    np.testing.assert_array_equal(other.K, [[510.0, 1.5, 321.0], [0, 511.0, 239.0], [0, 0, 1]])
    np.testing.assert_array_equal(other.dist, [0.02, 0.001, 0.0, 0.0])
    np.testing.assert_array_equal(other.intrinsics_sigma, cam.intrinsics_sigma)
    np.testing.assert_array_equal(cam.K, K)  # the original is unchanged


@pytest.mark.parametrize(
    ("cam", "theta", "match"),
    [
        (default_camera("pinhole", 640), [-1.0, 320, 160, 100, 0, 0, 0, 0, 0], "fx, fy > 0"),
        (default_camera("fisheye", 640), [200, 200, 320, np.nan, 0, 0, 0, 0], "finite"),
        (default_camera("double_sphere", 640), [200, 200, 320, 256, 0.1, 1.2], "alpha must be in"),
        (default_camera("double_sphere", 640), [200, 200, 320, 256, -1.0, 0.5], "xi must be in"),
        (
            default_camera("unified", 640),
            [360, 360, 320, 256, -0.1, 0, 0, 0, 0],
            "xi must be finite and >= 0",
        ),
    ],
)
def test_with_intrinsics_validates_as_the_constructor(cam: CameraModel, theta: list, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        cam.with_intrinsics(theta)


def test_jacobian_is_nan_where_the_point_is_not_imaged() -> None:
    cam = default_camera("pinhole", 640)
    p = np.array([[0.1, 0.0, 1.0], [0.1, 0.0, -1.0]])  # in front, behind
    uv, J_p, J_t = cam.project_with_intrinsics_jacobian(p)
    assert np.all(np.isfinite(J_t[0])) and np.all(np.isnan(J_t[1])) and np.all(np.isnan(uv[1]))
    np.testing.assert_array_equal(np.isnan(J_p), np.isnan(cam.d_uv_d_point(p)))


# --------------------------------------------------------- the Jacobian w.r.t. theta
@pytest.mark.parametrize(
    ("strategy", "max_deg"),
    [(pinholes(), 50.0), (fisheyes(), 95.0), (double_spheres(), 95.0), (unifieds(), 85.0)],
    ids=["pinhole", "fisheye", "double_sphere", "unified"],
)
@settings(max_examples=30, deadline=None, database=None)
@given(data=st.data())
def test_intrinsics_jacobian_matches_central_differences(strategy, max_deg: float, data) -> None:
    cam = data.draw(strategy)
    p = imaged_points(cam, data.draw(st.integers(0, 2**31 - 1)), max_deg=max_deg)
    assert len(p) >= 10, "the camera images too few of the sampled rays"
    assert_intrinsics_jacobian(cam, p)


@pytest.mark.parametrize("n_dist", [0, 4, 5, 8])
def test_pinhole_intrinsics_jacobian_is_opencvs(n_dist: int) -> None:
    """``cv2.projectPoints`` returns d uv / d (fx, fy, cx, cy, dist...) after the pose columns."""
    import cv2

    rng = np.random.default_rng(n_dist)
    K = np.array([[1400.0, 0.0, 955.3], [0.0, 1404.0, 610.1], [0.0, 0.0, 1.0]])
    dist = {
        0: [],
        4: [-0.12, 0.03, -0.001, 0.0008],
        5: [-0.28, 0.075, 0.0006, -0.0004, -0.009],
        8: [0.6, -0.05, 0.0007, 0.0005, 0.002, 0.95, 0.03, 0.004],
    }[n_dist]
    cam = Pinhole(1920, 1208, K, dist)
    p = np.c_[rng.uniform(-0.5, 0.5, (30, 2)), np.ones(30)] * rng.uniform(0.5, 8.0, (30, 1))
    _, J_cv = cv2.projectPoints(p[:, None], np.zeros(3), np.zeros(3), K, np.array(cam.dist, dtype=np.float64))
    J_t = cam.project_with_intrinsics_jacobian(p)[2]
    J_cv = J_cv.reshape(30, 2, -1)[:, :, 6 : 6 + J_t.shape[2]]
    np.testing.assert_allclose(J_t, J_cv, rtol=1e-10, atol=1e-9 * np.abs(J_t).max())


def test_fisheye_intrinsics_jacobian_is_opencvs() -> None:
    """``cv2.fisheye.projectPoints`` returns d uv / d (fx, fy, cx, cy, k1..k4) first."""
    import cv2

    rng = np.random.default_rng(7)
    K = np.array([[1176.93, 0.0, 962.275], [0.0, 1177.72, 612.725], [0.0, 0.0, 1.0]])
    cam = Fisheye(1920, 1208, K, [-0.0540096, -0.0784275, 0.0959641, -0.0515253])
    p = np.c_[rng.uniform(-1.0, 1.0, (30, 2)), np.ones(30)] * rng.uniform(0.5, 8.0, (30, 1))
    _, J_cv = cv2.fisheye.projectPoints(p[:, None], np.zeros(3), np.zeros(3), K, cam.dist)
    J_t = cam.project_with_intrinsics_jacobian(p)[2]
    np.testing.assert_allclose(
        J_t, J_cv.reshape(30, 2, -1)[:, :, :8], rtol=1e-10, atol=1e-9 * np.abs(J_t).max()
    )


def test_equirectangular_has_nothing_to_refine() -> None:
    cam = Equirectangular(800, 400)
    p = np.random.default_rng(0).normal(size=(20, 3))
    uv, J_p, J_t = cam.project_with_intrinsics_jacobian(p)
    assert J_t.shape == (20, 2, 0)
    np.testing.assert_array_equal(uv, cam.project(p))
    np.testing.assert_array_equal(J_p, cam.d_uv_d_point(p))
    assert cam.with_intrinsics([]) == cam
    with pytest.raises(ValueError, match="no intrinsics to refine"):
        Equirectangular(800, 400, intrinsics_sigma=[1.0])


# ------------------------------------------------------------------ intrinsics_sigma
@pytest.mark.parametrize("kind", [k for k in camera_kinds() if NAMES[k]])
def test_intrinsics_sigma_through_config_and_back(kind: str) -> None:
    cam = default_camera(kind, 640)
    sigma = {n: 0.5 + i for i, n in enumerate(cam.intrinsic_names)}
    d = {**cam.to_dict(), "intrinsics_sigma": sigma}
    got = camera_from_config(d, "DATA/config.yaml")
    np.testing.assert_array_equal(got.intrinsics_sigma, list(sigma.values()))
    assert not got.intrinsics_sigma.flags.writeable
    out = yaml.safe_load(yaml.safe_dump(got.to_dict(), sort_keys=False))
    assert list(out)[-1] == "intrinsics_sigma" and out["intrinsics_sigma"] == sigma
    assert set(out) <= set(got.config_keys)
    assert make_camera(out) == got and got != cam
    assert "intrinsics_sigma" not in cam.to_dict()
    # a mapping in the constructor too, in any key order
    again = type(cam)(**{**_init_kwargs(cam), "intrinsics_sigma": dict(reversed(sigma.items()))})
    assert again == got


def _init_kwargs(cam: CameraModel) -> dict:
    from dataclasses import fields

    return {f.name: getattr(cam, f.name) for f in fields(cam) if f.init}


@pytest.mark.parametrize(
    ("sigma", "message"),
    [
        (
            [2.0] * 8,
            r"camera\.intrinsics_sigma = \[2\.0.*expected a mapping \{name: sigma >= 0\} with exactly",
        ),
        ({"fx": 2.0}, r"camera\.intrinsics_sigma\.fy = missing: expected a number >= 0"),
        (
            {"f": 2.0},
            r"camera\.intrinsics_sigma\.f = 2\.0: expected no such intrinsic; this camera's are \['fx'",
        ),
        (
            {"fx": 2, "fy": 2, "cx": 3, "cy": 3, "k1": -0.01, "k2": 0.01, "k3": 0.01, "k4": 0.01},
            r"camera\.intrinsics_sigma\.k1 = -0\.01: expected a number in \[0\.0, inf\]",
        ),
        (
            {"fx": 2, "fy": "2", "cx": 3, "cy": 3, "k1": 0.01, "k2": 0.01, "k3": 0.01, "k4": 0.01},
            r"camera\.intrinsics_sigma\.fy = '2': expected a number",
        ),
    ],
)
def test_intrinsics_sigma_errors_name_file_key_and_value(sigma, message: str) -> None:
    d = {**default_camera("fisheye", 640).to_dict(), "intrinsics_sigma": sigma}
    with pytest.raises(InputError, match=r"^DATA/config\.yaml: " + message):
        camera_from_config(d, "DATA/config.yaml")


def test_intrinsics_sigma_on_a_panorama_is_refused() -> None:
    d = {"model": "equirectangular", "width": 800, "height": 400, "intrinsics_sigma": {}}
    with pytest.raises(
        InputError, match=r"camera\.intrinsics_sigma = \{\}: expected no such key: this camera"
    ):
        camera_from_config(d, "DATA/config.yaml")


def test_intrinsics_sigma_in_the_constructor_is_checked() -> None:
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    with pytest.raises(ValueError, match=r"must be 8 finite numbers >= 0"):
        Fisheye(640, 480, K, intrinsics_sigma=[1.0] * 7)
    with pytest.raises(ValueError, match=r"must be 8 finite numbers >= 0"):
        Fisheye(640, 480, K, intrinsics_sigma=[1.0] * 7 + [-1.0])
    with pytest.raises(ValueError, match=r"must name exactly"):
        Fisheye(640, 480, K, intrinsics_sigma={"fx": 1.0})
    cam = Pinhole(640, 480, K, [], intrinsics_sigma=[1, 1, 2, 2])  # no distortion: four names
    assert cam.to_dict()["intrinsics_sigma"] == {"fx": 1.0, "fy": 1.0, "cx": 2.0, "cy": 2.0}
