"""Image stage internals: virtual views, their Jacobian, the measured covariance, the ordering rules."""

from __future__ import annotations

import numpy as np
import pytest

from ilcc_graph.board import Board
from ilcc_graph.cameras import Equirectangular, Fisheye, Pinhole
from ilcc_graph.errors import CornersNotFound
from ilcc_graph.image.ordering import order_grid
from ilcc_graph.image.uncertainty import homography_sigma, image_covariance
from ilcc_graph.image.views import (
    VirtualView,
    look_rotation,
    pixels_per_radian,
    render_view,
    view_around,
    view_jacobian,
    view_to_image,
)

K = np.array([[500.0, 0.0, 399.5], [0.0, 500.0, 299.5], [0.0, 0.0, 1.0]])
CAMERAS = [
    Equirectangular(2000, 1000),
    Pinhole(800, 600, K, np.array([-0.1, 0.02, 0.001, -0.001, 0.0])),
    Fisheye(800, 600, K, np.array([0.02, -0.005, 0.001, 0.0])),
]


def _direction(camera, rng) -> np.ndarray:
    """A random camera-frame direction well inside the picture."""
    while True:
        uv = rng.uniform([0.2 * camera.width, 0.2 * camera.height], [0.8 * camera.width, 0.8 * camera.height])
        b = camera.bearing(uv[None])[0]
        if np.all(np.isfinite(b)):
            return b


@pytest.mark.parametrize("camera", CAMERAS, ids=lambda c: c.kind)
def test_view_round_trip_and_jacobian(camera):
    rng = np.random.default_rng(1)
    b = _direction(camera, rng)
    R = look_rotation(camera, b)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    view = VirtualView(R, 400.0, 150.0, 120.0, 300, 240)
    xy = rng.uniform([20, 20], [280, 220], size=(30, 2))
    uv = view_to_image(view, camera, xy)
    np.testing.assert_allclose(view.to_view(camera.bearing(uv)), xy, atol=1e-6)
    # Jacobian against the analytic chain d uv / d b * d b / d xy
    J = view_jacobian(view, camera, xy, h=1e-3)
    h = 1e-6
    for a in range(2):
        step = np.zeros(2)
        step[a] = h
        d = (camera.project(view.rays(xy + step)) - camera.project(view.rays(xy - step))) / (2 * h)
        np.testing.assert_allclose(J[:, :, a], d, rtol=1e-5, atol=1e-5)


def test_view_is_upright_and_across_the_seam():
    cam = Equirectangular(2000, 1000)
    b_seam = np.array([-1.0, 0.0, 0.0])  # azimuth pi: the left/right edge of the panorama
    R = look_rotation(cam, b_seam)
    np.testing.assert_allclose(R[:, 1], [0.0, 0.0, -1.0], atol=1e-12)  # view y = world down
    # a synthetic panorama: a value that is smooth in azimuth across the seam
    vv, uu = np.mgrid[0:1000, 0:2000].astype(np.float64)
    az = 2 * np.pi * (0.5 - (uu + 0.5) / 2000)
    img = np.clip(128 + 100 * np.cos(3 * az) * np.cos(np.pi * (vv / 1000 - 0.5)), 0, 255).astype(np.uint8)
    f = pixels_per_radian(cam, b_seam)
    assert f == pytest.approx(2000 / (2 * np.pi), rel=1e-9)
    view = VirtualView(R, f, 99.5, 99.5, 200, 200)
    out = render_view(view, cam, img).astype(float)
    uv = view_to_image(view, cam, np.stack(np.meshgrid(np.arange(200.0), np.arange(200.0)), axis=-1))
    a = 2 * np.pi * (0.5 - (uv[..., 0] + 0.5) / 2000)
    ref = 128 + 100 * np.cos(3 * a) * np.cos(np.pi * (uv[..., 1] / 1000 - 0.5))
    assert np.abs(out - ref).max() < 3.0  # no garbage column at the seam


def test_view_around_holds_the_directions():
    cam = CAMERAS[1]
    rng = np.random.default_rng(2)
    b = np.array([_direction(cam, rng) for _ in range(5)])
    view = view_around(cam, b, pad_px=10.0)
    xy = view.to_view(b)
    assert np.all(xy >= 10.0 - 1e-9) and np.all(xy <= np.array([view.width, view.height]) - 10.0)


@pytest.mark.parametrize("camera", CAMERAS, ids=lambda c: c.kind)
def test_view_around_on_a_lattice(camera):
    """With snap_px, directions that differ by a small fraction of a pixel get the identical view
    (so the resampled image the corners are refined in does not depend on the seed), and the
    directions still fit inside it."""
    rng = np.random.default_rng(4)
    b = np.array([_direction(camera, rng) for _ in range(5)])
    view = view_around(camera, b, pad_px=10.0, snap_px=2.0)
    xy = view.to_view(b)
    assert np.all(xy >= 9.0) and np.all(xy <= np.array([view.width, view.height]) - 9.0)
    assert float(view.cx).is_integer() and float(view.cy).is_integer()
    same = 0
    for _ in range(20):  # nudge every direction by ~0.01 view px
        nudged = b + rng.normal(0.0, 0.01 / view.f, b.shape)
        nudged /= np.linalg.norm(nudged, axis=1, keepdims=True)
        v2 = view_around(camera, nudged, pad_px=10.0, snap_px=2.0)
        same += int(
            np.array_equal(v2.R_cam_view, view.R_cam_view)
            and (v2.f, v2.cx, v2.cy) == (view.f, view.cx, view.cy)
        )
    assert same >= 17  # a nudge across a lattice cell boundary (2 px) is rare


