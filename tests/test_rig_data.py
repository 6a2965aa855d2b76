"""Rig data (docs/rig.md): the simulator's rigs agree with their ground truth, and the rig source gives
the same moments and arrays from a folder per sensor and from one bag."""

from __future__ import annotations

import pickle
import shutil

import numpy as np
import pytest
import yaml

from ilcc_graph.cameras import camera_class, camera_kinds
from ilcc_graph.datasets import FolderSource, RigSource, open_source
from ilcc_graph.errors import DamagedFile, InputError, OutputError
from ilcc_graph.image import detect_corners
from ilcc_graph.run.source import check_image_size
from ilcc_graph.run.stages import read_frame_file
from ilcc_graph.simulate import RenderOptions, Systematics, simulate_dataset, standard_spec
from ilcc_graph.simulate.bag import WalkAndPause
from ilcc_graph.simulate.rig_export import write_rig_bag, write_rig_set
from ilcc_graph.simulate.rig_placements import rig_placements, sees
from ilcc_graph.simulate.rig_spec import (
    RIG_PRESETS,
    Mount,
    RigSpec,
    backpack_rig,
    horizontal_fov_deg,
    ring_rig,
    simulate_moments,
)


@pytest.fixture(scope="module")
def ring(tmp_path_factory) -> dict:
    """Four pinhole cameras and an HDL-32, 4 moments; a camera writes only when it sees the board."""
    d = tmp_path_factory.mktemp("ring")
    spec = ring_rig("pinhole", 480, n_moments=4, seed=2, only_seen=True)
    moments = list(simulate_moments(spec))
    return {
        "spec": spec,
        "moments": moments,
        "folder": write_rig_set(d / "folder", spec, moments=moments),
        "ros1": write_rig_bag(d / "ros1", spec, moments=moments),
        "sqlite3": write_rig_bag(d / "sqlite3", spec, moments=moments, storage="sqlite3", image_format="png"),
    }


@pytest.fixture(scope="module")
def pack(tmp_path_factory) -> dict:
    """The backpack (VLP-16, OS1-64 turned and tipped, panorama) without noise, 4 moments."""
    spec = backpack_rig(width=1000, n_moments=4, seed=1, noise_scale=0.0, systematics=Systematics.off(),
                        image=RenderOptions(blur_sigma_px=0.0, noise_sigma=0.0))  # fmt: skip
    return {"spec": spec, "folder": write_rig_set(tmp_path_factory.mktemp("pack") / "set", spec)}


def test_folder_and_bags_give_the_same_moments_and_data(ring) -> None:
    folder = open_source(ring["folder"], rig=True)
    ref = folder.moments()
    assert [m.name for m in ref] == ["0001", "0002", "0003", "0004"]
    rig = folder.config()
    for layout in ("ros1", "sqlite3"):
        bag = open_source(ring[layout], rig=True)
        got = bag.moments()
        assert [m.sensors for m in got] == [m.sensors for m in ref], layout
        for a, b in zip(ref, got, strict=True):
            for lidar in rig.lidars:
                sa, sb = folder.read_scan(a, lidar), bag.read_scan(b, lidar)
                np.testing.assert_array_equal(sa.points, sb.points)
                np.testing.assert_array_equal(sa.intensity, sb.intensity)
                np.testing.assert_array_equal(sa.ring, sb.ring)
            for cam in a.sensors[1:]:
                np.testing.assert_array_equal(folder.read_image(a, cam), bag.read_image(b, cam))
                assert folder.image_size(a, cam) == bag.image_size(b, cam) == (480, 300)
        again = pickle.loads(pickle.dumps(bag))  # a worker process gets the source pickled
        cam = got[0].sensors[1]
        np.testing.assert_array_equal(again.read_image(got[0], cam), folder.read_image(ref[0], cam))
        ga, gb = folder.ground_truth(), bag.ground_truth()
        assert list(gb.T_ref_board) == [m.name for m in got]
        for a, b in zip(ref, got, strict=True):
            np.testing.assert_array_equal(ga.T_ref_board[a.name], gb.T_ref_board[b.name])
            assert ga.seen_by[a.name] == gb.seen_by[b.name]
        assert all(np.array_equal(ga.T_ref_sensor[n], gb.T_ref_sensor[n]) for n in rig.names)


