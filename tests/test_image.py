"""Image stage: corners on simulated panoramas, pinhole and fisheye images, against the true projection."""

from __future__ import annotations

import dataclasses
import time
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from ilcc_graph.board import Board
from ilcc_graph.errors import CornersNotFound
from ilcc_graph.image import ImageOptions, detect_corners, detectors
from ilcc_graph.image.detectors import grid_problem
from ilcc_graph.simulate import SceneOptions, simulate_frames, standard_spec
from ilcc_graph.simulate.spec import default_T_cam_lidar

ODD_BOARD = Board(7, 8, 0.1, lower_left="white")  # 7 + 8 odd: no half-turn symmetry, order is exact
MARGIN_BOARD = Board(5, 8, 0.09, margin_long=0.05, margin_short=0.03)  # odd too, with a white margin


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def facing_pose(board: Board, centre_lidar, camera_lidar, roll: float = 0.0, tilt: float = 0.0) -> np.ndarray:
    """T_lidar_board: pattern centre at ``centre_lidar``, z towards ``camera_lidar``, rolled about z."""
    c = np.asarray(centre_lidar, dtype=float)
    z = np.asarray(camera_lidar, dtype=float) - c
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z]) @ _rot(0, tilt) @ _rot(2, roll)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = c - R @ board.pattern_centre
    return T


def camera_centre(T_cam_lidar: np.ndarray) -> np.ndarray:
    return -T_cam_lidar[:3, :3].T @ T_cam_lidar[:3, 3]


def truth_uv(spec, T_lidar_board: np.ndarray) -> np.ndarray:
    b = spec.board
    P = (spec.T_cam_lidar @ T_lidar_board @ np.c_[b.corners_board(), np.ones(b.n_corners)].T)[:3].T
    return spec.camera.project(P)


def pixel_error(camera, uv: np.ndarray, ref: np.ndarray) -> np.ndarray:
    d = uv - ref
    if hasattr(camera, "wrap_du"):
        d[:, 0] = camera.wrap_du(d[:, 0])
    return np.linalg.norm(d, axis=1)