def test_homography_sigma_measures_the_noise():
    rng = np.random.default_rng(3)
    board = Board(9, 12, 0.05)
    xy_b = board.corners_board()[:, :2]
    H = np.array([[900.0, 80.0, 300.0], [-40.0, 870.0, 200.0], [0.1, 0.2, 1.0]])
    p = np.c_[xy_b, np.ones(len(xy_b))] @ H.T
    xy = p[:, :2] / p[:, 2:]
    sigma0, _ = homography_sigma(xy_b, xy)
    assert sigma0 < 1e-4  # exact data: nothing but round-off
    sigmas = [homography_sigma(xy_b, xy + rng.normal(0, 0.1, xy.shape))[0] for _ in range(200)]
    assert np.mean(np.square(sigmas)) == pytest.approx(0.01, rel=0.05)  # unbiased variance (2K-8)


def test_image_covariance_maps_and_floors():
    J = np.array([[[2.0, 0.0], [0.0, 1.0]], [[1e-3, 0.0], [0.0, 1e-3]]])
    cov = image_covariance(0.1, J, floor_px=0.05)
    np.testing.assert_allclose(cov[0], np.diag([0.04, 0.01]), atol=1e-15)
    np.testing.assert_allclose(cov[1], np.diag([0.0025, 0.0025]), atol=1e-15)


def _rendered_grid(board: Board, R: np.ndarray, t: np.ndarray, f: float = 600.0, c: float = 400.0):
    """800x800 grey image of ``board`` (pose R, t in the view frame) and its corners in the board's order."""
    yy, xx = np.mgrid[0:800, 0:800].astype(np.float64)
    d = np.stack([(xx - c) / f, (yy - c) / f, np.ones_like(xx)], axis=-1)
    n = R[:, 2]
    lam = (n @ t) / (d @ n)
    pb = (lam[..., None] * d - t) @ R  # board-frame hits
    col = board.colour_at(pb.reshape(-1, 3)).reshape(800, 800)
    img = np.where(np.isnan(col), 90.0, 30.0 + 200.0 * np.nan_to_num(col)).astype(np.uint8)
    P = board.corners_board() @ R.T + t
    return img, f * P[:, :2] / P[:, 2:] + c


@pytest.mark.parametrize("board", [Board(5, 8, 0.1), Board(6, 8, 0.1, lower_left="white"), Board(5, 5, 0.1)])
@pytest.mark.parametrize("roll", [0.3, 2.0, -2.5])
def test_order_grid_recovers_the_canonical_order(board, roll):
    c, s = np.cos(roll), np.sin(roll)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.diag([1.0, -1.0, -1.0])  # z to the camera
    t = np.array([0.0, 0.0, 2.0]) - R @ board.pattern_centre
    img, truth = _rendered_grid(board, R, t)
    rng = np.random.default_rng(4)
    g = truth.reshape(board.rows - 1, board.cols - 1, 2)
    for shuffled in (g[::-1], g[:, ::-1], g[::-1, ::-1], g):  # what a detector may return
        res = order_grid(shuffled.reshape(-1, 2) + rng.normal(0, 0.01, (board.n_corners, 2)), board, img,
                         600.0, 400.0, 400.0)  # fmt: skip
        ref = truth if not board.half_turn_symmetric else None
        if ref is None:
            e = min(np.abs(res.corners - truth).max(), np.abs(res.corners - truth[::-1]).max())
            assert res.half_turn_ambiguous
        else:
            e = np.abs(res.corners - ref).max()
            assert not res.half_turn_ambiguous
        assert e < 0.1 and res.colour_score > 0.9


def test_order_grid_lower_left_contradiction():
    """An even x even print whose origin colour is not the configured one: refused, or geometry only."""
    import dataclasses

    board = Board(6, 8, 0.1)
    R = np.diag([1.0, -1.0, -1.0])
    t = np.array([0.0, 0.0, 2.0]) - R @ board.pattern_centre
    img, truth = _rendered_grid(board, R, t)
    wrong = dataclasses.replace(board, lower_left="white")
    with pytest.raises(CornersNotFound, match="set board.lower_left: black"):
        order_grid(truth, wrong, img, 600.0, 400.0, 400.0)
    res = order_grid(truth, wrong, img, 600.0, 400.0, 400.0, strict_colour=False)
    assert res.colour_score < -0.9 and res.half_turn_ambiguous
