"""The simulator: ground truth agrees with the rendered images and the LiDAR scans; switches work."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ilcc_graph.board import Board
from ilcc_graph.errors import OutputError
from ilcc_graph.io.output_folders import MARKER
from ilcc_graph.simulate import (
    RenderOptions,
    SimulationSpec,
    Systematics,
    beam_biases,
    board_placements,
    frame_scene,
    ground_truth,
    simulate_frame,
    simulate_frames,
    simulate_scan,
    standard_spec,
)


def _inv(T: np.ndarray) -> np.ndarray:
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def _apply(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ T[:3, :3].T + T[:3, 3]


def _bilinear(gray: np.ndarray, uv: np.ndarray) -> np.ndarray:
    m = uv.astype(np.float32).reshape(1, -1, 2)
    return cv2.remap(gray, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP).ravel()


# ----------------------------------------------------------------------------------- images
CAMERAS = {  # the pinhole and fisheye cases also vary the board (margin, white origin, odd size)
    "equirectangular": dict(camera="equirectangular", width=2400),
    "pinhole": dict(camera="pinhole", width=800, board=Board(6, 8, 0.075, 0.045, 0.02)),
    "fisheye": dict(camera="fisheye", width=1024, board=Board(5, 8, 0.07, 0.03, 0.03, "white")),
}


@pytest.fixture(scope="module", params=sorted(CAMERAS))
def rendered(request):
    spec = standard_spec(frames=20, seed=3, **CAMERAS[request.param])
    # three frames spread over the directions and distances (near, middle, far)
    frames = list(simulate_frames(spec, frames=[0, 9, 19]))
    return spec, frames


def test_true_corners_land_on_rendered_corners(rendered):
    """cornerSubPix, started 1.3 px off, converges onto the projection of the true corners."""
    spec, frames = rendered
    cam, board = spec.camera, spec.board
    for f in frames:
        gray = cv2.cvtColor(f.image, cv2.COLOR_BGR2GRAY)
        uv = cam.project(_apply(spec.T_cam_lidar @ f.T_lidar_board, board.corners_board()))
        assert np.all(np.isfinite(uv)) and np.all(cam.in_image(uv)), f.name
        start = (uv + [1.0, -0.8]).astype(np.float32).reshape(-1, 1, 2)
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
        found = cv2.cornerSubPix(gray, start, (3, 3), (-1, -1), crit).reshape(-1, 2)
        err = np.linalg.norm(found - uv, axis=1)
        assert np.median(err) < 0.12, (cam.kind, f.name, np.median(err))
        assert err.max() < 0.35, (cam.kind, f.name, err.max())


def test_rendered_colours_follow_the_board_frame(rendered):
    """Around every inner corner the four squares have the colours the board frame says (no mirror)."""
    spec, frames = rendered
    cam, board = spec.camera, spec.board
    s = board.square_size
    for f in frames:
        gray = cv2.cvtColor(f.image, cv2.COLOR_BGR2GRAY).astype(np.float32)
        corners = board.corners_board()
        for dx, dy in ((1, 1), (-1, 1), (1, -1), (-1, -1)):
            q = corners + [dx * s / 3, dy * s / 3, 0.0]
            want = board.colour_at(q)
            got = _bilinear(gray, cam.project(_apply(spec.T_cam_lidar @ f.T_lidar_board, q)))
            assert np.all(got[want == 0] < 60), (cam.kind, f.name, got[want == 0].max())
            assert np.all(got[want == 1] > 130), (cam.kind, f.name, got[want == 1].min())


def test_equirectangular_projection_is_interface_formula():
    """The camera model the simulator renders with is interface.md's formula (guards the convention)."""
    spec = standard_spec(width=2400, frames=1)
    p = np.random.default_rng(0).normal(size=(50, 3))
    W, H = spec.camera.width, spec.camera.height
    az, el = np.arctan2(p[:, 1], p[:, 0]), np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))
    uv = np.column_stack([W * (0.5 - az / (2 * np.pi)) - 0.5, H * (0.5 - el / np.pi) - 0.5])
    np.testing.assert_allclose(spec.camera.project(p), uv, atol=1e-9)


