"""The paper's intensity re-projection error and the corner errors on cases with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ilcc_graph.board import Board
from ilcc_graph.cameras import R_FLU_OPENCV, Equirectangular, Pinhole
from ilcc_graph.evaluation.frame_errors import evaluate
from ilcc_graph.evaluation.metric import (
    EvalFrame,
    cell_coordinates,
    gray_zone,
    intensity_colour,
    metric_points,
    transform_points,
)

BOARD = Board(6, 8, 0.075)
R_OPENCV_LIDAR = R_FLU_OPENCV.T  # nominal R_cam_lidar of a lens camera looking along LiDAR x


def pose(rotvec_deg, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    T[:3, 3] = t
    return T


def board_pose_facing(centre_lidar: np.ndarray, yaw_deg: float, board: Board = BOARD) -> np.ndarray:
    """T_lidar_board with the board centred at ``centre_lidar``, its printed face towards the origin."""
    n = -centre_lidar / np.linalg.norm(centre_lidar)  # board z towards the LiDAR
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(up, n)
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    R = np.stack([x, y, n], axis=1) @ Rotation.from_rotvec([0, 0, np.radians(yaw_deg)]).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre_lidar - R @ board.pattern_centre
    return T


def synthetic_frame(
    name: str,
    T_lidar_board: np.ndarray,
    T_cam_lidar: np.ndarray,
    camera,
    rng: np.random.Generator,
    n_points: int = 1500,
    px_noise: float = 0.3,
) -> EvalFrame:
    """Board points (uniform over the board, intensity by colour, 1 cm range noise), noisy corners."""
    x0, x1, y0, y1 = BOARD.extent()
    q = np.column_stack([rng.uniform(x0, x1, n_points), rng.uniform(y0, y1, n_points), np.zeros(n_points)])
    colour = BOARD.colour_at(q)
    intensity = np.where(colour > 0.5, 80.0, 8.0) + rng.normal(0.0, 3.0, n_points)
    p_lidar = transform_points(T_lidar_board, q)
    p_lidar *= 1.0 + rng.normal(0.0, 0.01, (n_points, 1)) / np.linalg.norm(p_lidar, axis=1, keepdims=True)
    corners_lidar = transform_points(T_lidar_board, BOARD.corners_board())
    uv = camera.project(transform_points(T_cam_lidar, corners_lidar)) + rng.normal(
        0, px_noise, (BOARD.n_corners, 2)
    )
    return EvalFrame(name, p_lidar, intensity, uv, corners_lidar, T_lidar_board)


def frames_for(camera, T_cam_lidar, rng, centres, px_noise: float = 0.1):
    return [
        synthetic_frame(
            f"{k:04d}",
            board_pose_facing(np.asarray(c, float), 10.0 * k),
            T_cam_lidar,
            camera,
            rng,
            px_noise=px_noise,
        )
        for k, c in enumerate(centres)
    ]


PANO = Equirectangular(2000, 1000)
T_PANO = pose([2.0, -3.0, 4.0], [0.05, -0.03, 0.25])
PANO_CENTRES = [(4.0, 1.0, 0.2), (3.0, -2.0, -0.3), (-2.0, 4.0, 0.5), (5.0, 0.0, 0.0)]


def test_gray_zone_takes_the_middle_half_between_the_peaks() -> None:
    rng = np.random.default_rng(0)
    r = np.concatenate([rng.normal(10, 1, 500), rng.normal(90, 1, 500)])
    lo, hi = gray_zone(r)
    assert lo == pytest.approx(30, abs=2.5) and hi == pytest.approx(70, abs=2.5)
    cls = intensity_colour(np.array([5.0, 50.0, 95.0]), (lo, hi))
    assert cls.tolist() == [0, -1, 1]


def test_cell_coordinates_recover_pattern_coordinates_under_a_homography() -> None:
    rng = np.random.default_rng(1)
    H = np.array([[80.0, 10.0, 200.0], [-5.0, 90.0, 100.0], [0.02, 0.01, 1.0]])
    ni, nj = BOARD.inner_shape

    def to_px(ab):
        h = np.column_stack([ab, np.ones(len(ab))]) @ H.T
        return h[:, :2] / h[:, 2:]

    corners = to_px(BOARD.corners_board()[:, :2] / BOARD.square_size)
    ab = np.column_stack([rng.uniform(0, BOARD.cols, 400), rng.uniform(0, BOARD.rows, 400)])
    inside, got = cell_coordinates(to_px(ab), corners, BOARD)
    want_inside = (ab[:, 0] > 1) & (ab[:, 0] < nj) & (ab[:, 1] > 1) & (ab[:, 1] < ni)
    np.testing.assert_array_equal(inside, want_inside)
    np.testing.assert_allclose(got[inside], ab[inside], atol=1e-9)


def test_perfect_extrinsic_gives_near_zero_and_one_degree_is_clearly_larger() -> None:
    rng = np.random.default_rng(2)
    frames = frames_for(PANO, T_PANO, rng, PANO_CENTRES)
    good = evaluate(frames, PANO, BOARD, T_PANO)
    bad = evaluate(frames, PANO, BOARD, pose([0.0, 0.0, 1.0], [0, 0, 0]) @ T_PANO)
    g_mean, _ = good.intensity_mrad
    b_mean, _ = bad.intensity_mrad
    assert g_mean < 0.2, good.frames  # 0.1 px of corner noise is 0.3 mrad at 2000 px / 360 deg
    assert b_mean > 10 * g_mean and b_mean > 2.0, (good.frames, bad.frames)
    for f in good.frames:
        assert f.attendance > 0.9 and f.n_inside > 100
        assert f.corner_rms_px < 0.3 and f.corner_rms_mrad < 1.0
    for f in bad.frames:  # 1 degree = 17.5 mrad of bearing, ~5.6 px at 2000 px / 360 deg
        assert f.corner_rms_mrad == pytest.approx(17.45, rel=0.1)
        assert f.intensity_mrad > 5 * max(g.intensity_mrad for g in good.frames)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_every_rotation_axis_and_a_translation_raise_the_metric(axis: int) -> None:
    rng = np.random.default_rng(3)
    frames = frames_for(PANO, T_PANO, rng, PANO_CENTRES)
    good = evaluate(frames, PANO, BOARD, T_PANO).intensity_mrad[0]
    rv = np.zeros(3)
    rv[axis] = 1.0
    assert evaluate(frames, PANO, BOARD, pose(rv, [0, 0, 0]) @ T_PANO).intensity_mrad[0] > 5 * good
    t = np.zeros(3)
    t[axis] = 0.05
    assert evaluate(frames, PANO, BOARD, pose([0, 0, 0], t) @ T_PANO).intensity_mrad[0] > 3 * good


def test_pinhole_camera_and_the_metric_grows_with_the_error() -> None:
    rng = np.random.default_rng(4)
    cam = Pinhole(640, 480, np.array([[400.0, 0, 320], [0, 400.0, 240], [0, 0, 1]]), np.zeros(5))
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.radians([1.0, 2.0, -1.0])).as_matrix() @ R_OPENCV_LIDAR
    T[:3, 3] = [0.1, -0.2, 0.05]
    frames = frames_for(cam, T, rng, [(3.0, 0.3, 0.2), (4.0, -0.5, -0.2), (2.5, 0.0, 0.4)])
    values = [
        evaluate(frames, cam, BOARD, pose([0, 0, a], [0, 0, 0]) @ T).intensity_mrad[0]
        for a in (0.0, 0.3, 1.0)
    ]
    assert values[0] < 0.3 and values[0] < values[1] < values[2], values


def test_points_pushed_off_the_pattern_count_through_the_attendance_rate() -> None:
    rng = np.random.default_rng(5)
    frames = frames_for(PANO, T_PANO, rng, PANO_CENTRES[:1])
    far = pose([0, 0, 4.0], [0, 0, 0]) @ T_PANO  # shifts the cloud by ~4 squares sideways
    ev = evaluate(frames, PANO, BOARD, far).frames[0]
    assert ev.attendance < 0.6
    mp = metric_points(frames[0], PANO, BOARD, far)
    assert int(mp.inside.sum()) == ev.n_inside
    very_far = pose([0, 0, 40.0], [0, 0, 0]) @ T_PANO
    assert evaluate(frames, PANO, BOARD, very_far).frames[0].intensity_mrad == np.inf


def test_board_across_the_panorama_seam() -> None:
    rng = np.random.default_rng(6)
    T = pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.2])
    frames = frames_for(PANO, T, rng, [(-4.0, 0.0, 0.0)])  # straight behind: az = +-pi
    uv = frames[0].uv
    assert uv[:, 0].min() < 100 and uv[:, 0].max() > 1900  # the corners straddle the seam
    ev = evaluate(frames, PANO, BOARD, T).frames[0]
    assert ev.n_inside > 100 and ev.intensity_mrad < 0.3 and ev.corner_rms_px < 1.0


def test_half_turned_image_corners_still_compare_fairly() -> None:
    rng = np.random.default_rng(7)
    f = frames_for(PANO, T_PANO, rng, PANO_CENTRES[:1])[0]
    turned = EvalFrame(f.name, f.points_lidar, f.intensity, f.uv[::-1], f.corners_lidar, f.T_lidar_board)
    a, b = evaluate([f, turned], PANO, BOARD, T_PANO).frames
    assert not a.half_turn and b.half_turn
    assert b.corner_rms_px == pytest.approx(a.corner_rms_px)
    assert b.intensity_mrad == pytest.approx(a.intensity_mrad, abs=0.05)


def test_expected_corner_error_matches_a_monte_carlo_of_the_stated_uncertainties() -> None:
    from ilcc_graph.evaluation.frame_errors import corner_errors, expected_corner_px
    from ilcc_graph.types import BoardFit, FrameResult, ImageCorners

    rng = np.random.default_rng(8)
    T_lb = board_pose_facing(np.array([3.0, 1.0, 0.3]), 20.0)
    A = rng.normal(size=(6, 6))
    cov_b = A @ A.T * 1e-6 + np.diag([1e-6, 1e-6, 4e-6, 4e-6, 4e-6, 1e-6])
    K = BOARD.n_corners
    cov_px = np.tile(np.diag([0.3**2, 0.2**2]), (K, 1, 1))
    uv_true = PANO.project(transform_points(T_PANO @ T_lb, BOARD.corners_board()))
    corners_lidar = transform_points(T_lb, BOARD.corners_board())
    bf = BoardFit(T_lb, cov_b, corners_lidar, np.zeros((0, 3)), np.zeros(0), True)
    fr = FrameResult("x", True, None, bf, ImageCorners(uv_true, PANO.bearing(uv_true), cov_px, True))
    want = expected_corner_px(fr, PANO, BOARD, T_PANO)
    L = np.linalg.cholesky(cov_b)
    sq = []
    for _ in range(400):
        xi = L @ rng.normal(size=6)
        D = np.eye(4)
        D[:3, :3] = Rotation.from_rotvec(xi[:3]).as_matrix()
        D[:3, 3] = xi[3:]
        corners = transform_points(T_lb @ D, BOARD.corners_board())
        uv = uv_true + rng.normal(size=(K, 2)) * [0.3, 0.2]
        sq.append(corner_errors(corners, uv, PANO, T_PANO)[0] ** 2)
    assert np.sqrt(np.mean(sq)) == pytest.approx(want, rel=0.08)
    assert want > np.sqrt(0.3**2 + 0.2**2) * 1.2  # the LiDAR pose's share is not negligible here
