"""Double sphere camera (Usenko et al. 2018): the paper's formulas, special cases, round trips,
Jacobians, the valid region, config, Kalibr export, and the image stage and a calibration on
simulated images."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from camera_checks import (
    assert_image_stage_finds_boards,
    assert_jacobian,
    assert_pixel_round_trip,
    assert_simulated_set_calibrates,
    directions,
    unit,
)
from hypothesis import given, settings
from hypothesis import strategies as st

from ilcc_graph.cameras import DoubleSphere, Pinhole, Unified, make_camera
from ilcc_graph.config import parse_config
from ilcc_graph.errors import InputError
from ilcc_graph.exports import export_calibration

K = [[300.0, 0.0, 320.5], [0.0, 302.0, 241.0], [0.0, 0.0, 1.0]]
TUM = DoubleSphere(640, 480, K, -0.2, 0.59)  # close to published fits of wide lenses


def paper_project(p, fx, fy, cx, cy, xi, alpha):
    """The paper's projection of one point, written out with ``math`` (no validity test)."""
    x, y, z = p
    d1 = math.sqrt(x * x + y * y + z * z)
    d2 = math.sqrt(x * x + y * y + (xi * d1 + z) ** 2)
    den = alpha * d2 + (1 - alpha) * (xi * d1 + z)
    return fx * x / den + cx, fy * y / den + cy


def paper_unproject(u, v, fx, fy, cx, cy, xi, alpha):
    """The paper's closed-form unprojection of one pixel, written out with ``math``."""
    mx, my = (u - cx) / fx, (v - cy) / fy
    r2 = mx * mx + my * my
    mz = (1 - alpha * alpha * r2) / (alpha * math.sqrt(1 - (2 * alpha - 1) * r2) + 1 - alpha)
    f = (mz * xi + math.sqrt(mz * mz + (1 - xi * xi) * r2)) / (mz * mz + r2)
    return f * mx, f * my, f * mz - xi


def test_a_value_worked_by_hand() -> None:
    # p = (1, 2, 3), xi = -0.2, alpha = 0.59: d1 = sqrt(14) = 3.7416574, xi d1 + z = 2.2516685,
    # d2 = sqrt(1 + 4 + 2.2516685^2) = 3.1733281, den = 0.59 d2 + 0.41 (2.2516685) = 2.7954477,
    # mx = 0.3577245, my = 0.7154489 -> u = 300 mx + 320.5 = 427.8173, v = 302 my + 241 = 457.0656
    uv = TUM.project(np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(uv, [427.8173, 457.0656], atol=1e-4)


def test_matches_the_papers_formulas() -> None:
    rng = np.random.default_rng(0)
    for cam in (TUM, DoubleSphere(800, 600, K, 0.7, 0.3), DoubleSphere(800, 600, K, -0.6, 0.85)):
        args = (300.0, 302.0, 320.5, 241.0, cam.xi, cam.alpha)
        p = unit(rng.normal(size=(200, 3)))
        p = p[np.arccos(p[:, 2]) < cam.theta_max - 1e-3] * rng.uniform(0.5, 20.0, (1, 1))
        ref = np.array([paper_project(q, *args) for q in p])
        np.testing.assert_allclose(cam.project(p), ref, rtol=0, atol=1e-9)
        uv = ref[:50]
        b = np.array([paper_unproject(u, v, *args) for u, v in uv])
        np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-12)  # on the unit sphere
        np.testing.assert_allclose(cam.bearing(uv), b, atol=1e-12)
        np.testing.assert_allclose(b, unit(p[:50]), atol=1e-9)


def test_special_cases() -> None:
    rng = np.random.default_rng(1)
    p = unit(rng.normal(size=(500, 3)))
    # alpha = 0 is the unified model with the same xi (same valid region too)
    for xi in (0.0, 0.4, 1.0):
        ds, ucm = DoubleSphere(640, 480, K, xi, 0.0), Unified(640, 480, K, xi)
        np.testing.assert_allclose(ds.project(p), ucm.project(p), rtol=0, atol=1e-9)
        ok = np.isfinite(ds.project(p)[:, 0])
        np.testing.assert_allclose(ds.d_uv_d_point(p[ok]), ucm.d_uv_d_point(p[ok]), rtol=1e-9, atol=1e-9)
        uv = ds.project(p[ok])
        np.testing.assert_allclose(ds.bearing(uv), ucm.bearing(uv), atol=1e-10)
    # alpha = 0, xi = 0 is a pinhole without distortion
    ds, pin = DoubleSphere(640, 480, K, 0.0, 0.0), Pinhole(640, 480, K)
    np.testing.assert_allclose(ds.project(p), pin.project(p), rtol=0, atol=1e-9)
    # alpha = 1/2, xi = 0: stereographic, r = 2 tan(theta / 2); alpha = 1, xi = 0: r = sin(theta)
    theta = np.deg2rad([0.0, 30.0, 60.0, 120.0, 150.0])
    d = directions(theta, np.zeros(5))
    uv = DoubleSphere(640, 480, K, 0.0, 0.5).project(d)
    np.testing.assert_allclose((uv[:, 0] - 320.5) / 300.0, 2 * np.tan(theta / 2), atol=1e-12)
    uv = DoubleSphere(640, 480, K, 0.0, 1.0).project(d[:3])
    np.testing.assert_allclose((uv[:, 0] - 320.5) / 300.0, np.sin(theta[:3]), atol=1e-12)
    assert np.all(np.isnan(DoubleSphere(640, 480, K, 0.0, 1.0).project(d[3:])))  # not in front


