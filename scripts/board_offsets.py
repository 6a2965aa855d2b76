"""Where each board's returns sit against the camera's view of that board, across the image.

For each data set: ``calibrate``'s run (configs as shipped, ``run.pipeline.run``); then per used
frame the board's pose from its image alone (``evaluation.causes.fit_image_alone`` on the image
corners' bearings through the stated camera, against the LiDAR stage's own corner layout), taken
into the LiDAR frame with the result's ``T_cam_lidar``, and the board's own returns (the LiDAR
stage's segment, inside the pattern less 30 mm) measured against that plane along their rays
(median, mm). Each board's offset is set beside its angle from the camera's optical axis and its
range, with the correlations and a least-squares
fit ``offset = a + b angle^2 + c range``.

A stated lens (focal length, radial polynomial) that is a little off puts each board too near or
too far by an amount that grows with its angle from the axis; a LiDAR range scale error, by an
amount that grows with its range; a constant range offset shifts them all alike. A diagnostic:
docs/bench_board_offsets.md reads it (session 60: the boards' own plane offset of acfr-os1-fisheye,
14.6 mm, and its 12 mm tz sigma).

    python scripts/board_offsets.py ../shared/data/acfr-vlp16-fisheye ../shared/data/acfr-os1-fisheye \
        [--out docs/bench_board_offsets.md]
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np
from _shared import write_between

from ilcc_graph.datasets import open_source
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.evaluation.causes import fit_image_alone
from ilcc_graph.evaluation.metric import transform_points
from ilcc_graph.run.pipeline import run
from ilcc_graph.run.result import RunOptions
from ilcc_graph.types import FrameResult

#: returns this far inside the pattern's outer corners count (m): clear of the board's edges
INSET_M = 0.03
#: and this near the camera's plane of the board (m): the board's, not what stands behind it
NEAR_M = 0.15


def image_board(f: FrameResult, T_cam_lidar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The board as its image alone places it, in the LiDAR frame: its corners (K, 3), fitted to the
    stated camera's bearings as ``calibrate``'s causes fit an image alone
    (``evaluation.causes.fit_image_alone``, laid out as the LiDAR stage's fit lays them in the board
    frame), and the board's pose (4, 4) that carries that layout onto them."""
    assert f.board is not None and f.corners is not None
    layout = transform_points(np.linalg.inv(f.board.T_lidar_board), f.board.corners_lidar)
    layout[:, 2] = 0.0
    cam = fit_image_alone(f.corners.bearings, layout).corners_cam
    corners = transform_points(np.linalg.inv(T_cam_lidar), cam)
    a, b = layout - layout.mean(0), corners - corners.mean(0)  # the rigid motion a -> b (Kabsch)
    U, _, Vt = np.linalg.svd(b.T @ a)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, corners.mean(0) - R @ layout.mean(0)
    return corners, T


def board_row(f: FrameResult, T_cam_lidar: np.ndarray) -> dict[str, float]:
    """One used frame: its returns' median offset along their rays from the plane its image gives
    (mm; positive: behind it), the pattern centre's angle from the optical axis (deg), its range
    (m), and how many returns counted."""
    assert f.board is not None
    corners, T = image_board(f, T_cam_lidar)
    in_plane = transform_points(np.linalg.inv(T), corners)[:, :2]
    lo, hi = in_plane.min(0) + INSET_M, in_plane.max(0) - INSET_M
    p = f.board.points_lidar
    q = transform_points(np.linalg.inv(T), p)
    keep = np.all((q[:, :2] > lo) & (q[:, :2] < hi), axis=1) & (np.abs(q[:, 2]) < NEAR_M)
    u = p[keep] / np.linalg.norm(p[keep], axis=1, keepdims=True)
    along = q[keep, 2] / np.abs(u @ T[:3, 2])
    centre = corners.mean(0)
    c_cam = transform_points(T_cam_lidar, centre)[0]
    angle = np.degrees(np.arccos(c_cam[2] / np.linalg.norm(c_cam)))
    return {"offset_mm": 1e3 * float(np.median(along)), "angle_deg": float(angle),
            "range_m": float(np.linalg.norm(centre)), "returns": float(keep.sum())}  # fmt: skip


def data_set(data: Path) -> list[str]:
    """The markdown section of one data set."""
    t0 = time.perf_counter()
    try:
        cal = run([open_source(data)], RunOptions()).calibration
    except CalibrationImpossible as err:
        return [f"## {data.name}", "", f"Does not calibrate (exit 3): {err}", ""]
    frames = [f for f in cal.frames if f.used and f.board is not None and f.corners is not None]
    rows = {f.name: board_row(f, cal.T_cam_lidar) for f in frames}
    off = np.array([r["offset_mm"] for r in rows.values()])
    ang = np.array([r["angle_deg"] for r in rows.values()])
    rng = np.array([r["range_m"] for r in rows.values()])
    X = np.c_[np.ones(len(off)), ang**2, rng]
    coef, *_ = np.linalg.lstsq(X, off, rcond=None)
    lines = [
        f"## {data.name}",
        "",
        f"{len(rows)} boards ({time.perf_counter() - t0:.0f} s).",
        "",
        "| frame | offset mm | angle from the axis deg | range m | returns |",
        "|---|---|---|---|---|",
        *(
            f"| {n} | {r['offset_mm']:+.1f} | {r['angle_deg']:.1f} | {r['range_m']:.2f} | "
            f"{r['returns']:.0f} |"
            for n, r in rows.items()
        ),
        "",
        f"Offsets: spread (sd) {off.std():.1f} mm; correlation with the angle "
        f"{np.corrcoef(ang, off)[0, 1]:+.2f}, "
        f"with the range {np.corrcoef(rng, off)[0, 1]:+.2f}; the angle and the range "
        f"{np.corrcoef(ang, rng)[0, 1]:+.2f} with each other. Fit: {coef[0]:+.1f} mm "
        f"{coef[1] * 100:+.2f} mm per (10 deg)^2 {coef[2]:+.1f} mm per m; the residuals' sd "
        f"{np.std(off - X @ coef):.1f} mm.",
        "",
    ]
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, help="a markdown file: the tables between its markers")
    args = ap.parse_args(argv)
    logging.getLogger("ilcc_graph").setLevel(logging.ERROR)
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    lines = [f"`python scripts/board_offsets.py {' '.join(argv or sys.argv[1:])}` ({when})", ""]
    for d in args.data:
        lines += data_set(d)
    print("\n".join(lines))
    if args.out is not None:
        write_between(
            args.out, "<!-- board_offsets:begin -->", "<!-- board_offsets:end -->", "\n".join(lines)
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
