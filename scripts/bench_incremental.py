"""Benchmark of ilcc_graph.incremental: per-frame iSAM2 update time vs frames, and equality with batch.

Graph-level synthetic frames (tests/synthetic_graph.py; set-up in docs/bench_joint.md). One
calibrator takes 400 frames one by one (no ``T_init``: the first 3 frames are buffered for UPnP);
the time of each ``add_frame`` (gate, corner order, iSAM2 update, marginal covariance of the
extrinsic) is recorded. At 20, 100 and 400 frames the incremental estimate is compared with
``graph.solve`` (batch LM, no gate) on the same frames, before and after ``finish()``.

Run: ``nice python3 scripts/bench_incremental.py [--repeats 3] [--write]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import gtsam
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "scripts"))

from bench_customfactor import write_section  # noqa: E402
from synthetic_graph import session_frames  # noqa: E402

from ilcc_graph.board import Board  # noqa: E402
from ilcc_graph.cameras import Equirectangular  # noqa: E402
from ilcc_graph.estimation import NoiseOptions, solve  # noqa: E402
from ilcc_graph.estimation.incremental import IncrementalCalibrator  # noqa: E402

CAMERA = Equirectangular(8000, 4000)
BOARD = Board(6, 8, 0.075)
T_TRUE = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.03, -0.05, 0.07), np.array([0.05, -0.03, -0.25]))
DOC = ROOT / "docs" / "bench_joint.md"
CHECKPOINTS = (20, 100, 400)


def compare(cal: IncrementalCalibrator, T_inc: np.ndarray, cov_inc: np.ndarray) -> tuple[float, float]:
    """Largest |batch - incremental| per axis in batch sigmas, and of the covariance in sigma_i sigma_j."""
    ref = solve(cal.frames, CAMERA, T_inc, NoiseOptions(chi2_gate_prob=None))
    s = np.sqrt(np.diag(ref.covariance))
    xi = gtsam.Pose3(ref.T_cam_lidar).localCoordinates(gtsam.Pose3(T_inc))
    return float(np.max(np.abs(xi) / s)), float(np.max(np.abs(cov_inc - ref.covariance) / np.outer(s, s)))


def run(repeats: int) -> str:
    rng = np.random.default_rng(5)
    n_max = max(CHECKPOINTS)
    times = np.full((repeats, n_max), np.nan)
    cpu = np.full((repeats, n_max), np.nan)
    diffs: dict[int, list[tuple[float, float, float, float, float]]] = {n: [] for n in CHECKPOINTS}
    rejected = 0
    for rep in range(repeats):
        frames, _ = session_frames(rng, n_max, CAMERA, T_TRUE, BOARD)
        cal = IncrementalCalibrator(CAMERA, BOARD)
        for i, f in enumerate(frames):
            c0 = time.process_time()
            u = cal.add_frame(f)
            cpu[rep, i] = time.process_time() - c0
            times[rep, i] = u.seconds
            rejected += not u.accepted
            if i + 1 in CHECKPOINTS:
                d_live = compare(cal, u.T_cam_lidar, u.covariance)
                t0 = time.perf_counter()
                fin = cal.finish()  # relinearises everything; adding frames afterwards carries on as before
                t_fin = time.perf_counter() - t0
                d_fin = compare(cal, fin.T_cam_lidar, fin.covariance)
                diffs[i + 1].append((*d_live, *d_fin, t_fin))
            print(f"rep {rep} frame {i + 1}: {1e3 * u.seconds:.1f} ms", end="\r", flush=True)
    print()
    rows = [
        f"{repeats} sequences of {n_max} frames; update time = one `add_frame` (innovation gate, iSAM2 "
        "update, "
        "marginal covariance of `T_cam_lidar`), median and 90th percentile over the 11 frames around the "
        "count and the sequences. 'vs batch': largest difference of the estimate per axis in batch "
        "sigmas and of the covariance in units of sigma_i sigma_j, against `graph.solve` (LM, no gate) "
        f"on the same frames. Frames rejected by the innovation gate (p = 0.999): {rejected}. CPU time: "
        "process time of the update (wall time includes waiting for the busy machine's cores).",
        "",
        "| frames | update median (ms) | update p90 (ms) | CPU time median (ms) "
        "| after add_frame vs batch: estimate (sigma) | covariance | after finish(): estimate (sigma) "
        "| covariance | finish() (s) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n in CHECKPOINTS:
        lo, hi = max(0, n - 6), min(n_max, n + 5)
        w = times[:, lo:hi].ravel()
        wc = cpu[:, lo:hi].ravel()
        d = np.array(diffs[n])
        rows.append(
            f"| {n} | {1e3 * np.median(w):.1f} | {1e3 * np.percentile(w, 90):.1f} "
            f"| {1e3 * np.median(wc):.1f} "
            f"| {d[:, 0].max():.1e} "
            f"| {d[:, 1].max():.1e} | {d[:, 2].max():.1e} | {d[:, 3].max():.1e} | {np.median(d[:, 4]):.2f} |"
        )
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    table = run(args.repeats)
    print(table)
    if args.write:
        write_section(DOC, "incremental", table)
        print(f"wrote {DOC}")


if __name__ == "__main__":
    main()
