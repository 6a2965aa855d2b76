"""Benchmark: read/write times of every scan format for a 100k-point scan.

Prints a markdown table and writes it to docs/io_benchmark.md. Run: python3 scripts/bench_io.py
"""

from __future__ import annotations

import tempfile
import time
from functools import partial
from pathlib import Path

import numpy as np

from ilcc_graph.io import read_scan, write_pcd, write_ply
from ilcc_graph.types import Scan

N = 100_000
REPEATS = 5


def _best(fn, repeats: int = REPEATS) -> float:
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    rng = np.random.default_rng(0)
    ring = rng.integers(0, 32, N).astype(np.int32)
    el = np.deg2rad(-30.67 + 1.333 * ring)
    az = rng.uniform(-np.pi, np.pi, N)
    r = rng.uniform(1, 60, N)
    pts = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1)
    pts = np.round(pts.astype(np.float32), 3).astype(np.float64)  # 1 mm steps, like a driver's output
    scan = Scan(pts, rng.integers(0, 256, N).astype(np.float64), ring)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        cases = {
            "pcd binary": (d / "a.pcd", lambda p: write_pcd(p, scan, "binary")),
            "pcd ascii": (d / "b.pcd", lambda p: write_pcd(p, scan, "ascii")),
            "pcd binary_compressed": (d / "c.pcd", lambda p: write_pcd(p, scan, "binary_compressed")),
            "ply binary": (d / "d.ply", lambda p: write_ply(p, scan)),
            "kitti bin": (
                d / "e.bin",
                lambda p: np.column_stack([pts, scan.intensity]).astype("<f4").tofile(p),
            ),
            "csv (header)": (
                d / "f.csv",
                lambda p: np.savetxt(
                    p,
                    np.column_stack([pts, scan.intensity, ring]),
                    delimiter=",",
                    fmt="%.6g",
                    header="x,y,z,intensity,laser_id",
                    comments="",
                ),
            ),
        }
        for name, (path, write) in cases.items():
            tw = _best(partial(write, path), 1 if "compressed" in name else REPEATS)
            tr = _best(partial(read_scan, path))
            assert len(read_scan(path)) == N
            rows.append((name, path.stat().st_size / 1e6, 1000 * tr, 1000 * tw))
    head = f"Scan I/O, {N} points (x y z intensity ring), best of {REPEATS}, shared 2-core machine\n\n"
    table = "| format | size MB | read ms | write ms |\n|---|---:|---:|---:|\n"
    table += "".join(f"| {n} | {s:.2f} | {r:.1f} | {w:.1f} |\n" for n, s, r, w in rows)
    print(head + table)
    out = Path(__file__).resolve().parents[1] / "docs" / "io_benchmark.md"
    out.write_text("# " + head + table)


if __name__ == "__main__":
    main()