def test_image_options_change_the_image():
    spec = standard_spec(width=600, frames=2, image=RenderOptions(noise_sigma=0.0, blur_sigma_px=0.0))
    clean = simulate_frame(spec, 1).image
    noisy = simulate_frame(spec.with_(image=RenderOptions(noise_sigma=3.0, blur_sigma_px=0.0)), 1).image
    d = noisy.astype(float) - clean.astype(float)
    assert 2.5 < d.std() < 3.5
    assert clean.dtype == np.uint8 and clean.shape == (300, 600, 3)


# ------------------------------------------------------------------------------------ LiDAR
def _scan(spec: SimulationSpec, i: int = 0):
    T = board_placements(spec)[i]
    return simulate_scan(spec, frame_scene(spec, T, i), i), T


def _board_frame(scan, T):
    return _apply(_inv(T), scan.points)


def _dist_to_colour_edge(board: Board, xy: np.ndarray) -> np.ndarray:
    s = board.square_size
    fx, fy = np.mod(xy[:, 0], s), np.mod(xy[:, 1], s)
    return np.minimum.reduce([fx, s - fx, fy, s - fy])


def test_lidar_intensity_follows_the_pattern():
    spec = standard_spec(width=400, frames=20, seed=1)
    board = spec.board
    w, h = board.pattern_size_m
    for i in (0, 7, 19):
        scan, T = _scan(spec, i)
        q = _board_frame(scan, T)
        on = (np.abs(q[:, 2]) < 0.05) & (q[:, 0] > 0) & (q[:, 0] < w) & (q[:, 1] > 0) & (q[:, 1] < h)
        clear = on & (_dist_to_colour_edge(board, q[:, :2]) > 0.015)
        c = board.colour_at(q[clear, :2])
        inten = scan.intensity[clear]
        assert (c == 0).sum() > 20 and (c == 1).sum() > 20, i
        assert np.mean(inten[c == 0] < 25) > 0.99 and np.mean(inten[c == 1] > 55) > 0.99, i


def test_lidar_footprint_blends_at_colour_edges():
    spec = standard_spec(width=400, frames=20, noise_scale=0.0, systematics=Systematics.off())
    board = spec.board
    w, h = board.pattern_size_m
    near, clear = [], []
    for i in range(4):
        scan, T = _scan(spec, i)
        q = _board_frame(scan, T)
        on = (q[:, 0] > 0.01) & (q[:, 0] < w - 0.01) & (q[:, 1] > 0.01) & (q[:, 1] < h - 0.01)
        on &= np.abs(q[:, 2]) < 1e-9
        d = _dist_to_colour_edge(board, q[:, :2])
        near.append(scan.intensity[on & (d < 0.0015)])
        clear.append(scan.intensity[on & (d > 0.015)])
    near_i, clear_i = np.concatenate(near), np.concatenate(clear)
    mixed = (near_i > 25) & (near_i < 60)
    assert near_i.size > 20 and mixed.mean() > 0.6
    assert np.mean((clear_i > 25) & (clear_i < 60)) < 0.01


def test_noise_free_board_points_lie_on_the_board_and_noise_has_its_sigmas():
    base = standard_spec(width=400, frames=20, seed=2, noise_scale=0.0, systematics=Systematics.off())
    exact, T = _scan(base, 4)
    noisy, _ = _scan(base.with_(noise_scale=1.0), 4)
    assert len(exact) == len(noisy)
    q0, q1 = _board_frame(exact, T), _board_frame(noisy, T)
    board = base.board
    x0, x1, y0, y1 = board.extent()
    on = (np.abs(q0[:, 2]) < 1e-9) & (q0[:, 0] > x0) & (q0[:, 0] < x1) & (q0[:, 1] > y0) & (q0[:, 1] < y1)
    assert on.sum() > 300
    sd = (q1[on] - q0[on]).std(axis=0)
    np.testing.assert_allclose(sd, [0.0016, 0.0016, 0.010], rtol=0.15)
    # off the board: noise along the beam with the model's range sigma
    off = ~on
    dr = np.linalg.norm(noisy.points[off], axis=1) - np.linalg.norm(exact.points[off], axis=1)
    assert abs(dr.std() - base.lidar_model.range_sigma_m) < 0.1 * base.lidar_model.range_sigma_m

    # range noise (``range_noise_m``): every return moved along its own beam by that sigma, the board's too
    ranged, _ = _scan(base.with_(range_noise_m=0.03), 4)
    dr = np.linalg.norm(ranged.points, axis=1) - np.linalg.norm(exact.points, axis=1)
    assert abs(dr[on].std() - 0.03) < 0.003 and abs(dr[off].std() - 0.03) < 0.003
    u0 = exact.points / np.linalg.norm(exact.points, axis=1)[:, None]
    u1 = ranged.points / np.linalg.norm(ranged.points, axis=1)[:, None]
    assert np.abs(u1 - u0).max() < 1e-9  # the beams' directions exact
    with pytest.raises(ValueError, match="range_noise_m"):
        base.with_(range_noise_m=-0.01)


