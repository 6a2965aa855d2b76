"""Latency of ``ilcc-graph check --watch``: from a frame's arrival to its verdict (issue 13).

A simulated set's frames are copied one by one into an empty data-set folder (its config.yaml
first; per frame the scan, then the image, each with ``shutil.copyfile``, like a recorder writing
files) every ``--interval`` seconds, while ``ilcc-graph check DEST --watch --until N --out OUT``
runs as a separate process (the real command line). A frame's latency is the time from the end of
the write of its last file (the file's modification time) to the verdict, as ``check.yaml``
records it; it includes waiting until the files stop growing (0.3 s) and the polling (0.1 s).

Sets: a small one (pinhole 800 x 500, 8 frames), the 2000 x 1000 panoramic set (10 frames) and,
with ``--standard DIR`` (e.g. the folder ``ilcc-graph demo`` simulates, 8000 x 4000), its frames.
Run: ``python scripts/bench_live.py --write [--standard ~/.cache/ilcc_graph/demo-hdl32-equirect8000-seed0]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ilcc_graph.io import read_yaml
from ilcc_graph.simulate import simulate_dataset, standard_spec

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bench_live.md"


def fill_and_check(src: Path, work: Path, n: int, interval: float) -> tuple[list[dict], float]:
    """Copy ``n`` frames of ``src`` into a new folder under ``work`` while ``check --watch`` runs."""
    dst, out = work / "live", work / "out"
    shutil.rmtree(dst, ignore_errors=True)
    (dst / "pcd").mkdir(parents=True)
    (dst / "img").mkdir()
    shutil.copyfile(src / "config.yaml", dst / "config.yaml")
    stems = sorted(p.stem for p in (src / "pcd").iterdir())[:n]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "ilcc_graph.cli", "check", str(dst), "--watch", "--until", str(len(stems)),
           "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    time.sleep(3.0)  # the command's start (imports) is not part of a frame's latency
    t0 = time.perf_counter()
    for stem in stems:
        scan = next((src / "pcd").glob(f"{stem}.*"))
        image = next((src / "img").glob(f"{stem}.*"))
        shutil.copyfile(scan, dst / "pcd" / scan.name)
        shutil.copyfile(image, dst / "img" / image.name)
        time.sleep(interval)
    text, _ = proc.communicate(timeout=600)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"check failed ({proc.returncode}):\n{text}")
    print(text)
    return read_yaml(out / "check.yaml")["frames"], wall


def summary(name: str, frames: list[dict], interval: float) -> list[str]:
    lat = np.array([f["latency_s"] for f in frames])
    sec = np.array([f["seconds"] for f in frames])
    calibrated = [f for f in frames if "sigma" in f]
    return [
        name,
        str(len(frames)),
        f"{interval:.1f}",
        f"{np.median(sec):.2f} / {sec.max():.2f}",
        f"{np.median(lat):.2f}",
        f"{lat.max():.2f}",
        f"{np.mean(lat <= 2.0):.0%}",
        str(len(calibrated)),
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--interval", type=float, default=3.0, help="seconds between frames")
    ap.add_argument(
        "--standard", type=Path, default=None, help="the 8000 x 4000 standard set (demo's folder)"
    )
    ap.add_argument("--frames", type=int, default=10, help="frames of the standard set to copy")
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="bench_live_"))
    sets = [
        ("pinhole 800 x 500, HDL-32E", standard_spec(camera="pinhole", width=800, frames=8, seed=5), 8),
        ("panorama 2000 x 1000, HDL-32E", standard_spec(width=2000, frames=10, seed=1), 10),
    ]
    rows = []
    for name, spec, n in sets:
        src = simulate_dataset(work / name.split()[0], spec)
        frames, _ = fill_and_check(src, work, n, args.interval)
        rows.append(summary(name, frames, args.interval))
    if args.standard is not None:
        frames, _ = fill_and_check(args.standard, work, args.frames, args.interval)
        rows.append(summary("standard panorama 8000 x 4000, HDL-32E", frames, args.interval))
    header = ["set", "frames", "every (s)", "work per frame median / max (s)", "latency median (s)",
              "latency max (s)", "within 2 s", "frames with sigmas"]  # fmt: skip
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    table = "\n".join(lines)
    print(table)
    if args.write:
        load = os.getloadavg()[0]
        DOC.write_text(
            "# `ilcc-graph check --watch`: latency from a frame's arrival to its verdict\n\n"
            "`scripts/bench_live.py` (issue 13; target: within 2 s). Frames of simulated sets are copied "
            f"one by one into an empty folder every {args.interval:g} s while `check --watch` runs as its "
            "own "
            "process; latency: from the end of the write of the frame's last file to its verdict (includes "
            "the 0.3 s the files must stay unchanged and the 0.1 s polling). The work per frame is both "
            "stages (reading the files included), the repeat test and the iSAM2 update.\n\n"
            + table
            + f"\n\nMachine: {os.cpu_count()} cores, load average {load:.1f} when it finished.\n"
        )
        print(f"wrote {DOC}")
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
