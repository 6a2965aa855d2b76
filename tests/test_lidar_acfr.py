"""The LiDAR stage on recorded VLP-16 scans (../shared/data/acfr-vlp16-fisheye; skipped where absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ilcc_graph.config import load_config
from ilcc_graph.io import read_scan
from ilcc_graph.lidar import estimate_board


def test_board_found_on_recorded_vlp16_scans(acfr_data: Path) -> None:
    cfg = load_config(acfr_data / "config.yaml")
    board = cfg.board
    for stem in ("pose01", "pose15", "pose29"):  # 1.7 m, 2.5 m, 3.1 m
        scan = read_scan(acfr_data / "pcd" / f"{stem}.pcd")
        fit = estimate_board(scan, board, cfg.lidar, cfg.roi)
        c = fit.corners_lidar.reshape(board.rows - 1, board.cols - 1, 3)
        # the corner grid has the printed square size along both sides
        assert np.allclose(np.linalg.norm(np.diff(c, axis=1), axis=2), board.square_size, atol=1e-6)
        assert np.allclose(np.linalg.norm(np.diff(c, axis=0), axis=2), board.square_size, atol=1e-6)
        # the board (on a tripod in the room, 1.5-4 m away) faces the sensor, and its returns lie on it
        T = fit.T_lidar_board
        assert 1.5 < np.linalg.norm(fit.corners_lidar.mean(axis=0)) < 4.0
        assert T[:3, 2] @ fit.corners_lidar.mean(axis=0) < 0
        z = (fit.points_lidar - T[:3, 3]) @ T[:3, 2]
        assert np.median(np.abs(z)) < 0.02
        # black returns on black squares, white on white, for most of the board
        b = (fit.points_lidar - T[:3, 3]) @ T[:3, :3]
        colour = board.colour_at(b[:, :2])
        thr = 0.5 * (fit.diagnostics["intensity_low"] + fit.diagnostics["intensity_high"])
        agree = (fit.intensity > thr) == (colour > 0.5)
        assert agree.mean() > 0.8, (stem, agree.mean())
