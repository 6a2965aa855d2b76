"""Unified omnidirectional camera with radial-tangential distortion (Mei and Rives 2007): the
formulas, special cases, round trips, Jacobians, the valid region, config, Kalibr export, and the
image stage and a calibration on simulated images."""

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

from ilcc_graph.cameras import Pinhole, Unified, make_camera
from ilcc_graph.config import parse_config
from ilcc_graph.errors import InputError
from ilcc_graph.exports import export_calibration

K = [[300.0, 0.0, 320.5], [0.0, 302.0, 241.0], [0.0, 0.0, 1.0]]
DIST = [-0.05, 0.01, 4e-4, -3e-4]
MEI = Unified(640, 480, K, 0.9, DIST)


def mei_project(p, fx, fy, cx, cy, xi, k1, k2, p1, p2):
    """Mei's projection of one point, written out with ``math``: sphere, shift by xi, radtan, K."""
    x, y, z = p
    d = math.sqrt(x * x + y * y + z * z)
    a, b = x / (z + xi * d), y / (z + xi * d)
    r2 = a * a + b * b
    rad = 1 + k1 * r2 + k2 * r2 * r2
    xd = a * rad + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
    yd = b * rad + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    return fx * xd + cx, fy * yd + cy


def test_a_value_worked_by_hand() -> None:
    # p = (1, 2, 3), xi = 0.9: |p| = 3.7416574, z + xi |p| = 6.3674916, (a, b) = (0.1570477, 0.3140954),
    # r^2 = 0.1233199, 1 + k1 r^2 + k2 r^4 = 0.9939861, (xd, yd) = (0.1560909, 0.3123051)
    # -> u = 300 xd + 320.5 = 367.3273, v = 302 yd + 241 = 335.3162
    np.testing.assert_allclose(MEI.project(np.array([1.0, 2.0, 3.0])), [367.3273, 335.3162], atol=1e-4)


def test_matches_meis_formulas() -> None:
    rng = np.random.default_rng(0)
    for cam in (MEI, Unified(800, 600, K, 1.7, [0.02, -0.001, -2e-4, 1e-4]), Unified(800, 600, K, 0.3)):
        args = (300.0, 302.0, 320.5, 241.0, cam.xi, *cam.dist)
        p = unit(rng.normal(size=(300, 3)))
        p = p[p[:, 2] > -cam.w + 0.05] * rng.uniform(0.5, 20.0, (1, 1))
        ref = np.array([mei_project(q, *args) for q in p])
        np.testing.assert_allclose(cam.project(p), ref, rtol=0, atol=1e-9)
        np.testing.assert_allclose(cam.bearing(ref), unit(p), atol=1e-9)


def test_special_cases() -> None:
    rng = np.random.default_rng(1)
    p = unit(rng.normal(size=(500, 3))) * 3.0
    # xi = 0 is OpenCV's pinhole with the same (k1, k2, p1, p2)
    ucm, pin = Unified(640, 480, K, 0.0, DIST), Pinhole(640, 480, K, DIST)
    np.testing.assert_allclose(ucm.project(p), pin.project(p), rtol=1e-12, atol=1e-9)
    ok = np.isfinite(pin.project(p)[:, 0])
    np.testing.assert_array_equal(np.isfinite(ucm.project(p)[:, 0]), ok)
    np.testing.assert_allclose(ucm.d_uv_d_point(p[ok]), pin.d_uv_d_point(p[ok]), rtol=1e-9, atol=1e-12)
    uv = pin.project(p[ok])
    np.testing.assert_allclose(ucm.bearing(uv), pin.bearing(uv), atol=1e-12)
    # xi = 1, no distortion: stereographic, r = f tan(theta / 2), all but the back pole
    theta = np.deg2rad([0.0, 45.0, 90.0, 135.0, 179.0])
    uv = Unified(640, 480, K, 1.0).project(directions(theta, np.zeros(5)))
    np.testing.assert_allclose((uv[:, 0] - 320.5) / 300.0, np.tan(theta / 2), rtol=1e-12)