def test_rings_and_scan_order():
    spec = standard_spec(width=400, frames=20, noise_scale=0.0, systematics=Systematics.off())
    scan, _ = _scan(spec, 0)
    model = spec.lidar_model
    n_az = round(360 / model.horizontal_resolution_deg)
    assert len(scan) == n_az * model.n_beams  # closed room: every beam returns
    np.testing.assert_array_equal(scan.ring, np.tile(np.arange(model.n_beams), n_az))
    np.testing.assert_array_equal(scan.ring, model.ring_from_points(scan.points))
    az = np.arctan2(scan.points[scan.ring == 5, 1], scan.points[scan.ring == 5, 0])
    step = np.mod(np.diff(az) + np.pi, 2 * np.pi) - np.pi
    np.testing.assert_allclose(step, -2 * np.pi / n_az, atol=1e-9)  # clockwise seen from above
    noisy, _ = _scan(standard_spec(width=400, frames=20), 0)
    assert np.mean(noisy.ring == model.ring_from_points(noisy.points)) > 0.995
    assert noisy.ring.dtype == np.int32


def test_systematic_switches_change_what_they_should():
    off = standard_spec(width=400, frames=20, seed=5, systematics=Systematics.off())
    ref, T = _scan(off, 2)

    def along_beam(scan):  # signed length of the change along the beam (beams are ~ p / |p|)
        dp = scan.points - ref.points
        return np.linalg.norm(dp, axis=1) * np.sign(np.einsum("ij,ij->i", dp, ref.points))

    bias = off.with_(systematics=Systematics(0.003, 0, 0, 0, 0))
    s, _ = _scan(bias, 2)
    b = beam_biases(bias)
    assert np.abs(b).max() > 0.001
    np.testing.assert_allclose(along_beam(s), b[s.ring], atol=1e-12)

    shift = off.with_(systematics=Systematics(0, 0, 0, 0, 0.02))
    s, _ = _scan(shift, 2)
    np.testing.assert_allclose(along_beam(s), 0.02, atol=1e-12)

    dark = off.with_(systematics=Systematics(0, 0.004, 0, 0, 0))
    s, _ = _scan(dark, 2)
    dr = along_beam(s)
    q = _board_frame(ref, T)
    w, h = off.board.pattern_size_m
    inside = (np.abs(q[:, 2]) < 0.05) & (q[:, 0] > 0) & (q[:, 0] < w) & (q[:, 1] > 0) & (q[:, 1] < h)
    clear = inside & (_dist_to_colour_edge(off.board, q[:, :2]) > 0.015)
    c = off.board.colour_at(q[:, :2])
    np.testing.assert_allclose(dr[clear & (c == 0)], 0.004, atol=1e-12)
    np.testing.assert_allclose(dr[clear & (c == 1)], 0.0, atol=1e-12)
    np.testing.assert_allclose(dr[~inside & (np.abs(q[:, 2]) > 0.2)], 0.0, atol=1e-12)

    gain = off.with_(systematics=Systematics(0, 0, 0, 0, 0, 0.05))
    s, _ = _scan(gain, 2)
    np.testing.assert_array_equal(s.points, ref.points)
    ratio = np.array([np.median(s.intensity[ref.ring == k] / np.maximum(ref.intensity[ref.ring == k], 1))
                      for k in range(32)])  # fmt: skip
    assert 0.02 < np.std(ratio) < 0.08  # each beam reads brighter or darker by its own gain

    drop = off.with_(systematics=Systematics(0, 0, 0.0, 0.5, 0))
    s, _ = _scan(drop, 2)
    qs = _board_frame(s, T)

    def count(qq, colour):
        ok = (np.abs(qq[:, 2]) < 0.05) & (qq[:, 0] > 0) & (qq[:, 0] < w) & (qq[:, 1] > 0) & (qq[:, 1] < h)
        ok &= _dist_to_colour_edge(off.board, qq[:, :2]) > 0.015
        return int((off.board.colour_at(qq[ok, :2]) == colour).sum())

    assert count(qs, 1) == count(q, 1)
    assert 0.35 < count(qs, 0) / count(q, 0) < 0.65
    kept = {tuple(p) for p in s.points.tolist()}
    lost = np.array([tuple(p) not in kept for p in ref.points.tolist()])
    assert lost.sum() == len(ref) - len(s) and np.all(inside[lost])  # only the print loses points
    assert not np.any(lost & clear & (c == 1))  # ... and never clear white print