def test_moments_hold_the_cameras_that_see_the_board_and_say_why_others_are_missing(ring) -> None:
    spec, src = ring["spec"], open_source(ring["folder"], rig=True)
    gt = src.ground_truth()
    assert gt.reference == "lidar"
    for m, sim in zip(src.moments(), ring["moments"], strict=True):
        assert set(m.sensors) == set(gt.seen_by[m.name]) == set(sim.seen_by)
        assert len(m.sensors) == 2 and m.sensors[0] == "lidar"  # a pinhole ring: one camera per board
        assert m.missing == {n: f"no file {n}/{m.name}.*" for n in spec.names if n not in m.sensors}
    bag = open_source(ring["ros1"], rig=True).moments()
    absent = next(n for n in spec.names if n not in bag[0].sensors)
    assert bag[0].missing[absent].startswith(f"no message on /{absent}/image_raw within 0.05 s (the nearest")
    for m in src.moments():
        for s in m.missing:
            with pytest.raises(InputError, match=f"moment {m.name} has no file of {s}"):
                src.read_image(m, s)


def _board_frame(points: np.ndarray, T_sensor_board: np.ndarray) -> np.ndarray:
    return (points - T_sensor_board[:3, 3]) @ T_sensor_board[:3, :3]


def test_lidar_returns_lie_on_the_true_board_in_every_lidar_frame(pack) -> None:
    src = open_source(pack["folder"], rig=True)
    gt, board = src.ground_truth(), pack["spec"].board
    x0, x1, y0, y1 = board.extent()
    counts = []
    for m in src.moments():
        for lidar in src.config().lidars:
            p = _board_frame(src.read_scan(m, lidar).points, gt.T_sensor_board(lidar, m.name))
            inside = (
                (p[:, 0] > x0 + 0.02) & (p[:, 0] < x1 - 0.02) & (p[:, 1] > y0 + 0.02) & (p[:, 1] < y1 - 0.02)
            )
            near = inside & (np.abs(p[:, 2]) < 0.05)
            if lidar in gt.seen_by[m.name]:
                counts.append(int(near.sum()))
                assert near.sum() >= 20, (m.name, lidar)
                assert np.abs(p[near, 2]).max() < 2e-5  # float32 files: on the plane to a few um
    assert len(counts) >= 6  # both LiDARs see most boards
    # a wrong frame convention would put the boards elsewhere: the OS1 in the VLP-16's frame does not fit
    m = src.moments()[0]
    p = _board_frame(src.read_scan(m, "os1").points, gt.T_sensor_board("vlp16", m.name))
    assert (np.abs(p[:, 2]) < 2e-5).sum() < 5


def test_the_panorama_sees_the_printed_squares_where_the_truth_puts_them(pack) -> None:
    src = open_source(pack["folder"], rig=True)
    gt, board, cam = src.ground_truth(), pack["spec"].board, src.config().sensor("pano").camera
    s = board.square_size
    r, c = np.meshgrid(np.arange(board.rows), np.arange(board.cols), indexing="ij")
    centres = np.column_stack([(c.ravel() + 0.5) * s, (r.ravel() + 0.5) * s, np.zeros(r.size)])
    white = board.square_colour(r.ravel(), c.ravel()) > 0.5
    for m in src.moments():
        T = gt.T_sensor_board("pano", m.name)
        uv = np.rint(cam.project(centres @ T[:3, :3].T + T[:3, 3])).astype(int)
        grey = src.read_image(m, "pano")[uv[:, 1], uv[:, 0]].mean(axis=1)
        assert grey[white].min() > grey[~white].max() + 60, m.name


def test_image_corners_project_where_the_camera_truth_says(ring) -> None:
    src, spec = open_source(ring["folder"], rig=True), ring["spec"]
    gt = src.ground_truth()
    K = spec.board.corners_board()
    worst = 0.0
    for m in src.moments():
        cam_name = m.sensors[1]
        cam = src.config().sensor(cam_name).camera
        found = detect_corners(src.read_image(m, cam_name), cam, spec.board)
        T = gt.T_sensor_board(cam_name, m.name)
        truth = cam.project(K @ T[:3, :3].T + T[:3, 3])
        err = min(
            np.abs(found.uv[perm] - truth).max()
            for perm in (np.arange(len(K)), spec.board.half_turn_permutation())
        )
        worst = max(worst, err)
    assert worst < 0.5  # px; 9 px squares, blur and noise