@st.composite
def unified_cameras(draw) -> Unified:
    f = draw(st.floats(150.0, 600.0))
    Kr = [[f, draw(st.floats(-1.0, 1.0)), 400.0], [0.0, f * draw(st.floats(0.97, 1.03)), 300.0], [0, 0, 1]]
    dist = [draw(st.floats(-0.3, 0.1)), draw(st.floats(-0.05, 0.05)), draw(st.floats(-2e-3, 2e-3)),
            draw(st.floats(-2e-3, 2e-3))]  # fmt: skip
    return Unified(800, 600, Kr, draw(st.floats(0.0, 3.0)), dist)


def field_directions(cam: Unified, rng: np.random.Generator, n: int, margin: float = 1e-6) -> np.ndarray:
    """Unit directions inside the valid region (z > -w |p|, normalised radius below ``r_max``),
    below 0.9 ``r_max`` and a normalised radius of 4 (76 deg for a pinhole): near the radial fold
    and far beyond any image the tangential terms fold the radial-tangential map (``RadTan``), for
    the pinhole as for this model, and a pixel there has two rays."""
    t = np.linspace(0, math.acos(-cam.w), 200001)[1:-1]
    a = np.sin(t) / (np.cos(t) + cam.xi)  # the normalised radius before distortion, increasing
    k1, k2, p1, p2 = cam.dist
    # where the radial map is nearly flat (it need not stop increasing: r_max inf) the tangential
    # terms, whose derivative is at most about 6 max(|p1|, |p2|) a, fold it all the same: stop
    # before the radial derivative falls to twice that
    slope = 1 + 3 * k1 * a**2 + 5 * k2 * a**4
    flat = np.flatnonzero(slope < 12 * max(abs(p1), abs(p2)) * a)
    end = a[flat[0]] if flat.size else np.inf
    inside = np.flatnonzero((a < min(0.9 * cam.r_max, 4.0)) & (a < end))
    theta = t[inside[-1]] * np.r_[0.0, rng.uniform(0, 1, n), 1 - margin]
    return directions(theta, rng.uniform(-np.pi, np.pi, theta.size))


@settings(max_examples=60, deadline=None, database=None)
@given(unified_cameras(), st.integers(0, 2**31 - 1))
def test_round_trips_over_the_valid_field(cam: Unified, seed: int) -> None:
    rng = np.random.default_rng(seed)
    b = field_directions(cam, rng, 300)
    uv = cam.project(b * rng.uniform(0.1, 50.0, (len(b), 1)))
    assert np.all(np.isfinite(uv)), "every direction inside the valid region is imaged"
    np.testing.assert_allclose(cam.bearing(uv), b, atol=1e-7)
    pix = np.c_[rng.uniform(-2000, 2800, 500), rng.uniform(-2000, 2600, 500)]
    assert_pixel_round_trip(cam, pix, atol=1e-6)


@settings(max_examples=40, deadline=None, database=None)
@given(unified_cameras(), st.integers(0, 2**31 - 1))
def test_jacobian_matches_central_differences(cam: Unified, seed: int) -> None:
    rng = np.random.default_rng(seed)
    p = field_directions(cam, rng, 40, margin=0.05) * rng.uniform(0.3, 30.0, (42, 1))
    assert_jacobian(cam, p, rel=5e-6)


