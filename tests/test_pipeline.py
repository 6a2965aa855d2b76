"""pipeline.solve_observed on synthetic observations: ordering, outliers, too few frames, both refinements."""

from __future__ import annotations

import dataclasses
import logging

import gtsam
import numpy as np
import pytest

from ilcc_graph.config import parse_config
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.run.pipeline import solve_observed
from ilcc_graph.run.result import RunOptions
from ilcc_graph.types import BoardFit, FrameResult, ImageCorners

CONFIG = {
    "board": {"squares": [6, 8], "square_size": 0.075, "margin": 0.0, "lower_left": "black"},
    "lidar": {"model": "hdl32"},
    "camera": {"model": "equirectangular", "width": 8000, "height": 4000},
}
T_TRUE = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.02, -0.03, 0.05), np.array([0.05, -0.03, 0.25])).matrix()
SIGMA_PX = 0.3


def _board_pose(rng: np.random.Generator, azimuth: float, board) -> np.ndarray:
    """A board 1.5-2.5 m away at ``azimuth``, facing the sensor, turned ~45 deg in its plane."""
    d = rng.uniform(1.5, 2.5)
    centre = np.array([d * np.cos(azimuth), d * np.sin(azimuth), rng.uniform(-0.3, 0.3)])
    z = -centre / np.linalg.norm(centre)  # board normal towards the LiDAR
    x = np.cross([0, 0, 1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z]) @ gtsam.Rot3.Rz(np.pi / 4 + rng.normal(0, 0.2)).matrix()
    R = gtsam.Rot3(R).compose(gtsam.Rot3.RzRyRx(*rng.normal(0, 0.15, 3))).matrix()
    w, h = board.pattern_size_m
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre - R @ np.array([w / 2, h / 2, 0.0])
    return T


def _frames(n: int, seed: int = 0, flip_every: int = 2):
    cfg = parse_config(CONFIG)
    board, camera = cfg.board, cfg.camera
    rng = np.random.default_rng(seed)
    perm = board.half_turn_permutation()
    frames = []
    for i in range(n):
        T_lb = _board_pose(rng, 2 * np.pi * i / n, board)
        cov_board = np.diag([1e-6, 1e-6, 4e-6, 4e-6, 4e-6, 1e-6])
        noisy = gtsam.Pose3(T_lb).compose(gtsam.Pose3.Expmap(rng.multivariate_normal(np.zeros(6), cov_board)))
        corners_lidar = board.corners_board() @ noisy.rotation().matrix().T + noisy.translation()
        p_cam = (T_TRUE @ T_lb)[:3, :3] @ board.corners_board().T + (T_TRUE @ T_lb)[:3, 3:4]
        uv = camera.project(p_cam.T) + rng.normal(0, SIGMA_PX, (board.n_corners, 2))
        if flip_every and i % flip_every == 1:
            uv = uv[perm]
        cov_px = np.tile(np.eye(2) * SIGMA_PX**2, (board.n_corners, 1, 1))
        ones = np.ones(len(corners_lidar))
        fit = BoardFit(noisy.matrix(), cov_board, corners_lidar, corners_lidar, ones, True)
        corners = ImageCorners(uv, camera.bearing(uv), cov_px, True)
        frames.append(FrameResult(name=f"{i:04d}", used=True, board=fit, corners=corners))
    return cfg, frames