# --------------------------------------------------------------------- placements and truth
def test_default_placements_are_like_the_paper():
    spec = standard_spec(width=400, frames=20, seed=0)
    Ts = board_placements(spec)
    assert len(Ts) == 20
    c = np.array([T[:3, :3] @ spec.board.pattern_centre + T[:3, 3] for T in Ts])
    d = np.linalg.norm(c[:, :2], axis=1)
    assert d.min() > 1.1 and d.max() < 2.7
    az = np.degrees(np.arctan2(c[:, 1], c[:, 0]))
    for k in range(5):  # four boards around each of five directions 72 deg apart
        dev = np.mod(az[4 * k : 4 * k + 4] - 72 * k + 180, 360) - 180
        assert np.all(np.abs(dev) < 13)
    for T, ci in zip(Ts, c, strict=True):
        assert np.dot(T[:3, 2], -ci / np.linalg.norm(ci)) > 0.7  # faces the sensors
        np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
    spec_p = standard_spec(camera="pinhole", width=640, frames=20)
    for T in board_placements(spec_p):
        uv = spec_p.camera.project(_apply(spec_p.T_cam_lidar @ T, spec_p.board.outline()))
        assert np.all(spec_p.camera.in_image(uv))


def test_ground_truth_and_frames_agree():
    spec = standard_spec(width=400, frames=3, seed=4)
    frames = list(simulate_frames(spec))
    gt = ground_truth(spec, frames)
    assert [f.name for f in frames] == ["0001", "0002", "0003"] == list(gt["T_lidar_board"])
    np.testing.assert_allclose(gt["T_cam_lidar"], spec.T_cam_lidar)
    for f in frames:
        np.testing.assert_allclose(gt["T_lidar_board"][f.name], f.T_lidar_board)
        np.testing.assert_allclose(
            gt["corners_lidar"][f.name], _apply(f.T_lidar_board, spec.board.corners_board())
        )
    assert gt == ground_truth(spec)  # from the placements alone
    # a frame alone equals the same frame generated in sequence (independent streams)
    alone = simulate_frame(spec, 2)
    np.testing.assert_array_equal(alone.image, frames[2].image)
    np.testing.assert_array_equal(alone.scan.points, frames[2].scan.points)


def test_placements_override_and_validation():
    spec = standard_spec(width=400, frames=20)
    Ts = board_placements(spec)[:2]
    spec2 = standard_spec(width=400, placements=tuple(Ts))
    assert spec2.n_frames == 2
    np.testing.assert_array_equal(board_placements(spec2)[1], Ts[1])
    with pytest.raises(ValueError):
        standard_spec(width=400, noise_scale=-1)
    with pytest.raises(ValueError):
        Systematics(dropout=1.5)
    with pytest.raises(ValueError):
        standard_spec(width=400, placements=(np.eye(3),))


