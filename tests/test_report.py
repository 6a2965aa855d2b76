"""Studies (cross-validation, frames vs accuracy), overlays, coloured points and the HTML report."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from test_report_metric import BOARD, R_OPENCV_LIDAR, board_pose_facing, pose, synthetic_frame

from ilcc_graph.cameras import Pinhole
from ilcc_graph.evaluation import cross_validate, frames_vs_accuracy, pose_difference
from ilcc_graph.evaluation.metric import transform_points
from ilcc_graph.report import OCCLUDED_RGB, build_report, colour_points, draw_corners, visible_points
from ilcc_graph.types import BoardFit, Calibration, FrameResult, ImageCorners, Scan

CAM = Pinhole(320, 240, np.array([[220.0, 0, 160], [0, 220.0, 120], [0, 0, 1]]), np.zeros(5))
T_TRUE = np.eye(4)
T_TRUE[:3, :3] = Rotation.from_rotvec(np.radians([1.0, -2.0, 1.5])).as_matrix() @ R_OPENCV_LIDAR
T_TRUE[:3, 3] = [0.05, 0.2, -0.04]
CENTRES = [(3.0, 0.3, 0.2), (3.5, -0.6, -0.1), (2.6, 0.1, 0.4), (4.0, 0.5, -0.3), (3.2, -0.2, 0.0)]


def frame_results(rng: np.random.Generator, bad: set[int] = frozenset()) -> list[FrameResult]:
    """FrameResults of synthetic frames; frames in ``bad`` see the camera rotated by 2 degrees."""
    out = []
    for k, c in enumerate(CENTRES):
        T_lb = board_pose_facing(np.asarray(c, float), 8.0 * k)
        T_seen = pose([0, 2.0, 0], [0, 0, 0]) @ T_TRUE if k in bad else T_TRUE
        ef = synthetic_frame(f"{k + 1:04d}", T_lb, T_seen, CAM, rng, n_points=800, px_noise=0.1)
        K = BOARD.n_corners
        bf = BoardFit(T_lb, np.eye(6) * 1e-6, ef.corners_lidar, ef.points_lidar, ef.intensity, True)
        cr = ImageCorners(ef.uv, CAM.bearing(ef.uv), np.tile(np.eye(2) * 0.01, (K, 1, 1)), True)
        out.append(FrameResult(ef.name, True, None, bf, cr))
    return out


def _exp(xi: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(xi[:3]).as_matrix()
    T[:3, 3] = xi[3:]
    return T


def bearing_solver(frames):
    """A small least-squares solver on corner bearings (T = T0 * Exp(xi)), covariance from J."""
    if len(frames) < 2:
        raise ValueError("need two frames")
    P = np.vstack([f.board.corners_lidar for f in frames])
    B = np.vstack([f.corners.bearings for f in frames])
    T0 = pose([0.5, -0.5, 0.5], [0.02, -0.02, 0.02]) @ T_TRUE

    def res(xi):
        pc = transform_points(T0 @ _exp(xi), P)
        return (pc / np.linalg.norm(pc, axis=1, keepdims=True) - B).ravel()

    sol = least_squares(res, np.zeros(6))
    J = sol.jac
    sigma2 = (0.1 / 220.0) ** 2
    return T0 @ _exp(sol.x), np.linalg.inv(J.T @ J) * sigma2


def test_cross_validation_evaluates_each_frame_on_a_fit_that_did_not_see_it() -> None:
    rng = np.random.default_rng(10)
    frames = frame_results(rng, bad={2})
    cv = cross_validate(frames, bearing_solver, CAM, BOARD, folds=len(frames))
    assert len(cv.folds) == len(frames)
    for fold in cv.folds:
        assert set(fold.train).isdisjoint(fold.test) and len(fold.test) == 1
    held = cv.held_out.by_name()
    ins = cv.in_sample.by_name()
    assert [f.name for f in cv.held_out.frames] == [f.name for f in frames]
    # the inconsistent frame looks worse when it cannot pull the fit towards itself
    assert held["0003"].corner_rms_mrad > ins["0003"].corner_rms_mrad
    assert held["0003"].corner_rms_mrad > 25.0  # ~2 degrees = 35 mrad
    fold_without_bad = next(f for f in cv.folds if "0003" in f.test)
    assert np.degrees(np.linalg.norm(pose_difference(T_TRUE, fold_without_bad.T_cam_lidar)[:3])) < 0.05
    assert held["0003"].intensity_mrad > 2 * ins["0003"].intensity_mrad


def test_cross_validation_on_consistent_frames_matches_in_sample() -> None:
    rng = np.random.default_rng(11)
    frames = frame_results(rng)
    cv = cross_validate(frames, bearing_solver, CAM, BOARD, folds=5)
    assert len(cv.folds) == 5 and all(f.failure is None for f in cv.folds)
    s = cv.summary()
    # held out is a little worse (the fit did not see the frame), not a lot: 0.1 px is 0.45 mrad here
    assert (
        s["in_sample_corner_mrad_mean"]
        <= s["held_out_corner_mrad_mean"]
        < 2 * s["in_sample_corner_mrad_mean"]
    )
    assert s["held_out_corner_mrad_mean"] < 1.0
    assert s["held_out_intensity_mrad_mean"] < 0.5


def test_frames_vs_accuracy_records_failures_and_converges_to_the_truth() -> None:
    rng = np.random.default_rng(12)
    frames = frame_results(rng)
    curve = frames_vs_accuracy(frames, bearing_solver, CAM, BOARD, T_ground_truth=T_TRUE)
    assert curve.failures and curve.failures[0][0] == 1 and "two frames" in curve.failures[0][1]
    assert curve.n_frames.tolist() == list(range(2, len(frames) + 1))
    assert curve.reference == "ground truth"
    assert np.all(curve.sigma[-1] <= curve.sigma[0] + 1e-12)  # more frames, smaller sigmas
    assert np.all(np.abs(curve.offset[-1]) < 5 * curve.sigma[-1] + 1e-9)
    assert np.isnan(curve.heldout_mean[-1]) and np.isfinite(curve.heldout_mean[0])
    assert curve.error_mean[-1] < 1.0
    with pytest.raises(ValueError):
        frames_vs_accuracy(frames, bearing_solver, CAM, BOARD, order=[0, 0, 1, 2, 3])


# ------------------------------------------------------------------------------ pictures
def scene_image_and_scan(rng: np.random.Generator, T_lidar_board: np.ndarray) -> tuple[np.ndarray, Scan]:
    """A small picture with the board painted in, and a scan of the board plus a wall behind it."""
    img = np.full((CAM.height, CAM.width, 3), 120, np.uint8)
    xs, ys = np.meshgrid(np.linspace(*BOARD.extent()[:2], 90), np.linspace(*BOARD.extent()[2:], 70))
    q = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    uv = CAM.project(transform_points(T_TRUE @ T_lidar_board, q))
    col = (255 * BOARD.colour_at(q)).astype(np.uint8)
    ok = np.all(np.isfinite(uv), axis=1)
    ij = np.round(uv[ok]).astype(int)
    m = (ij[:, 0] >= 0) & (ij[:, 0] < CAM.width) & (ij[:, 1] >= 0) & (ij[:, 1] < CAM.height)
    img[ij[m, 1], ij[m, 0]] = col[ok][m][:, None]
    az, el = np.meshgrid(np.radians(np.linspace(-30, 30, 200)), np.radians(np.linspace(-15, 15, 16)))
    d = np.column_stack(
        [np.cos(el.ravel()) * np.cos(az.ravel()), np.cos(el.ravel()) * np.sin(az.ravel()), np.sin(el.ravel())]
    )
    wall = d * (8.0 / d[:, :1])  # a wall at x = 8 m
    x0, x1, y0, y1 = BOARD.extent()
    bq = np.column_stack([rng.uniform(x0, x1, 500), rng.uniform(y0, y1, 500), np.zeros(500)])
    board_pts = transform_points(T_lidar_board, bq)
    pts = np.vstack([wall, board_pts])
    inten = np.concatenate([np.full(len(wall), 40.0), np.where(BOARD.colour_at(bq) > 0.5, 80.0, 8.0)])
    return cv2.GaussianBlur(img, (3, 3), 0), Scan(pts, inten)


def test_points_behind_the_board_are_hidden_and_coloured_clouds_mark_them() -> None:
    rng = np.random.default_rng(13)
    T_lb = board_pose_facing(np.array([3.0, 0.0, 0.0]), 0.0)
    image, scan = scene_image_and_scan(rng, T_lb)
    vis = visible_points(scan.points, CAM, T_TRUE, T_lb, BOARD)
    n_wall = len(scan) - 500
    # wall points whose camera ray crosses the board are hidden; board points are not
    q = transform_points(np.linalg.inv(T_TRUE @ T_lb), np.zeros((1, 3)))  # camera centre, board frame
    assert not vis.occluded[n_wall:].any()
    hidden = vis.occluded[:n_wall]
    assert hidden.sum() > 50 and vis.in_image[:n_wall].sum() > hidden.sum()
    d = scan.points[:n_wall][hidden] - transform_points(np.linalg.inv(T_TRUE), np.zeros((1, 3)))
    assert np.all(d[:, 0] > 2.5) and q[0, 2] > 0  # hidden ones are behind the board, camera in front
    cp = colour_points(scan, image, CAM, T_TRUE, T_lb, BOARD)
    assert cp.rgb.shape == (len(scan), 3) and cp.rgb.dtype == np.uint8
    assert np.all(cp.rgb[:n_wall][hidden] == OCCLUDED_RGB)
    b = cp.rgb[n_wall:][vis.in_image[n_wall:]]
    white = (
        BOARD.colour_at(transform_points(np.linalg.inv(T_lb), scan.points[n_wall:]))[vis.in_image[n_wall:]]
        > 0.5
    )
    assert b[white].mean() > b[~white].mean() + 60  # board points take the board's printed colour


def test_draw_corners_keeps_its_signature() -> None:
    img = np.zeros((300, 400, 3), np.uint8)
    uv = np.array([[100.0, 100.0], [150.0, 110.0], [200.0, 120.0]])
    out = draw_corners(img, uv)
    assert out.ndim == 3 and out.shape[0] <= 300 and out.any()
    assert draw_corners(img, uv, crop=False).shape == img.shape


def test_report_is_self_contained_and_has_the_table() -> None:
    rng = np.random.default_rng(14)
    frames = frame_results(rng)[:3]
    T_est, cov = bearing_solver(frames)
    dropped = FrameResult("0009", False, "LiDAR: no segment passes the chessboard tests")
    cal = Calibration(T_est, cov, tuple(frames) + (dropped,))
    srcs = []
    for f in frames:
        image, scan = scene_image_and_scan(rng, f.board.T_lidar_board)
        srcs.append((f.name, scan, image))
    written: list[str] = []
    files = build_report(
        cal, CAM, BOARD, iter(srcs), T_ground_truth=T_TRUE, on_frame=lambda ff, scan: written.append(ff.name)
    )
    assert written == [f.name for f in frames]
    page = files["index.html"].decode("utf-8")
    refs = set(re.findall(r'(?:src|href)="([^"#][^"]*)"', page))
    assert refs and refs <= set(files), refs - set(files)
    anchors = set(re.findall(r'href="#([^"]+)"', page))
    assert anchors and all(f'id="{a}"' in page for a in anchors)
    assert not re.search(r"(?:src|href)=\"(?:https?:|//)", page)  # offline
    for name in ("0001", "0002", "0003"):
        assert f'<td class="l"><a href="#f{name}">{name}</a></td>' in page
    assert '<td class="l">0009</td>' in page  # no pictures for it: no link
    assert "no segment passes the chessboard tests" in page and "Against the ground truth" in page
    assert "<table>" in page and "T_cam_lidar" in page
    for path, data in files.items():
        if path.endswith(".png"):
            assert data[:8] == b"\x89PNG\r\n\x1a\n"
            assert path.startswith("figures/")
        if path.endswith(".webp"):
            assert data[:4] == b"RIFF" and data[8:12] == b"WEBP"
            assert path.startswith("figures/")
    assert {
        "figures/0001_corners.webp",
        "figures/0001_range.webp",
        "figures/0001_edges.webp",
        "figures/0001_metric.webp",
        "figures/0001_whole.webp",
        "figures/per_frame.png",
        "figures/valley.png",
    } <= set(files)


def test_report_of_a_calibration_file_rebuilds_the_board_points_from_the_scans(tmp_path) -> None:
    from ilcc_graph.io import read_calibration, write_calibration

    rng = np.random.default_rng(15)
    frames = frame_results(rng)[:3]
    T_est, cov = bearing_solver(frames)
    write_calibration(tmp_path / "calibration.yaml", Calibration(T_est, cov, tuple(frames)))
    cal = read_calibration(tmp_path / "calibration.yaml")
    assert all(len(f.board.points_lidar) == 0 for f in cal.frames)  # the file keeps no segments
    srcs = []
    for f in frames:
        image, scan = scene_image_and_scan(rng, f.board.T_lidar_board)
        srcs.append((f.name, scan, image))
    files = build_report(cal, CAM, BOARD, iter(srcs), show_valley=False)
    assert "figures/0001_metric.webp" in files
    page = files["index.html"].decode("utf-8")
    m = re.search(r"intensity error \(mrad\)</td><td>([0-9.]+)</td>", page)
    assert m is not None and float(m.group(1)) < 0.5, page[:2000]


def test_evaluate_calibration_judges_another_extrinsic_on_the_same_frames(tmp_path) -> None:
    from ilcc_graph.evaluation import evaluate_calibration, evaluation_rows, evaluation_to_dict
    from ilcc_graph.io import read_calibration, write_calibration

    rng = np.random.default_rng(16)
    frames = frame_results(rng)[:3]
    write_calibration(tmp_path / "c.yaml", Calibration(T_TRUE, np.eye(6) * 1e-8, tuple(frames)))
    cal = read_calibration(tmp_path / "c.yaml")
    scans = [(f.name, scene_image_and_scan(rng, f.board.T_lidar_board)[1]) for f in frames]
    good = evaluate_calibration(cal, CAM, BOARD, iter(scans))
    bad = evaluate_calibration(
        cal, CAM, BOARD, iter(scans), T_cam_lidar=pose([0, 1.0, 0], [0, 0, 0]) @ T_TRUE
    )
    assert [e.name for e in good.frames] == [f.name for f in frames]
    assert good.intensity_mrad[0] < 0.5 and bad.intensity_mrad[0] > 5 * good.intensity_mrad[0]
    header, rows = evaluation_rows(good)
    assert len(rows) == len(frames) + 2 and rows[-2][0] == "mean" and len(header) == len(rows[0])
    d = evaluation_to_dict(good)
    assert d["overall"]["frames"] == 3.0 and d["frames"][0]["name"] == "0001"


def test_panorama_crop_wraps_across_the_seam() -> None:
    from ilcc_graph.cameras import Equirectangular
    from ilcc_graph.report.overlays import crop_around

    cam = Equirectangular(400, 200)
    img = np.zeros((200, 400, 3), np.uint8)
    img[:, :200] = (0, 0, 255)  # left half red, right half blue
    img[:, 200:] = (255, 0, 0)
    uv = np.array([[390.0, 100.0], [395.0, 110.0], [5.0, 100.0], [10.0, 90.0]])  # straddles u = 0
    crop = crop_around(img, uv, cam, pad=0.5, min_size=10)
    w = crop.image.shape[1]
    assert w < 100  # not the whole width
    inside = crop.to_crop(uv)
    assert np.all((inside[:, 0] >= 0) & (inside[:, 0] < w))
    assert crop.image[0, 0, 0] == 255 and crop.image[0, -1, 2] == 255  # blue on the left, red on the right


def test_depth_map_hides_points_behind_nearer_ones() -> None:
    from ilcc_graph.cameras import Equirectangular

    cam = Equirectangular(720, 360)
    az = np.radians(np.linspace(-20, 20, 81))
    near = np.column_stack([np.cos(az), np.sin(az), np.zeros_like(az)]) * 2.0
    far = near * 5.0  # the same directions, 10 m away
    vis = visible_points(np.vstack([near, far]), cam, np.eye(4))
    assert not vis.occluded[: len(near)].any() and vis.occluded[len(near) :].all()
    lone = visible_points(far, cam, np.eye(4))
    assert not lone.occluded.any()


def test_a_frame_with_shifted_corners_is_called_out() -> None:
    import dataclasses

    rng = np.random.default_rng(17)
    frames = frame_results(rng)
    shifted = dataclasses.replace(frames[3].corners, uv=frames[3].corners.uv + [6.0, 0.0])
    frames[3] = dataclasses.replace(frames[3], corners=shifted)
    cal = Calibration(T_TRUE, np.eye(6) * 1e-8, tuple(frames))
    page = build_report(cal, CAM, BOARD, show_valley=False)["index.html"].decode("utf-8")
    verdict = page[page.index('<div class="verdict') : page.index("</div>")]
    assert "verdict bad" in verdict and "0004 stand out" in verdict, verdict
    cal_ok = Calibration(T_TRUE, np.eye(6) * 1e-8, tuple(frame_results(rng)))
    page_ok = build_report(cal_ok, CAM, BOARD, show_valley=False)
    assert "stand out" not in page_ok["index.html"].decode("utf-8")


def test_the_valley_bottoms_out_at_the_right_extrinsic() -> None:
    from ilcc_graph.evaluation import eval_frames
    from ilcc_graph.evaluation.studies import valley

    rng = np.random.default_rng(18)
    efs = eval_frames(frame_results(rng)[:3])
    v = valley(efs, CAM, BOARD, T_TRUE, rotation_deg=1.0, translation_m=0.05, n=2)
    mid = v.steps.size // 2
    assert v.steps[mid] == 0.0 and v.intensity.shape == (6, 5)
    for k in range(6):
        assert np.argmin(v.corner[k]) == mid
        assert v.intensity[k, mid] <= v.intensity[k].min() + 0.05
        assert max(v.intensity[k, 0], v.intensity[k, -1]) > 5 * v.intensity[k, mid]


def test_lidar_corners_a_square_off_are_told_apart_from_a_wrong_extrinsic() -> None:
    import dataclasses

    rng = np.random.default_rng(19)
    frames = frame_results(rng)
    b = frames[1].board
    s = BOARD.square_size
    slid = transform_points(b.T_lidar_board, BOARD.corners_board() + [s, s, 0.0])  # fit slid by a square
    frames[1] = dataclasses.replace(frames[1], board=dataclasses.replace(b, corners_lidar=slid))
    cal = Calibration(T_TRUE, np.eye(6) * 1e-8, tuple(frames))
    page = build_report(cal, CAM, BOARD, show_valley=False)["index.html"].decode("utf-8")
    row = page[page.index('<td class="l">0002</td>') :].split("</tr>")[0]
    assert "LiDAR board fit is likely off" in row, row
    others = page[page.index('<td class="l">0003</td>') :].split("</table>")[0]
    assert "likely off" not in others and "neither corners nor points" not in others


def test_crops_grow_small_boards_and_shrink_large_ones_consistently() -> None:
    from ilcc_graph.report.overlays import crop_around

    img = np.zeros((3000, 4000, 3), np.uint8)
    for uv, want in ((np.array([[1000.0, 1000.0], [1060.0, 1040.0]]), "grow"),
                     (np.array([[500.0, 500.0], [3500.0, 2500.0]]), "shrink")):  # fmt: skip
        base = crop_around(img, uv, pad=0.2, min_size=10)
        z = base.zoomed(600, 8, 1000)
        side = max(z.image.shape[:2])
        assert (z.zoom > 1 and side >= 600) if want == "grow" else (z.zoom < 1 and side <= 1000)
        # the same full-image pixel lands on the same content in both
        p = base.to_crop(uv[:1])[0]
        q = z.to_crop(uv[:1])[0]
        np.testing.assert_allclose((q + 0.5) / z.zoom, p + 0.5, atol=1.0)