def test_a_pair_of_the_rig_is_a_single_pair_source(ring) -> None:
    src = open_source(ring["folder"], rig=True)
    cam = src.moments()[0].sensors[1]
    pair = src.pair(cam, "lidar")
    refs = pair.frames()
    assert [r.name for r in refs] == [m.name for m in src.moments() if m.has(cam)]
    assert {n for n, _ in pair.skipped()} == {m.name for m in src.moments() if not m.has(cam)}
    check_image_size(pair, refs, pair.config())  # the real size check passes
    np.testing.assert_array_equal(pair.read_image(refs[0]), src.read_image(refs[0].name, cam))
    gt, rig_gt = pair.ground_truth(), src.ground_truth()
    np.testing.assert_allclose(gt.T_cam_lidar, np.linalg.inv(rig_gt.T_ref_sensor[cam]), atol=1e-12)
    np.testing.assert_allclose(gt.T_lidar_board[refs[0].name], rig_gt.T_ref_board[refs[0].name], atol=1e-12)
    with pytest.raises(ValueError, match="must be a camera and"):
        src.pair("lidar", cam)


def test_a_moved_mount_moves_that_sensor_alone() -> None:
    spec = ring_rig("pinhole", 320, n_moments=2, seed=5)
    moved = spec.with_(moved=Mount("front", rotation_deg=(0.0, 0.25, 0.0), translation_mm=(10.0, 0.0, 0.0)))
    delta = np.linalg.solve(spec.T_ref_sensor()["front"], moved.T_ref_sensor()["front"])
    np.testing.assert_allclose(np.degrees(np.arccos((np.trace(delta[:3, :3]) - 1) / 2)), 0.25, atol=1e-9)
    np.testing.assert_allclose(delta[:3, 3], [0.010, 0.0, 0.0], atol=1e-12)
    for a, b in zip(simulate_moments(spec), simulate_moments(moved), strict=True):
        np.testing.assert_array_equal(a.T_body_board, b.T_body_board)  # the same boards
        np.testing.assert_array_equal(a.scans["lidar"].points, b.scans["lidar"].points)
        for n in ("left", "back", "right"):
            np.testing.assert_array_equal(a.images[n], b.images[n])
        if "front" in a.seen_by:
            assert np.abs(a.images["front"].astype(int) - b.images["front"]).max() > 50


def test_a_single_pair_data_set_opens_as_a_rig_of_two(tmp_path) -> None:
    spec = standard_spec(lidar="vlp16", camera="pinhole", width=320, frames=2, seed=3)
    data = simulate_dataset(tmp_path / "pair", spec)
    src, folder = open_source(data, rig=True), FolderSource(data)
    assert src.config().names == ("lidar", "camera")
    refs = folder.frames()
    assert [m.name for m in src.moments()] == [r.name for r in refs]
    np.testing.assert_array_equal(
        src.read_scan(refs[0].name, "lidar").points, folder.read_scan(refs[0], folder.config()).points
    )
    np.testing.assert_array_equal(src.read_image(refs[0].name, "camera"), folder.read_image(refs[0]))
    gt = src.ground_truth()
    np.testing.assert_allclose(gt.T_a_b("camera", "lidar"), spec.T_cam_lidar, atol=1e-12)
    by_file = open_source(data / "config.yaml", rig=True)  # the config file itself
    assert [m.name for m in by_file.moments()] == [r.name for r in refs]


def test_damaged_and_wrong_input_name_the_file(ring, tmp_path) -> None:
    data = shutil.copytree(ring["folder"], tmp_path / "copy")
    src = open_source(data, rig=True)
    m = src.moments()[0]
    cam = m.sensors[1]
    png = data / cam / f"{m.name}.png"
    png.write_bytes(png.read_bytes()[:100])
    with pytest.raises(DamagedFile, match=f"damaged file: {png}: cannot decode image"):
        read_frame_file(src.read_image, m, cam)
    (data / "lidar" / "notes.txt").write_text("x")
    fresh = RigSource(data)
    fresh.moments()
    assert ("notes", "lidar/notes.txt: unsupported file type '.txt'") in fresh.skipped()
    with pytest.raises(InputError, match=r"a rig data set \(several sensors, docs/rig.md\)"):
        open_source(data)
    with pytest.raises(OutputError, match="lidar/notes.txt"):  # a file of the user's in the set: kept
        write_rig_set(data, ring["spec"], moments=ring["moments"])
    # a bag whose rig file names a topic the bag does not have
    bag = shutil.copytree(ring["ros1"], tmp_path / "bag")
    d = yaml.safe_load((bag / "rig.yaml").read_text())
    d["sensors"]["left"]["topic"] = "/left/nope"
    (bag / "rig.yaml").write_text(yaml.safe_dump(d))
    topics = r".*/front/image_raw \(sensor_msgs/msg/Image\)"
    with pytest.raises(
        InputError,
        match=r"rig\.yaml: sensors\.left\.topic = '/left/nope': no such topic in .*rig\.bag; topics: "
        + topics,
    ):
        open_source(bag, rig=True).moments()