def test_same_seed_same_bytes(tmp_path):
    from ilcc_graph.simulate.write_set import simulate_dataset

    spec = standard_spec(width=400, frames=2, seed=7)
    seen = []
    a = simulate_dataset(tmp_path / "a", spec, progress=lambda k, n: seen.append((k, n)))
    b = simulate_dataset(tmp_path / "b", spec)
    c = simulate_dataset(tmp_path / "c", spec.with_(seed=8))
    assert seen == [(1, 2), (2, 2)]
    files = sorted(p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file() and p.name != MARKER)
    assert files == ["config.yaml", "ground_truth.yaml", "img/0001.png", "img/0002.png", "pcd/0001.pcd",
                     "pcd/0002.pcd"]  # fmt: skip
    for name in files:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert (a / "pcd/0001.pcd").read_bytes() != (c / "pcd/0001.pcd").read_bytes()
    assert (a / "img/0001.png").read_bytes() != (c / "img/0001.png").read_bytes()
    assert simulate_dataset(a, spec.with_(seed=8)) == a  # an earlier simulated set: replaced whole
    assert (a / "pcd/0001.pcd").read_bytes() == (c / "pcd/0001.pcd").read_bytes()
    (a / "notes.txt").write_text("mine")  # now it holds a file of the user's: refused, kept
    with pytest.raises(OutputError, match="notes.txt"):
        simulate_dataset(a, spec)
    assert (a / "notes.txt").read_text() == "mine"


def test_written_dataset_reads_back(tmp_path):
    from ilcc_graph.io import read_ground_truth, read_image, read_scan
    from ilcc_graph.simulate.write_set import simulate_dataset

    spec = standard_spec(width=400, frames=1, seed=1)
    out = simulate_dataset(tmp_path / "d", spec)
    frame = simulate_frame(spec, 0)
    scan = read_scan(out / "pcd" / "0001.pcd")
    np.testing.assert_allclose(scan.points, frame.scan.points, atol=1e-5)
    np.testing.assert_array_equal(scan.ring, frame.scan.ring)
    np.testing.assert_array_equal(read_image(out / "img" / "0001.png"), frame.image)
    gt = read_ground_truth(out)
    np.testing.assert_allclose(gt.T_lidar_board["0001"], frame.T_lidar_board)
    np.testing.assert_allclose(gt.T_cam_lidar, spec.T_cam_lidar)
    try:
        from ilcc_graph.config import load_config
    except ImportError:  # pragma: no cover - config module not there yet
        return
    cfg = load_config(out / "config.yaml")
    assert cfg.board == spec.board and cfg.camera == spec.camera and cfg.lidar == spec.lidar_model


def test_open_scene_and_camera_switch():
    from ilcc_graph.simulate import SceneOptions

    spec = standard_spec(width=400, frames=20, scene=SceneOptions(room=None, clutter=False))
    scan, T = _scan(spec, 0)
    q = _board_frame(scan, T)
    x0, x1, y0, y1 = spec.board.extent()
    e = 0.01  # in-plane noise may carry an edge point a few mm past the board
    on_board = (np.abs(q[:, 2]) < 0.05) & (q[:, 0] > x0 - e) & (q[:, 0] < x1 + e)
    on_board &= (q[:, 1] > y0 - e) & (q[:, 1] < y1 + e)
    upward = scan.ring >= np.searchsorted(spec.lidar_model.vertical_angles_deg, 0.5)
    assert upward.any() and np.all(on_board[upward])  # no walls or ceiling: only the board returns above
    pin = spec.with_(camera=standard_spec(camera="pinhole", width=320).camera)
    np.testing.assert_allclose(pin.T_cam_lidar[2, :3] @ [1.0, 0.0, 0.0], 1.0, atol=0.01)  # z_cam ~ x_lidar


