"""Benchmark: time and peak memory to write a simulated data set (default 20 frames, HDL-32E, 8000x4000).

Usage: ``python3 scripts/bench_simulate.py [--frames 20] [--width 8000] [--lidar hdl32]
[--camera equirectangular] [--keep DIR] [--md docs/bench_simulate.md]``.
Prints a markdown table and writes it to ``--md``. Peak memory is the process's maximum resident
set size (``resource.getrusage``), which includes the interpreter and the imported libraries.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ilcc_graph.simulate import ImageRenderer, board_placements, frame_scene, simulate_scan, standard_spec  # noqa: E402
from ilcc_graph.simulate.write_set import simulate_dataset  # noqa: E402


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--width", type=int, default=8000)
    ap.add_argument("--lidar", default="hdl32")
    ap.add_argument("--camera", default="equirectangular")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", type=Path, default=None, help="write the data set here (default: a temp dir)")
    ap.add_argument("--md", type=Path, default=ROOT / "docs" / "bench_simulate.md")
    args = ap.parse_args()

    spec = standard_spec(args.lidar, args.camera, args.width, args.frames, args.seed)
    load0 = os.getloadavg()
    tmp = Path(tempfile.mkdtemp(prefix="bench_sim_"))
    out = args.keep if args.keep is not None else tmp / "data"
    stamps: list[float] = []
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    t0 = time.perf_counter()
    simulate_dataset(out, spec, progress=lambda k, n: stamps.append(time.perf_counter()))
    total = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    rss_total = _rss_mb()
    size_mb = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6
    n_points = []
    from ilcc_graph.io import read_scan

    for p in sorted((out / "pcd").glob("*.pcd")):
        n_points.append(len(read_scan(p)))

    # one more frame, stage by stage (same process, after the run above)
    import cv2

    renderer = ImageRenderer(spec)
    t = time.perf_counter()
    renderer.background()
    t_bg = time.perf_counter() - t
    T = board_placements(spec)[0]
    scene = frame_scene(spec, T, 0)
    t = time.perf_counter()
    simulate_scan(spec, scene, 0)
    t_scan = time.perf_counter() - t
    t = time.perf_counter()
    img = renderer.render(scene, 0)
    t_render = time.perf_counter() - t
    t = time.perf_counter()
    cv2.imencode(".png", img)
    t_png = time.perf_counter() - t
    if args.keep is None:
        shutil.rmtree(tmp, ignore_errors=True)

    per_frame = np.diff([t0, *stamps])
    cam = spec.camera
    rows = [
        ("data set", f"{args.frames} frames, {args.lidar}, {cam.kind} {cam.width}x{cam.height}"),
        ("total wall time", f"{total:.1f} s"),
        ("CPU time of the run (user + sys, all threads)", f"{cpu:.1f} s"),
        ("first frame (incl. the room's image)", f"{per_frame[0]:.1f} s"),
        (
            "later frames, mean (min-max)",
            f"{per_frame[1:].mean():.2f} s ({per_frame[1:].min():.2f}-{per_frame[1:].max():.2f})"
            if len(per_frame) > 1
            else "-",
        ),  # fmt: skip
        ("peak memory (max RSS)", f"{rss_total:.0f} MB"),
        ("size on disk", f"{size_mb:.0f} MB"),
        ("points per scan, mean", f"{np.mean(n_points):.0f}"),
        ("stage: room image (once)", f"{t_bg:.2f} s"),
        ("stage: LiDAR scan", f"{t_scan:.2f} s"),
        ("stage: frame image (regions, blur, noise)", f"{t_render:.2f} s"),
        ("stage: PNG encoding", f"{t_png:.2f} s"),
        ("machine", f"{os.cpu_count()} cores, {_cpu()}, load avg at start {load0[0]:.1f}"),
        ("python / numpy / opencv", f"{platform.python_version()} / {np.__version__} / {cv2.__version__}"),
    ]
    w = max(len(r[0]) for r in rows)
    table = [f"| {'what':<{w}} | value |", f"|{'-' * (w + 2)}|-------|"]
    table += [f"| {a:<{w}} | {b} |" for a, b in rows]
    text = "\n".join(table)
    print(text)
    md = (
        "# Simulator benchmark\n\n"
        "`python3 scripts/bench_simulate.py` writes a data set with\n"
        "`ilcc_graph.simulate.write_set.simulate_dataset` (config.yaml, binary PCD, PNG images,\n"
        "ground_truth.yaml) to a temporary folder and reports wall time and the process's peak\n"
        "resident memory. Aim: under 2 minutes and 3 GB for 20 frames of HDL-32E +\n"
        "8000x4000 equirectangular images. The stage rows time one extra frame after the run.\n"
        "The machine is shared (2 cores): its load average at the start is in the table; with other\n"
        "jobs running the wall time is far above the CPU time.\n\n" + text + "\n"
    )
    args.md.parent.mkdir(parents=True, exist_ok=True)
    args.md.write_text(md)


if __name__ == "__main__":
    main()