@st.composite
def ds_cameras(draw) -> DoubleSphere:
    f = draw(st.floats(150.0, 600.0))
    Kr = [[f, draw(st.floats(-1.0, 1.0)), 400.0], [0.0, f * draw(st.floats(0.97, 1.03)), 300.0], [0, 0, 1]]
    return DoubleSphere(800, 600, Kr, draw(st.floats(-0.95, 1.0)), draw(st.floats(0.0, 1.0)))


@settings(max_examples=60, deadline=None, database=None)
@given(ds_cameras(), st.integers(0, 2**31 - 1))
def test_round_trips_over_the_valid_field(cam: DoubleSphere, seed: int) -> None:
    rng = np.random.default_rng(seed)
    theta = cam.theta_max * np.r_[0.0, 1e-9, rng.uniform(0, 1, 300), 1 - 1e-6]
    b = directions(theta, rng.uniform(-np.pi, np.pi, theta.size))
    uv = cam.project(b * rng.uniform(0.1, 50.0, (theta.size, 1)))
    assert np.all(np.isfinite(uv)), "every direction inside the valid region is imaged"
    np.testing.assert_allclose(cam.bearing(uv), b, atol=1e-7)
    # pixels anywhere (also beyond the image of the valid field): those with a bearing return
    pix = np.c_[rng.uniform(-2000, 2800, 500), rng.uniform(-2000, 2600, 500)]
    ok = assert_pixel_round_trip(cam, pix, atol=1e-6)
    r2 = (
        (pix[:, 0] - cam.K[0, 2] - cam.K[0, 1] * (pix[:, 1] - cam.K[1, 2]) / cam.K[1, 1]) / cam.K[0, 0]
    ) ** 2
    r2 += ((pix[:, 1] - cam.K[1, 2]) / cam.K[1, 1]) ** 2
    if cam.alpha > 0.5:
        assert not np.any(ok[r2 > 1 / (2 * cam.alpha - 1) * (1 + 1e-9)])


@settings(max_examples=40, deadline=None, database=None)
@given(ds_cameras(), st.integers(0, 2**31 - 1))
def test_jacobian_matches_central_differences(cam: DoubleSphere, seed: int) -> None:
    rng = np.random.default_rng(seed)
    theta = cam.theta_max * np.r_[0.0, 1e-4, rng.uniform(0, 0.97, 40)]
    p = directions(theta, rng.uniform(-np.pi, np.pi, theta.size)) * rng.uniform(0.3, 30.0, (theta.size, 1))
    assert_jacobian(cam, p, rel=5e-6)


@pytest.mark.parametrize(
    ("xi", "alpha"), [(-0.6, 0.0), (-0.5, 0.3), (-0.2, 0.59), (0.3, 0.4), (0.8, 0.9), (0.9, 0.1)]
)
def test_valid_region_images_once_and_nothing_beyond(xi: float, alpha: float) -> None:
    cam = DoubleSphere(640, 480, K, xi, alpha)
    assert cam.theta_max < np.pi - 0.05  # something lies beyond
    theta = np.linspace(0.0, cam.theta_max, 20001)[:-1]
    u = cam.project(directions(theta, np.zeros_like(theta)))[:, 0]
    assert np.all(np.isfinite(u)) and np.all(np.diff(u) > 0)  # radius grows: one point, one pixel
    beyond = directions(np.linspace(cam.theta_max + 1e-6, np.pi, 50), np.full(50, 0.7))
    assert np.all(np.isnan(cam.project(beyond))) and np.all(np.isnan(cam.d_uv_d_point(beyond)))
    # where the image folds back or the last pinhole sees the point from behind, nothing is imaged
    t = np.linspace(cam.theta_max + 1e-4, min(np.pi, cam.theta_max + 0.05), 50)
    c, s = np.cos(t), np.sin(t)
    k = xi + c
    den = alpha * np.sqrt(s * s + k * k) + (1 - alpha) * k
    r = s / den
    assert np.any(den <= 0) or np.any(np.diff(r) <= 0)