def test_board_distance_option_moves_the_placements_out() -> None:
    from ilcc_graph.simulate import SceneOptions

    scene = SceneOptions(room=(-9.0, 9.0, -9.0, 9.0), ceiling_height_m=4.0, board_distance_m=(2.9, 5.0))
    spec = standard_spec("vlp16", "pinhole", frames=12, seed=1, scene=scene)
    c = spec.board.pattern_centre
    d = [np.linalg.norm(T[:3, :3] @ c + T[:3, 3]) for T in board_placements(spec)]
    assert min(d) >= 2.85 and max(d) <= 5.0 + 1.5
    with pytest.raises(ValueError, match="board_distance_m"):
        SceneOptions(board_distance_m=(3.0, 2.0))


def test_board_plane_systematic_puts_each_frames_returns_on_a_plane_off_the_print():
    """``Systematics.board_plane_sigma``: noise-free board returns lie on a plane off the board's face
    (heights ``delta + alpha x + beta y`` towards the sensor, drawn per frame); off it, the scan is the
    same as before to the bit."""
    import dataclasses

    base = standard_spec(width=400, frames=20, seed=2, noise_scale=0.0, systematics=Systematics.off())
    bent = base.with_(systematics=dataclasses.replace(Systematics.off(), board_plane_sigma=(0.005, 0.01)))
    x0, x1, y0, y1 = base.board.extent()
    fits = []
    for i in (1, 4, 9):
        flat, T = _scan(base, i)
        again, _ = _scan(base.with_(systematics=Systematics.off()), i)
        np.testing.assert_array_equal(flat.points, again.points)
        moved, _ = _scan(bent, i)
        q0, q1 = _board_frame(flat, T), _board_frame(moved, T)
        on = (np.abs(q0[:, 2]) < 1e-9) & (q0[:, 0] > x0) & (q0[:, 0] < x1) & (q0[:, 1] > y0) & (q0[:, 1] < y1)
        assert on.sum() > 300 and np.allclose(q1[~on], q0[~on])
        A = np.column_stack([np.ones(on.sum()), q0[on, 0], q0[on, 1]])  # at where each ray hit the print
        coef, *_ = np.linalg.lstsq(A, q1[on, 2], rcond=None)
        assert np.abs(q1[on, 2] - A @ coef).max() < 1e-9  # a plane
        fits.append(coef)
    fits = np.array(fits)
    assert np.all(np.abs(fits[:, 0]) < 0.03) and np.ptp(fits[:, 0]) > 1e-3  # offsets differ by frame
    assert np.all(np.abs(fits[:, 1:]) < 0.05) and np.ptp(fits[:, 1]) > 1e-3


def test_unit_seed_keeps_the_sensors_own_errors_across_captures():
    """``unit_seed`` draws the sensors' own errors (beam biases and gains, the stated intrinsics), so
    two captures of one rig share them and differ in everything else; unset, it is ``seed``."""
    from ilcc_graph.simulate import IntrinsicsError, beam_gains, stated_camera
    from ilcc_graph.simulate.rig_spec import ring_rig

    err = IntrinsicsError.typical()
    a = standard_spec(camera="fisheye", width=400, frames=2, seed=3, intrinsics_error=err)
    b = a.with_(seed=4, unit_seed=3)
    assert a.units_seed == 3 and "unit_seed" not in ground_truth(a)["simulation"]
    assert ground_truth(b)["simulation"]["unit_seed"] == 3
    np.testing.assert_array_equal(beam_biases(a), beam_biases(b))
    np.testing.assert_array_equal(beam_gains(a), beam_gains(b))
    assert stated_camera(a.camera, err, a.units_seed) == stated_camera(b.camera, err, b.units_seed)
    assert not np.array_equal(beam_biases(a), beam_biases(a.with_(seed=4)))
    assert not np.array_equal(board_placements(a)[0], board_placements(b)[0])
    with pytest.raises(ValueError, match="seeds"):
        a.with_(unit_seed=-1)
    rig = ring_rig("pinhole", 320, n_moments=2, seed=5)
    again = rig.with_(seed=6, unit_seed=5)
    for name in ("front", "lidar"):
        assert rig.sensor_spec(name).unit_seed is None  # as before unit_seed existed
        assert again.sensor_spec(name).units_seed == rig.sensor_spec(name).units_seed
        assert again.sensor_spec(name).seed != rig.sensor_spec(name).seed