def _errors(T: np.ndarray) -> tuple[float, float]:
    dR = T[:3, :3].T @ T_TRUE[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
    return float(angle), float(1e3 * np.linalg.norm(T[:3, 3] - T_TRUE[:3, 3]))


def test_recovers_truth_with_half_turned_frames():
    cfg, frames = _frames(10)
    cal = solve_observed(frames, cfg)
    rot, trans = _errors(cal.T_cam_lidar)
    assert rot < 0.05 and trans < 5
    assert all(f.used for f in cal.frames)
    assert np.all(np.linalg.eigvalsh(cal.covariance) > 0)
    xi = gtsam.Pose3.Logmap(gtsam.Pose3(cal.T_cam_lidar).between(gtsam.Pose3(T_TRUE)))
    assert xi @ np.linalg.solve(cal.covariance, xi) < 30  # chi-square(6) far tail
    assert all(f.rms_bearing_error_mrad < 1.0 for f in cal.frames)


def test_paper_refinement_has_no_covariance():
    cfg, frames = _frames(8, seed=1)
    cal = solve_observed(frames, cfg, RunOptions(mode="paper"))
    rot, trans = _errors(cal.T_cam_lidar)
    assert rot < 0.1 and trans < 10
    assert np.all(np.isnan(cal.covariance))
    assert cal.method == "paper"


def test_outlier_frame_is_dropped_with_reason():
    cfg, frames = _frames(10, seed=2)
    bad = frames[3]
    shifted = bad.corners.uv + np.array([40.0, -25.0])  # ~2 deg off in the panorama
    frames[3] = dataclasses.replace(
        bad, corners=dataclasses.replace(bad.corners, uv=shifted, bearings=cfg.camera.bearing(shifted))
    )
    cal = solve_observed(frames, cfg)
    dropped = {f.name: f.reason for f in cal.frames if not f.used}
    assert list(dropped) == ["0003"] and dropped["0003"]
    rot, trans = _errors(cal.T_cam_lidar)
    assert rot < 0.05 and trans < 5


def test_frames_without_observations_are_reported_not_used():
    cfg, frames = _frames(6, seed=3)
    frames[0] = FrameResult(name=frames[0].name, used=False, reason="LiDAR: no board")
    cal = solve_observed(frames, cfg)
    assert [f.used for f in cal.frames] == [False] + [True] * 5
    assert cal.frames[0].reason == "LiDAR: no board"


def test_few_frames_warn_and_none_is_impossible(caplog):
    cfg, frames = _frames(3, seed=4, flip_every=0)
    with caplog.at_level(logging.WARNING):
        cal = solve_observed(frames, cfg)
    assert sum(f.used for f in cal.frames) == 3
    assert any("frame" in r.message for r in caplog.records if r.levelno >= logging.WARNING)
    with pytest.raises(CalibrationImpossible):
        solve_observed([FrameResult(name="0001", used=False, reason="image: no board")], cfg)


def test_print_colour_is_taken_from_the_images(tmp_path, caplog):
    """A half-turn symmetric board whose config names the wrong lower-left colour is corrected."""
    import yaml

    from ilcc_graph.config import load_config
    from ilcc_graph.datasets import FolderSource
    from ilcc_graph.run.colour import check_board_colour
    from ilcc_graph.simulate import simulate_dataset, standard_spec

    data = simulate_dataset(tmp_path / "sim", standard_spec(camera="pinhole", width=960, frames=3, seed=2))
    cfg = yaml.safe_load((data / "config.yaml").read_text())
    assert cfg["board"]["lower_left"] == "black"
    right = load_config(data / "config.yaml")
    source = FolderSource(data)
    frames = source.frames()
    assert check_board_colour(source, frames, right)[0] == right
    cfg["board"]["lower_left"] = "white"
    (data / "config.yaml").write_text(yaml.safe_dump(cfg))
    wrong = load_config(data / "config.yaml")
    with caplog.at_level(logging.WARNING):
        fixed, known = check_board_colour(source, frames, wrong)
    assert known == {}  # the image results of the wrong colour are not kept
    assert fixed.board.lower_left == "black"
    assert "lower_left is white" in caplog.text


def test_recorded_board_print_is_white_at_lower_left(acfr_data):
    from ilcc_graph.config import load_config
    from ilcc_graph.datasets import FolderSource
    from ilcc_graph.run.colour import check_board_colour

    config = load_config(acfr_data / "config.yaml")
    source = FolderSource(acfr_data)
    frames = source.frames()
    assert config.board.lower_left == "white"  # as shipped
    same, known = check_board_colour(source, frames[:4], config)
    assert same == config and len(known) >= 2  # computed once, reused by the run
    wrong = dataclasses.replace(config, board=dataclasses.replace(config.board, lower_left="black"))
    assert check_board_colour(source, frames[:4], wrong)[0].board.lower_left == "white"


def test_repeated_board_poses_are_one_observation():
    cfg, frames = _frames(6, seed=5, flip_every=0)
    again = [dataclasses.replace(frames[2], name="0002b"), dataclasses.replace(frames[4], name="0004b")]
    cal = solve_observed(frames + again, cfg)
    by = {f.name: f for f in cal.frames}
    assert not by["0002b"].used and "same board pose as 0002" in by["0002b"].reason
    assert not by["0004b"].used and "same board pose as 0004" in by["0004b"].reason
    assert sum(f.used for f in cal.frames) == 6


def test_too_few_distinct_poses_is_impossible_and_says_what_to_capture():
    cfg, frames = _frames(6, seed=6, flip_every=0)
    copies = [dataclasses.replace(frames[k % 2], name=f"c{k}") for k in range(6)]
    with pytest.raises(CalibrationImpossible, match=r"only 2 distinct board pose\(s\)") as exc:
        solve_observed(copies, cfg)
    assert "capture the board" in exc.value.advice
    assert len(str(exc.value)) < 200
    rows = {f: why for f, stage, why in exc.value.frames if stage == "geometry"}
    assert sorted(rows) == sorted(c.name for c in copies) and rows["c2"] == "same board pose as c0"


def test_parallel_normals_are_said():
    """Boards moved side by side, never tilted: allowed (the intensity fit fixes them in-plane), with
    a warning that a LiDAR range error would move the extrinsic along their common normal."""
    from ilcc_graph.estimation.geometry import board_geometry
    from ilcc_graph.types import GraphFrame

    cfg, frames = _frames(3, seed=7, flip_every=0)
    f0 = frames[0]
    moved = []
    for k, shift in enumerate(([0, 0, 0], [0.0, 0.4, 0], [0.0, -0.4, 0.3], [0.3, 0.2, -0.3])):
        T = f0.board.T_lidar_board.copy()
        T[:3, 3] += shift
        c = f0.corners
        moved.append(
            GraphFrame(f"m{k}", T, f0.board.covariance, cfg.board.corners_board(), c.bearings, c.cov_px)
        )
    g = board_geometry(moved)
    assert len(g.groups) == 4 and g.ok and "range error" in g.parallel
    around = [GraphFrame(f.name, f.board.T_lidar_board, f.board.covariance, cfg.board.corners_board(),
                         f.corners.bearings, f.corners.cov_px) for f in frames]  # fmt: skip
    g = board_geometry(around)
    assert g.ok and g.parallel is None