def test_the_papers_bound_would_image_points_behind_the_last_pinhole() -> None:
    """xi = -0.5, alpha = 0: the paper's z > -w2 |p| reaches 63.4 deg, the denominator is negative
    beyond 60 deg; those points get NaN here."""
    cam = DoubleSphere(640, 480, K, -0.5, 0.0)
    w2 = -0.5 / math.sqrt(1.25)
    assert math.degrees(math.acos(-w2)) == pytest.approx(63.43, abs=0.01)
    assert math.degrees(cam.theta_max) == pytest.approx(60.0, abs=1e-9)
    b = directions(np.deg2rad([59.9, 61.0, 63.0]), np.zeros(3))
    assert b[1, 2] > -w2 and -0.5 + b[1, 2] < 0  # inside the paper's bound, denominator negative
    ok = np.isfinite(cam.project(b)[:, 0])
    np.testing.assert_array_equal(ok, [True, False, False])


def test_pixels_outside_the_unprojection_domain() -> None:
    cam = DoubleSphere(640, 480, K, 0.0, 0.75)  # r^2 <= 1 / (2 alpha - 1) = 2
    mx = np.array([1.0, 1.41, 1.42, 3.0])
    b = cam.bearing(np.c_[320.5 + 300.0 * mx, np.full(4, 241.0)])
    np.testing.assert_array_equal(np.isfinite(b[:, 0]), [True, True, False, False])


def test_config_round_trip_and_errors() -> None:
    section = {
        "model": "double_sphere",
        "width": 640,
        "height": 480,
        "K": sum(K, []),
        "xi": -0.2,
        "alpha": 0.59,
    }
    cfg = parse_config(
        {
            "board": {"squares": [6, 8], "square_size": 0.075},
            "lidar": {"model": "hdl32"},
            "camera": yaml.safe_load(yaml.safe_dump(section)),
        },
        "DATA/config.yaml",
    )
    assert cfg.camera == TUM and cfg.camera.kind == "double_sphere"
    assert make_camera(yaml.safe_load(yaml.safe_dump(TUM.to_dict()))) == TUM
    assert TUM.to_dict() == {
        "model": "double_sphere",
        "width": 640,
        "height": 480,
        "K": K,
        "xi": -0.2,
        "alpha": 0.59,
    }
    for change, words in [
        ({"xi": -1.0}, ["DATA/config.yaml", "camera.xi = -1.0", "(-1.0, 1.0]"]),
        ({"alpha": 1.5}, ["camera.alpha = 1.5", "[0.0, 1.0]"]),
        ({"alpha": None}, ["camera.alpha = None", "a number"]),
        ({"dist": [0, 0, 0, 0]}, ["camera.dist", "no such key", "alpha"]),
    ]:
        bad = {**section, **change}
        with pytest.raises(InputError) as err:
            parse_config({"board": {"squares": [6, 8], "square_size": 0.075}, "lidar": {"model": "hdl32"},
                          "camera": bad}, "DATA/config.yaml")  # fmt: skip
        assert all(w in str(err.value) for w in words), str(err.value)
    missing = {k: v for k, v in section.items() if k != "alpha"}
    with pytest.raises(ValueError, match="camera.alpha = missing"):
        make_camera(missing)


def test_kalibr_export_is_ds() -> None:
    T = np.eye(4)
    cam0 = yaml.safe_load(export_calibration((T, np.eye(6) * 1e-6), "kalibr", camera=TUM))["cam0"]
    assert cam0["camera_model"] == "ds"
    assert cam0["intrinsics"] == [-0.2, 0.59, 300.0, 302.0, 320.5, 241.0]  # xi, alpha, fx, fy, cx, cy
    assert cam0["distortion_model"] == "none" and cam0["distortion_coeffs"] == []
    assert cam0["resolution"] == [640, 480]
    ros = export_calibration((T, np.eye(6) * 1e-6), "ros-tf", camera=TUM.to_dict())
    assert "camera_optical" in ros


def test_image_stage_finds_the_board_in_simulated_images() -> None:
    assert_image_stage_finds_boards("double_sphere", width=800, seed=4)


def test_simulated_data_set_calibrates(tmp_path) -> None:
    assert_simulated_set_calibrates("double_sphere", tmp_path / "sim")
