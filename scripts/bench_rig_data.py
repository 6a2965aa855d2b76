"""Benchmark of the rig data side (issue 24): the simulator's preset rigs written as a folder per
sensor and as one bag (time), read back by the rig source (same moments), and every camera-LiDAR pair
of each rig solved alone by today's single-pair pipeline through ``RigSource.pair`` (error against
the rig's ground truth, the solver's sigma): the baseline the joint rig graph is to beat.

Usage: ``nice python3 scripts/bench_rig_data.py [--seed 1] [--md docs/bench_rig_data.md]``.
Prints a markdown table and writes it between markers in ``--md``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from _shared import write_between  # noqa: E402

from ilcc_graph.datasets import open_source  # noqa: E402
from ilcc_graph.errors import CalibrationError  # noqa: E402
from ilcc_graph.run.pipeline import run  # noqa: E402
from ilcc_graph.simulate.rig_export import write_rig_bag, write_rig_set  # noqa: E402
from ilcc_graph.simulate.rig_spec import RIG_PRESETS  # noqa: E402

RIGS = {"ring-pinhole": dict(width=640, n_moments=16), "ring-fisheye": dict(width=800, n_moments=16),
        "backpack": dict(width=2400, n_moments=12)}  # fmt: skip
BEGIN, END = "<!-- bench_rig_data:begin -->", "<!-- bench_rig_data:end -->"


def _pair_row(src, cam: str, lidar: str) -> str:  # noqa: ANN001 - a RigSource
    pair = src.pair(cam, lidar)
    n = sum(1 for m in src.moments() if m.has(cam) and m.has(lidar))
    seen = sum(1 for ms in src.ground_truth().seen_by.values() if cam in ms and lidar in ms)
    try:
        cal = run([pair]).calibration
    except CalibrationError as err:
        why = f"{type(err).__name__}: {str(err).splitlines()[0][:60]}"
        return f"| {cam} + {lidar} | {n} | {seen} | - | {why} | | | |"
    d = np.linalg.solve(pair.ground_truth().T_cam_lidar, cal.T_cam_lidar)
    rot = np.degrees(np.linalg.norm(Rotation.from_matrix(d[:3, :3]).as_rotvec()))
    sig = np.sqrt(np.diag(cal.covariance))
    return (f"| {cam} + {lidar} | {n} | {seen} | {sum(f.used for f in cal.frames)} | {rot:.3f} | "
            f"{1000 * np.linalg.norm(d[:3, 3]):.2f} | {np.degrees(np.linalg.norm(sig[:3])):.3f} | "
            f"{1000 * np.linalg.norm(sig[3:]):.2f} |")  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--md", type=Path, default=ROOT / "docs" / "bench_rig_data.md")
    a = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_rig_data."))
    gen = ["| rig | moments | folder s | bag s | moments read back (folder / bag) |", "|---|---|---|---|---|"]
    pairs = ["| rig | pair | moments with both | boards seen whole by both | used | error deg | error mm "
             "| sigma deg | sigma mm |", "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    try:
        for name, kw in RIGS.items():
            spec = RIG_PRESETS[name](seed=a.seed, **kw)
            t0 = time.perf_counter()
            folder = write_rig_set(work / name, spec)
            t1 = time.perf_counter()
            bag = write_rig_bag(work / f"{name}-bag", spec)
            t2 = time.perf_counter()
            src, bsrc = open_source(folder, rig=True), open_source(bag, rig=True)
            same = [m.sensors for m in src.moments()] == [m.sensors for m in bsrc.moments()]
            back = f"{len(src.moments())} / {len(bsrc.moments())} ({'same' if same else 'DIFFERENT'})"
            gen.append(
                f"| {name} ({kw['width']} px) | {spec.n_moments} | {t1 - t0:.1f} | {t2 - t1:.1f} | {back} |"
            )
            for cam in src.config().cameras:
                for lidar in src.config().lidars:
                    pairs.append(f"| {name} " + _pair_row(src, cam, lidar))
            print(gen[-1], flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    text = "\n".join([f"seed {a.seed}; one process on a shared 2-core machine", "", *gen, "", *pairs])
    print(text)
    if not a.md.is_file():
        a.md.write_text("# Rig data: simulated rigs, the rig source, pairs solved alone\n\n"
                        "Written by `scripts/bench_rig_data.py` (see its docstring).\n")  # fmt: skip
    write_between(a.md, BEGIN, END, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