def check(spec, frame, exact: bool, med_px: float = 0.15, max_px: float = 0.6, options=None):
    """Detect, compare with the truth (exact order, or up to the half turn), check the covariance."""
    res = detect_corners(frame.image, spec.camera, spec.board, options)
    ref = truth_uv(spec, frame.T_lidar_board)
    e = pixel_error(spec.camera, res.uv, ref)
    if not exact:
        assert res.half_turn_ambiguous
        e_turn = pixel_error(spec.camera, res.uv, ref[spec.board.half_turn_permutation()])
        e = e if e.max() < e_turn.max() else e_turn
    else:
        assert not res.half_turn_ambiguous
    assert np.median(e) < med_px and e.max() < max_px, (np.median(e), e.max())
    K = spec.board.n_corners
    assert res.uv.shape == (K, 2) and res.bearings.shape == (K, 3) and res.cov_px.shape == (K, 2, 2)
    np.testing.assert_allclose(np.linalg.norm(res.bearings, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(res.bearings, spec.camera.bearing(res.uv), atol=1e-12)
    np.testing.assert_allclose(res.cov_px, np.swapaxes(res.cov_px, 1, 2), atol=1e-15)
    assert np.all(np.linalg.eigvalsh(res.cov_px) >= 0.05**2 * (1 - 1e-9))
    assert np.all(spec.camera.in_image(res.uv))
    return res, e


# ----------------------------------------------------------------------------- panoramas
@pytest.fixture(scope="module")
def pano():
    """2000x1000 panorama, odd board: across the seam, high, low; a margin board; a rolled board."""
    T_cl = default_T_cam_lidar("equirectangular")
    cam_c = camera_centre(T_cl)
    R_lc = T_cl[:3, :3].T

    def at(az_deg, el_deg, dist):
        a, e = np.deg2rad(az_deg), np.deg2rad(el_deg)
        d_cam = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        return cam_c + dist * (R_lc @ d_cam)

    poses = [
        facing_pose(ODD_BOARD, at(180.0, 0.0, 2.2), cam_c, roll=0.3),  # straddles the seam
        facing_pose(ODD_BOARD, at(60.0, 42.0, 1.7), cam_c, roll=-0.5, tilt=0.3),  # high
        facing_pose(ODD_BOARD, at(-100.0, -35.0, 2.0), cam_c, roll=2.0),  # low, turned
    ]
    spec = standard_spec(camera="equirectangular", width=2000, board=ODD_BOARD, placements=tuple(poses))
    return spec, list(simulate_frames(spec))


def test_panorama_board_across_the_seam(pano):
    spec, frames = pano
    ref = truth_uv(spec, frames[0].T_lidar_board)
    assert ref[:, 0].min() < 100 and ref[:, 0].max() > spec.camera.width - 100  # it really straddles
    check(spec, frames[0], exact=True)


def test_panorama_high_and_low_boards(pano):
    spec, frames = pano
    for f in frames[1:]:
        check(spec, f, exact=True)


@pytest.fixture(scope="module")
def pole():
    """A board 68 deg up in a 2000x1000 panorama, open scene: the raw image bends it too much."""
    T_cl = default_T_cam_lidar("equirectangular")
    cam_c = camera_centre(T_cl)
    a, e = np.deg2rad(30.0), np.deg2rad(68.0)
    centre = cam_c + 2.0 * (
        T_cl[:3, :3].T @ np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    )
    pose = facing_pose(ODD_BOARD, centre, cam_c, roll=0.4)
    scene = SceneOptions(room=None, clutter=False)
    spec = standard_spec(
        camera="equirectangular", width=2000, board=ODD_BOARD, placements=(pose,), scene=scene
    )
    return spec, list(simulate_frames(spec))


def test_panorama_board_near_the_pole(pole):
    spec, frames = pole
    check(spec, frames[0], exact=True)  # Geiger's detector copes with the bent grid in the raw image
    # OpenCV's SB does not: the ring of virtual views finds it
    res, _ = check(spec, frames[0], exact=True, options=ImageOptions(quick=(), cascade=("sb",)))
    assert res.diagnostics["coarse_stage"] == 1.0 and res.detector == "sb"


def test_upside_down_panorama(pano):
    spec, frames = pano
    T_flip = np.eye(4)
    T_flip[:3, :3] = _rot(0, np.pi)  # camera rolled half a turn about its forward axis
    spec_ud = dataclasses.replace(spec, T_cam_lidar=T_flip @ spec.T_cam_lidar)
    # (az, el) -> (-az, -el) maps pixel (u, v) to (W-1-u, H-1-v) exactly: the flipped camera's image
    for f in frames:
        flipped = SimpleNamespace(
            image=np.ascontiguousarray(f.image[::-1, ::-1]), T_lidar_board=f.T_lidar_board
        )
        check(spec_ud, flipped, exact=True)


# ------------------------------------------------------------------------ pinhole, fisheye
@pytest.fixture(scope="module")
def pinhole():
    spec = standard_spec(camera="pinhole", width=960, frames=2, seed=3)  # 6x8: half-turn symmetric
    return spec, list(simulate_frames(spec))


def test_pinhole_symmetric_board(pinhole):
    spec, frames = pinhole
    assert spec.board.half_turn_symmetric
    for f in frames:
        check(spec, f, exact=False)


@pytest.fixture(scope="module")
def fisheye():
    spec = standard_spec(camera="fisheye", width=1280, frames=2, seed=5, board=MARGIN_BOARD)
    return spec, list(simulate_frames(spec))


def test_fisheye_margin_board(fisheye):
    spec, frames = fisheye
    for f in frames:
        check(spec, f, exact=True)


def test_geiger_back_end(fisheye):
    spec, frames = fisheye
    res, _ = check(spec, frames[0], exact=True, options=ImageOptions(quick=(), cascade=("cbdetect",)))
    assert res.detector == "cbdetect"


def test_fine_detector_agrees_with_refined_coarse_corners(fisheye):
    spec, frames = fisheye
    fast, e_fast = check(spec, frames[1], exact=True)
    assert fast.diagnostics["fine_redetected"] == 0.0  # default: coarse corners refined in the fine view
    sb, e_sb = check(spec, frames[1], exact=True, options=ImageOptions(reuse_coarse=False))
    assert sb.diagnostics["fine_redetected"] == 1.0 and sb.detector == "sb"
    assert np.max(np.abs(fast.uv - sb.uv)) < 0.05 and abs(np.median(e_fast) - np.median(e_sb)) < 0.01


@pytest.fixture(scope="module")
def upside_down_pinhole():
    T = default_T_cam_lidar("pinhole").copy()
    T[:3] = np.diag([-1.0, -1.0, 1.0]) @ T[:3]  # rolled by pi about the optical axis
    spec = standard_spec(camera="pinhole", width=960, frames=2, seed=7, board=ODD_BOARD, T_cam_lidar=T)
    return spec, list(simulate_frames(spec))


def test_upside_down_pinhole_exact_order(upside_down_pinhole):
    spec, frames = upside_down_pinhole
    for f in frames:
        check(spec, f, exact=True)


def test_half_turned_board_exact_order(pinhole):
    """The same physical board held half turned: the odd board's colours give the order back."""
    spec0, _ = pinhole
    cam_c = camera_centre(spec0.T_cam_lidar)
    T0 = facing_pose(ODD_BOARD, [2.0, 0.3, 0.0], cam_c, roll=0.2)
    spec = dataclasses.replace(spec0, board=ODD_BOARD, placements=(T0, T0 @ ODD_BOARD.T_half_turn()))
    frames = list(simulate_frames(spec))
    uv = [check(spec, f, exact=True)[0].uv for f in frames]
    np.testing.assert_allclose(uv[1], uv[0][ODD_BOARD.half_turn_permutation()], atol=0.5)


# -------------------------------------------------------------- dark, low contrast, shaded
def _board_mask(spec, T_lidar_board) -> np.ndarray:
    """(H, W) float32 1 on the physical board (margin included), 0 elsewhere, edges smoothed."""
    b = spec.board
    x0, x1, y0, y1 = b.extent()
    t = np.linspace(0.0, 1.0, 40)[:, None]
    sides = [(np.array([x0, y0]), np.array([x1, y0])), (np.array([x1, y0]), np.array([x1, y1]))]
    sides += [(np.array([x1, y1]), np.array([x0, y1])), (np.array([x0, y1]), np.array([x0, y0]))]
    xy = np.concatenate([a + t * (c - a) for a, c in sides])  # sampled edges: bent in a fisheye
    P = (spec.T_cam_lidar @ T_lidar_board @ np.c_[xy, np.zeros(len(xy)), np.ones(len(xy))].T)[:3].T
    m = np.zeros((spec.camera.height, spec.camera.width), np.uint8)
    cv2.fillPoly(m, [np.round(spec.camera.project(P)).astype(np.int32)], 1)
    return cv2.GaussianBlur(m.astype(np.float32), (0, 0), 1.0)


def _degraded(image: np.ndarray, gain, offset: float = 0.0, noise: float = 1.0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    g = np.asarray(gain, dtype=np.float64)
    g = g[..., None] if g.ndim == 2 else g
    out = image.astype(np.float64) * g + offset + rng.normal(0.0, noise, image.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("gain, offset", [(0.2, 0.0), (0.15, 100.0)], ids=["dark", "low-contrast"])
def test_dark_and_low_contrast_images(pinhole, gain, offset):
    """The whole image dark (white at ~50) or washed out (grey 100..140), with noise."""
    spec, frames = pinhole
    f = frames[0]
    dark = SimpleNamespace(image=_degraded(f.image, gain, offset), T_lidar_board=f.T_lidar_board)
    res, _ = check(spec, dark, exact=False)
    assert res.diagnostics["colour_score"] > 0.9


def test_shaded_board(pinhole):
    """The board in shade against a bright room (like the recorded pinhole set): SB misses it,
    the cascade does not, and the corners are as accurate as in the bright image."""
    spec, frames = pinhole
    f = frames[0]
    shade = 1.0 - 0.7 * _board_mask(spec, f.T_lidar_board)  # the board at 30 % of its brightness
    shaded = SimpleNamespace(image=_degraded(f.image, shade), T_lidar_board=f.T_lidar_board)
    with pytest.raises(CornersNotFound):
        sb_only = ImageOptions(quick=(), cascade=("sb",), tile_views=False)
        detect_corners(shaded.image, spec.camera, spec.board, sb_only)
    res, e = check(spec, shaded, exact=False)
    assert res.detector != "sb"
    bright, e_bright = check(spec, f, exact=False)
    assert bright.detector == "classic"  # the cheap search finds the bright board (issue 37)
    assert np.median(e) < np.median(e_bright) + 0.05


def test_deep_shade_needs_the_contrast_variant(fisheye):
    """The board at 15 % of its brightness: only the gamma-lifted search image shows it; the
    contrast variants come after the plain ones, so a bright image is found exactly as without."""
    spec, frames = fisheye
    f = frames[0]
    plain = ImageOptions(cascade=tuple(a for a in ImageOptions().cascade if "+" not in a))
    shade = 1.0 - 0.85 * _board_mask(spec, f.T_lidar_board)
    deep = SimpleNamespace(image=_degraded(f.image, shade), T_lidar_board=f.T_lidar_board)
    with pytest.raises(CornersNotFound):
        detect_corners(deep.image, spec.camera, spec.board, dataclasses.replace(plain, tile_views=False))
    res, _ = check(spec, deep, exact=True)
    assert "+" in res.detector  # found on a contrast variant (then refined on the image itself)
    bright = detect_corners(f.image, spec.camera, spec.board)
    np.testing.assert_array_equal(bright.uv, detect_corners(f.image, spec.camera, spec.board, plain).uv)


# --------------------------------------------------------------------- detectors and checks
def test_detectors_agree_on_a_simulated_image(fisheye):
    """Each detector alone seeds the same refinement: the same corners (well within their sigma)
    and the same measured sigma, whichever found the board."""
    spec, frames = fisheye
    runs = {
        n: check(spec, frames[0], exact=True, options=ImageOptions(quick=(), cascade=(n,)))[0]
        for n in ("sb", "classic", "cbdetect")
    }
    ref = runs["sb"]
    sig = np.sqrt(np.linalg.eigvalsh(ref.cov_px)[:, 0])
    for name, res in runs.items():
        assert res.detector == name
        assert np.all(np.linalg.norm(res.uv - ref.uv, axis=1) < 0.5 * sig), name
        assert res.diagnostics["sigma_view_px"] == pytest.approx(ref.diagnostics["sigma_view_px"], rel=0.1)
        np.testing.assert_allclose(res.cov_px, ref.cov_px, rtol=0.25, atol=1e-4)


def test_grid_problem_catches_folded_and_wrong_grids():
    b = Board(5, 7, 0.1)
    jj, ii = np.meshgrid(np.arange(6.0), np.arange(4.0))
    xy = np.stack([100 + 30 * jj.ravel() + 5 * ii.ravel(), 80 + 28 * ii.ravel()], axis=1)
    assert grid_problem(xy, b) is None
    assert grid_problem(xy[::-1], b) is None  # any order the detectors use is fine
    folded = xy.copy()
    folded[[8, 9]] = folded[[9, 8]]
    assert "folded" in grid_problem(folded, b)
    assert "corners instead" in grid_problem(xy[:-1], b)
    nan = xy.copy()
    nan[3] = np.nan
    assert grid_problem(nan, b) is not None


@pytest.mark.parametrize("spoil", ["fold", "noise"])
def test_a_false_grid_from_a_detector_does_not_get_through(pinhole, monkeypatch, spoil):
    """SB made to return a folded grid, or one that fits no plane: it is rejected and the next
    detector of the cascade finds the real board."""
    spec, frames = pinhole
    real_sb = detectors.DETECTORS["sb"]
    rng = np.random.default_rng(1)

    def bad_sb(gray, board):
        xy = real_sb(gray, board)
        if xy is None:
            return None
        sq = np.median(
            np.linalg.norm(np.diff(xy.reshape(board.rows - 1, board.cols - 1, 2), axis=1), axis=-1)
        )
        if spoil == "fold":
            xy[[8, 9]] = xy[[9, 8]]
        else:
            xy = xy + rng.normal(0.0, 0.3 * sq, xy.shape)
        return xy

    monkeypatch.setitem(detectors.DETECTORS, "sb", bad_sb)
    res, _ = check(spec, frames[0], exact=False, options=ImageOptions(quick=(), cascade=("sb", "cbdetect")))
    assert res.detector == "cbdetect"


@pytest.mark.parametrize("name", sorted(detectors.DETECTORS))
def test_detectors_on_images_without_corners(name):
    """Blank, uniform, noisy and tiny images: every detector says "not found" (libcbdetect used to
    divide by zero when it saw no corner at all, which killed the process)."""
    rng = np.random.default_rng(0)
    board = Board(6, 8, 0.075)
    for gray in (
        np.zeros((300, 400), np.uint8),
        np.full((300, 400), 200, np.uint8),
        rng.integers(0, 256, (300, 400)).astype(np.uint8),
        np.zeros((8, 8), np.uint8),
    ):
        assert detectors.run_attempt(name, detectors.ContrastCache(gray), board) is None
        assert detectors.run_attempt(f"{name}+gamma", detectors.ContrastCache(gray), board) is None


def test_detector_name_in_the_result(pinhole):
    spec, frames = pinhole
    assert detect_corners(frames[0].image, spec.camera, spec.board).detector == "classic"  # the cheap search
    assert detect_corners(frames[0].image, spec.camera, spec.board, ImageOptions(quick=())).detector == "sb"
    for name in ("classic", "cbdetect+gamma"):
        only = ImageOptions(quick=(), cascade=(name,))
        assert detect_corners(frames[0].image, spec.camera, spec.board, only).detector == name


# ------------------------------------------------------------------------------- failures
def test_no_board_raises(pinhole):
    spec, _ = pinhole
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, size=(spec.camera.height // 8, spec.camera.width // 8, 3), dtype=np.uint8)
    img = np.kron(img, np.ones((8, 8, 1), dtype=np.uint8))[: spec.camera.height, : spec.camera.width]
    with pytest.raises(CornersNotFound, match="no 6x8-square chessboard"):
        detect_corners(img, spec.camera, spec.board, ImageOptions(tile_views=False))


def test_no_board_with_the_whole_search_raises(pinhole):
    """Every detector and contrast variant, then the ring of views: still a clear CornersNotFound.

    The time bound is a guard against a runaway search (measured ~1-3 s; scripts/bench_image.py)."""
    spec, frames = pinhole
    img = frames[0].image.copy()
    img[_board_mask(spec, frames[0].T_lidar_board) > 0] = 128  # the room without the board
    t0 = time.perf_counter()
    with pytest.raises(CornersNotFound, match="no 6x8-square chessboard"):
        detect_corners(img, spec.camera, spec.board)
    assert time.perf_counter() - t0 < 30.0


def test_wrong_board_size_raises(pinhole):
    spec, frames = pinhole
    with pytest.raises(CornersNotFound):
        detect_corners(frames[0].image, spec.camera, Board(5, 9, 0.075), ImageOptions(tile_views=False))


def test_lower_left_contradicting_the_print(pinhole):
    """6x8 board configured white-origin on a black-origin print: clear error, or geometry only."""
    spec, frames = pinhole
    wrong = dataclasses.replace(spec.board, lower_left="white")
    with pytest.raises(CornersNotFound, match="lower_left: white"):
        detect_corners(frames[0].image, spec.camera, wrong)
    res = detect_corners(frames[0].image, spec.camera, wrong, ImageOptions(strict_colour=False))
    assert res.half_turn_ambiguous and res.diagnostics["colour_score"] < -0.5


@pytest.mark.parametrize(
    "bad",
    [
        [[0, 1], [2, 3]],  # not an array
        np.zeros((600, 960, 2), dtype=np.uint8),  # two channels
        np.zeros((601, 960, 3), dtype=np.uint8),  # not the camera's size
        np.full((600, 960), "a"),  # strings
        np.full((600, 960), np.nan),  # NaN
        np.zeros(5),  # 1-D
    ],
)
def test_not_an_image_raises_value_error(pinhole, bad):
    spec, _ = pinhole
    assert (spec.camera.width, spec.camera.height) == (960, 600)
    with pytest.raises(ValueError):
        detect_corners(bad, spec.camera, spec.board)


def test_options_are_checked():
    with pytest.raises(ValueError, match="unknown detector attempt"):
        ImageOptions(quick=(), cascade=("sb", "harris"))
    with pytest.raises(ValueError, match="unknown detector attempt"):
        ImageOptions(quick=(), cascade=("sb+sharpen",))
    with pytest.raises(ValueError):
        ImageOptions(quick=(), cascade="sb")
    with pytest.raises(ValueError):
        ImageOptions(coarse_width=10)
    with pytest.raises(ValueError):
        ImageOptions(floor_px=-1.0)
