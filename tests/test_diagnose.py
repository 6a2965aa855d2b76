"""The likely cause of a dropped frame (ilcc_graph.evaluation.causes), on boards made to fail one way each."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.cameras import Pinhole
from ilcc_graph.evaluation.causes import (
    dropped_frame_cause,
    fit_image_alone,
    residual_causes,
    stated_noise_mrad,
)
from ilcc_graph.types import BoardFit, FrameResult, ImageCorners

BOARD = Board(6, 8, 0.095, 0.045, 0.02, "white")
CAMERA = Pinhole(1280, 800, np.array([[900.0, 0, 640], [0, 900.0, 400], [0, 0, 1]]))
T_CL = gtsam.Pose3(gtsam.Rot3(np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])), np.array([0.05, -0.1, 0.02]))


def frame(rng: np.random.Generator, moved_m: float = 0.0, bend_m: float = 0.0) -> FrameResult:
    """A board 2.5 m ahead; the image sees it ``moved_m`` aside and bent by ``bend_m`` (its middle)."""
    facing = gtsam.Rot3(np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]]))  # board x, y along LiDAR y, z
    tilt = gtsam.Rot3.RzRyRx(*rng.normal(0, 0.2, 3))
    T_lb = gtsam.Pose3(tilt.compose(facing), np.array([2.5, -0.3, -0.2]))
    pb = BOARD.corners_board()
    lidar = np.array([T_lb.transformFrom(p) for p in pb])
    seen = pb.copy()
    c = pb[:, :2].mean(axis=0)
    seen[:, 2] += bend_m * (
        1.0 - np.sum((pb[:, :2] - c) ** 2, axis=1) / np.max(np.sum((pb[:, :2] - c) ** 2, axis=1))
    )
    seen[:, 0] += moved_m
    p_cam = np.array([T_CL.transformFrom(T_lb.transformFrom(p)) for p in seen])
    uv = CAMERA.project(p_cam) + rng.normal(0, 0.1, (len(pb), 2))
    bearings = CAMERA.bearing(uv)
    board = BoardFit(T_lb.matrix(), np.eye(6) * 1e-6, lidar, lidar, np.zeros(len(lidar)), True)
    corners = ImageCorners(uv, bearings, np.tile(np.eye(2) * 0.01, (len(pb), 1, 1)), True)
    return FrameResult("f", False, None, board, corners)


def test_image_alone_fits_a_flat_board_to_its_noise() -> None:
    rng = np.random.default_rng(0)
    f = frame(rng)
    alone = fit_image_alone(f.corners.bearings, BOARD.corners_board())  # type: ignore[union-attr]
    assert 0.02 < alone.rms_mrad < 0.2  # 0.1 px at 900 px focal length: ~0.1 mrad
    gap = np.linalg.norm(
        alone.corners_cam - np.array([T_CL.transformFrom(p) for p in f.board.corners_lidar]), axis=1
    )  # type: ignore[union-attr]
    assert np.max(gap) < 0.02


def test_a_moved_board_and_a_bent_image_are_told_apart() -> None:
    rng = np.random.default_rng(1)
    typical = float(
        np.median(
            [fit_image_alone(frame(rng).corners.bearings, BOARD.corners_board()).rms_mrad for _ in range(5)]
        )
    )  # type: ignore[union-attr]
    moved = dropped_frame_cause(frame(rng, moved_m=0.05), BOARD, CAMERA, T_CL.matrix(), typical)
    assert "moved between the scan and the photo" in moved
    mm = float(moved.split(" mm (corner rms)")[0].rsplit(" ", 1)[1])
    assert 35 < mm < 65, moved
    bent = dropped_frame_cause(frame(rng, bend_m=0.01), BOARD, CAMERA, T_CL.matrix(), typical)
    assert "fit a flat board worse" in bent and "blur, a curled print" in bent


def _named(f: FrameResult, name: str) -> FrameResult:
    return dataclasses.replace(f, name=name, used=True)


def test_residual_causes_name_moved_boards_and_images_off_the_lens_model() -> None:
    """Over all frames (``residual_causes``): clean frames show no cause; two boards moved 50 mm
    between scan and photo are named as synchronisation (the rest are not); images bent 1 cm (their
    corners 0.1 px noise, stated as such) are named as the camera's intrinsics or lens model."""
    rng = np.random.default_rng(2)
    clean = [_named(frame(rng), f"c{i}") for i in range(5)]
    T = T_CL.matrix()
    assert residual_causes(clean, BOARD, CAMERA, T) == []
    moved = clean[:3] + [_named(frame(rng, moved_m=0.05), f"m{i}") for i in range(2)]
    (sync,) = residual_causes(moved, BOARD, CAMERA, T)
    assert sync.startswith("synchronisation: the images of m0, m1 fit a flat board"), sync
    bent = [_named(frame(rng, bend_m=0.01), f"b{i}") for i in range(5)]
    (lens,) = [c for c in residual_causes(bent, BOARD, CAMERA, T) if "intrinsics" in c]
    assert lens.startswith("the camera's intrinsics or lens model: 5 of 5 images"), lens


def test_the_stated_noise_as_an_angle() -> None:
    """0.1 px (cov 0.01 px^2) at 900 px focal length near the image centre: about 0.11 mrad."""
    f = frame(np.random.default_rng(3))
    assert 0.09 < stated_noise_mrad(f.corners, CAMERA) < 0.115  # type: ignore[arg-type]


def _long(f: FrameResult, range_m: float, name: str) -> FrameResult:
    """``f`` with its scan reading ``range_m`` long: every LiDAR corner moved along its own ray."""
    assert f.board is not None
    p = f.board.corners_lidar
    moved = p * (1.0 + range_m / np.linalg.norm(p, axis=1, keepdims=True))
    board = dataclasses.replace(f.board, corners_lidar=moved)
    return dataclasses.replace(f, board=board, name=name, used=True)


def test_residual_causes_name_the_lidars_ranges_when_every_board_sits_beyond_its_image() -> None:
    """Scans reading 30 mm long (every board beyond where its image puts it, along the LiDAR's rays)
    name the LiDAR's ranges, beyond; 30 mm short, short of; clean frames (above) and boards moved
    sideways do not."""
    rng = np.random.default_rng(3)
    T = T_CL.matrix()
    for range_m, word in ((0.03, "beyond"), (-0.03, "short of")):
        frames = [_long(frame(rng), range_m, f"r{i}") for i in range(5)]
        causes = residual_causes(frames, BOARD, CAMERA, T)
        (ranges,) = [c for c in causes if c.startswith("the LiDAR's ranges")]
        said = f"in 5 of 5 frames the scan puts the board a median 30 mm {word} where the image"
        assert said in ranges, ranges
    sideways = [_named(frame(rng, moved_m=0.05), f"m{i}") for i in range(5)]
    assert not [c for c in residual_causes(sideways, BOARD, CAMERA, T) if c.startswith("the LiDAR's ranges")]