def test_valid_region() -> None:
    # xi <= 1: z > -xi |p|; the rest has no image (the shifted pinhole would see it from behind)
    cam = Unified(640, 480, K, 0.8)
    b = directions(np.arccos([-0.79, -0.81, -0.99]), np.zeros(3))
    np.testing.assert_array_equal(np.isfinite(cam.project(b)[:, 0]), [True, False, False])
    assert np.all(np.isnan(cam.d_uv_d_point(b[1:])))
    edge = directions(np.arccos(-0.8) * np.array([1 - 1e-9]), np.array([0.4]))  # 4e5 px out
    np.testing.assert_allclose(cam.bearing(cam.project(edge)), edge, atol=1e-9)
    # xi > 1: z > -|p| / xi, where the map from the sphere folds; pixels beyond its image have no ray
    cam = Unified(640, 480, K, 2.0)
    t = np.linspace(0.0, np.arccos(-0.5), 20001)[:-1]
    u = cam.project(directions(t, np.zeros_like(t)))[:, 0]
    assert np.all(np.diff(u) > 0)
    assert np.all(np.isnan(cam.project(directions(np.arccos([-0.51, -0.9]), np.zeros(2)))))
    a_max = 1 / math.sqrt(2.0**2 - 1)  # the normalised radius of the fold
    b = cam.bearing(np.c_[320.5 + 300.0 * a_max * np.array([0.999, 1.001]), [241.0, 241.0]])
    np.testing.assert_array_equal(np.isfinite(b[:, 0]), [True, False])
    # a distortion polynomial that folds back: nothing beyond its turning radius
    cam = Unified(640, 480, K, 0.5, [-0.3, 0.0, 0.0, 0.0])  # r (1 - 0.3 r^2) turns at r = 1/3 sqrt(10)
    assert cam.r_max == pytest.approx(1 / math.sqrt(0.9), rel=1e-9)
    t = np.linspace(0.0, np.arccos(-0.5) - 1e-3, 100001)
    a = np.sin(t) / (np.cos(t) + 0.5)  # the normalised radius before distortion
    t = np.array([t[a < 0.99 * cam.r_max][-1], t[a > 1.01 * cam.r_max][0]])
    np.testing.assert_array_equal(np.isfinite(cam.project(directions(t, np.zeros(2)))[:, 0]), [True, False])


def test_config_round_trip_and_errors() -> None:
    section = {"model": "unified", "width": 640, "height": 480, "K": K, "xi": 0.9, "dist": DIST}
    base = {"board": {"squares": [6, 8], "square_size": 0.075}, "lidar": {"model": "hdl32"}}
    cfg = parse_config({**base, "camera": yaml.safe_load(yaml.safe_dump(section))}, "DATA/config.yaml")
    assert cfg.camera == MEI and cfg.camera.kind == "unified"
    assert make_camera(yaml.safe_load(yaml.safe_dump(MEI.to_dict()))) == MEI
    assert MEI.to_dict() == section
    no_dist = parse_config({**base, "camera": {k: v for k, v in section.items() if k != "dist"}}).camera
    assert no_dist.dist.tolist() == [0.0] * 4
    for change, words in [
        ({"xi": -0.1}, ["DATA/config.yaml", "camera.xi = -0.1", "[0.0, inf]"]),
        ({"dist": [0.1, 0.0, 0.0, 0.0, 0.01]}, ["camera.dist", "a list of 4 numbers"]),
        ({"alpha": 0.5}, ["camera.alpha", "no such key"]),
        ({"K": [[300, 0, 320], [0, 0, 240], [0, 0, 1]]}, ["camera.K", "fx, fy > 0"]),
    ]:
        with pytest.raises(InputError) as err:
            parse_config({**base, "camera": {**section, **change}}, "DATA/config.yaml")
        assert all(w in str(err.value) for w in words), str(err.value)


def test_kalibr_export_is_omni_radtan() -> None:
    cam0 = yaml.safe_load(export_calibration((np.eye(4), np.eye(6) * 1e-6), "kalibr", camera=MEI))["cam0"]
    assert cam0["camera_model"] == "omni"
    assert cam0["intrinsics"] == [0.9, 300.0, 302.0, 320.5, 241.0]  # xi, fx, fy, cx, cy
    assert cam0["distortion_model"] == "radtan" and cam0["distortion_coeffs"] == DIST
    assert cam0["resolution"] == [640, 480]


def test_image_stage_finds_the_board_in_simulated_images() -> None:
    assert_image_stage_finds_boards("unified", width=800, seed=4)


def test_simulated_data_set_calibrates(tmp_path) -> None:
    assert_simulated_set_calibrates("unified", tmp_path / "sim")