def test_a_walk_and_pause_rig_bag_gives_one_moment_per_pause(tmp_path) -> None:
    # a VLP-16 and two fisheye cameras; the board is held still 1.3 s at each of 3 placements
    full = ring_rig("fisheye", 320, lidar="vlp16", seed=4)
    spec = RigSpec(
        (full.sensor("lidar"), full.sensor("front"), full.sensor("left")), "lidar",
        (("front", "lidar"), ("front", "left", "lidar"), ("left", "lidar")), n_moments=3, seed=4,
    )  # fmt: skip
    bag = write_rig_bag(tmp_path / "walk", spec, timeline=WalkAndPause(pause_s=1.3, move_s=0.5))
    src = open_source(bag, rig=True)
    moments, gt = src.moments(), src.ground_truth()
    assert len(gt.T_ref_board) == 3 * 13 + 2 * 5  # every message time is in the truth
    assert len(moments) == 3 and len(gt.extra["pauses"]) == 3
    boards = rig_placements(spec, spec.poses())
    for m, (first, last), T in zip(moments, gt.extra["pauses"], boards, strict=True):
        assert first < m.name < last  # inside the pause, not at its ends
        np.testing.assert_allclose(gt.T_ref_board[m.name], T, atol=1e-12)  # the board as placed, still
        assert set(m.sensors) == {"lidar", "front", "left"}
    d = yaml.safe_load((bag / "rig.yaml").read_text())
    d["data"]["select"] = "all"
    (bag / "rig.yaml").write_text(yaml.safe_dump(d))
    assert len(open_source(bag, rig=True).moments()) == len(gt.T_ref_board)  # every scan with its images


def test_a_rig_set_stopped_half_way_leaves_nothing(tmp_path) -> None:
    def stop(done: int, total: int) -> None:
        raise KeyboardInterrupt

    for name, make in RIG_PRESETS.items():
        with pytest.raises(KeyboardInterrupt):
            write_rig_set(tmp_path / name, make(width=160, n_moments=2), progress=stop)
    assert list(tmp_path.iterdir()) == []


def test_a_single_pair_set_seen_as_a_rig_calibrates_to_todays_result(tmp_path) -> None:
    from ilcc_graph.run.pipeline import run

    spec = standard_spec(lidar="hdl32", camera="pinhole", width=800, frames=6, seed=5)
    data = simulate_dataset(tmp_path / "pair", spec)
    base = run([FolderSource(data)]).calibration
    cal = run([open_source(data, rig=True).pair("camera", "lidar")]).calibration
    assert sum(f.used for f in base.frames) == 6
    assert [(f.name, f.used) for f in cal.frames] == [(f.name, f.used) for f in base.frames]
    np.testing.assert_array_equal(cal.T_cam_lidar, base.T_cam_lidar)
    np.testing.assert_array_equal(cal.covariance, base.covariance)


@pytest.mark.parametrize("kind", [k for k in camera_kinds() if not camera_class(k).periodic_u])
def test_each_board_is_seen_whole_by_its_views_cameras_alone(kind) -> None:
    spec = ring_rig(kind, 320, n_moments=8, seed=6)
    poses = spec.poses()
    shared: dict[frozenset, int] = {}
    for i, T in enumerate(rig_placements(spec, poses)):
        view = set(spec.views[i % len(spec.views)])
        seeing = {n for n in spec.names if sees(spec.sensor(n), poses[n], T, spec)}
        assert seeing == view, (i, seeing, view)
        cams = frozenset(view - {"lidar"})
        shared[cams] = shared.get(cams, 0) + 1
    pairs = {tuple(sorted(c)): n for c, n in shared.items() if len(c) == 2}
    wide = horizontal_fov_deg(spec.sensor("front").camera) > 100
    assert pairs == (
        {("front", "left"): 2, ("back", "left"): 1} if wide else {}
    )  # back+right, right+front: none
