"""Cropped scans through the command line (issue 38, "Cropped and partial scans"): a simulated
OS1-128 set whose organised clouds are cut to a box about the board, written as organised PCDs
(HEIGHT = rings, WIDTH = the window's columns, NaN outside the box) and as unorganised ones without
a ring field, their intensity the ring number; the board found in every scan and the calibration
within its covariance."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.board import Board
from ilcc_graph.io import read_ground_truth
from ilcc_graph.io.pcd import write_pcd
from ilcc_graph.types import Scan

CHI2_6_999 = 22.46
BOARD = Board(6, 8, 0.075)


def _organised(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's Ouster PCD (binary x y z intensity ring, HEIGHT x WIDTH): points (H, W, 3),
    ring (H, W)."""
    raw = path.read_bytes()
    head = raw[: raw.index(b"DATA binary\n") + len(b"DATA binary\n")]
    fields = dict(line.split(" ", 1) for line in head.decode().splitlines() if " " in line)
    h, w = int(fields["HEIGHT"]), int(fields["WIDTH"])
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("i", "<f4"), ("ring", "<u2")])
    rec = np.frombuffer(raw, dtype=dt, count=h * w, offset=len(head)).reshape(h, w)
    return np.stack([rec["x"], rec["y"], rec["z"]], axis=2).astype(np.float64), rec["ring"].astype(np.int64)


def _crop_set(data: Path, organised: bool, margin: float = 0.5) -> None:
    """Every scan of ``data`` cut to a box ``margin`` wider than the board about it (its true pose),
    in the columns about the board, intensity = ring; written back in place."""
    truth = read_ground_truth(data)
    x0, x1, y0, y1 = BOARD.extent()
    half = 0.5 * np.hypot(x1 - x0, y1 - y0)
    for pcd in sorted((data / "pcd").glob("*.pcd")):
        p, ring = _organised(pcd)
        T = truth.T_lidar_board[pcd.stem]
        c = T[:3, :3] @ np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0]) + T[:3, 3]
        box = (np.abs(p - c).max(axis=2) <= half + margin) & (p != 0).any(axis=2)
        cols = np.flatnonzero(box.any(axis=0))
        shift = p.shape[1] // 2 - int(np.median(cols))  # the window away from the seam
        p, ring, box = (np.roll(a, shift, axis=1) for a in (p, ring, box))
        cols = np.flatnonzero(box.any(axis=0))
        cols = np.arange(cols.min(), cols.max() + 1)
        if organised:
            q = np.where(box[:, cols, None], p[:, cols], np.nan).reshape(-1, 3)
            write_pcd(pcd, Scan(q, ring[:, cols].ravel().astype(float)), organised=(p.shape[0], cols.size))
        else:
            write_pcd(pcd, Scan(p[box], ring[box].astype(float)))


@pytest.mark.parametrize("organised", [True, False], ids=["organised", "unorganised-no-ring"])
def test_cropped_clouds_calibrate(tmp_path: Path, organised: bool) -> None:
    data = tmp_path / "data"
    common = ["--lidar", "os1-128-rev6", "--format", "ouster", "--camera", "pinhole", "--width", "640"]
    assert main(["simulate", str(data), *common, "--frames", "6", "--seed", "3"]) == 0
    _crop_set(data, organised)
    head = next((data / "pcd").iterdir()).read_bytes()[:300]
    assert (b"HEIGHT 128" in head) == organised and b"ring" not in head
    out = tmp_path / "out"
    assert main(["calibrate", str(data), "--out", str(out), "--no-report", "--jobs", "1"]) == 0
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    assert all(f["used"] for f in cal["frames"]), [f.get("reason") for f in cal["frames"]]
    assert cal["diagnostics"]["lidar_boards_no_print"] == 6  # the intensity is the ring: no print
    T, truth = gtsam.Pose3(np.array(cal["T_cam_lidar"])), gtsam.Pose3(read_ground_truth(data).T_cam_lidar)
    xi = np.asarray(gtsam.Pose3.Logmap(T.between(truth)))
    nees = float(xi @ np.linalg.solve(np.array(cal["covariance"]), xi))
    rot, trans = np.degrees(np.linalg.norm(xi[:3])), 1e3 * np.linalg.norm(xi[3:])
    assert rot < 0.3 and trans < 10.0 and nees < CHI2_6_999, (rot, trans, nees)
