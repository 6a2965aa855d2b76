"""Segmentation of one scan into objects along and across scanlines (ilcc_graph.lidar.segmentation)."""

from __future__ import annotations

import numpy as np
import pytest

from ilcc_graph.board import Board
from ilcc_graph.lidar._synthetic import SynthScene, board_pose, synth_scan
from ilcc_graph.lidar.segmentation import estimate_range_noise, segment_scan
from ilcc_graph.lidars import lidar_model

BOARD = Board(6, 8, 0.075)


def _board_mask(scan, T: np.ndarray, board: Board, tol: float = 0.05) -> np.ndarray:
    Tinv = np.linalg.inv(T)
    b = scan.points @ Tinv[:3, :3].T + Tinv[:3, 3]
    x0, x1, y0, y1 = board.extent()
    return (
        (np.abs(b[:, 2]) < tol)
        & (b[:, 0] > x0 - 0.01)
        & (b[:, 0] < x1 + 0.01)
        & (b[:, 1] > y0 - 0.01)
        & (b[:, 1] < y1 + 0.01)
    )


@pytest.mark.parametrize("name", ["hdl32", "vlp16", "hdl64", "os1-64"])
def test_floating_board_is_one_object_apart_from_wall_and_ground(name: str) -> None:
    model = lidar_model(name)
    rng = np.random.default_rng(3)
    scan, T = synth_scan(BOARD, model, SynthScene(distance=2.5, in_plane_deg=40, wall_gap=0.6), rng)
    seg = segment_scan(scan.points, scan.ring, model)
    on = _board_mask(scan, T, BOARD)
    labels, counts = np.unique(seg.labels[on], return_counts=True)
    main = labels[np.argmax(counts)]
    assert counts.max() >= 0.97 * on.sum()  # the board's returns stay together
    # and its object holds (almost) nothing else: the wall 0.6 m behind and the ground are apart
    assert np.sum((seg.labels == main) & ~on) <= 0.02 * on.sum()
    assert seg.n_objects >= 2


def test_points_out_of_scan_order_and_ring_from_elevation_give_the_same_objects() -> None:
    model = lidar_model("hdl32")
    scan, T = synth_scan(BOARD, model, SynthScene(distance=2.0), np.random.default_rng(0))
    seg_a = segment_scan(scan.points, scan.ring, model)
    seg_b = segment_scan(scan.points, model.ring_from_points(scan.points), model)
    on = _board_mask(scan, T, BOARD)
    # the board's returns share one label in both runs
    assert len(np.unique(seg_a.labels[on])) == 1 and len(np.unique(seg_b.labels[on])) == 1


def test_range_noise_estimate_follows_the_true_noise() -> None:
    model = lidar_model("hdl32")
    for sigma in (0.005, 0.02):
        sc = SynthScene(distance=3.0, range_sigma=sigma, azimuth_window_deg=None)
        scan, _ = synth_scan(BOARD, model, sc, np.random.default_rng(1))
        p = scan.points
        r = np.linalg.norm(p, axis=1)
        az = np.arctan2(p[:, 1], p[:, 0])
        o = np.lexsort((az, scan.ring))
        est = estimate_range_noise(r[o], scan.ring[o], az[o], np.deg2rad(model.horizontal_resolution_deg))
        assert 0.7 * sigma < est < 1.4 * sigma


def test_valid_mask_and_close_points_are_ignored() -> None:
    model = lidar_model("vlp16")
    scan, _ = synth_scan(BOARD, model, SynthScene(distance=2.0), np.random.default_rng(2))
    valid = scan.points[:, 1] > 0
    seg = segment_scan(scan.points, scan.ring, model, valid=valid)
    assert np.all(seg.labels[~valid] == -1)
    assert np.all(seg.labels[valid] >= 0)
    assert seg.edges.shape[1] == 2 and np.all(valid[seg.edges].all(axis=1))
    T = board_pose(BOARD, SynthScene(distance=2.0))
    assert T.shape == (4, 4)
