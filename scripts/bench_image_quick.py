"""The image stage with and without its cheap search (issue 37) on the images of a data folder: time per
image of ``detect_corners`` (the two alternately on each image, decoding excluded), the largest and median
difference of the corners (up to the half turn of a symmetric board), which attempt found the board and
on how many columns, and the measured corner sigma of both.

    nice python scripts/bench_image_quick.py DATA [--frames N]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

from ilcc_graph.config import load_config
from ilcc_graph.errors import CornersNotFound
from ilcc_graph.image import ImageOptions, detect_corners
from ilcc_graph.io import read_image

WITHOUT = ImageOptions(quick=())


def _difference(a, b, config) -> float:  # noqa: ANN001 - two ImageCorners and a Config
    cands = [b.uv - a.uv]
    if b.half_turn_ambiguous:
        cands.append(b.uv - a.uv[config.board.half_turn_permutation()])
    out = []
    for d in cands:
        if config.camera.periodic_u:
            d[:, 0] = config.camera.wrap_du(d[:, 0])
        out.append(float(np.abs(d).max()))
    return min(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("--frames", type=int, default=0, help="the first N images (default all)")
    args = ap.parse_args(argv)
    cfg = load_config(args.data / "config.yaml")
    paths = sorted((args.data / "img").iterdir())
    paths = paths[: args.frames] if args.frames else paths
    t = {"without": 0.0, "with": 0.0}
    diffs, found_by, sig, lost = [], Counter(), [], []
    for p in paths:
        image = read_image(p)
        res = {}
        for name, opts in (("without", WITHOUT), ("with", None)):
            t0 = time.perf_counter()
            try:
                res[name] = detect_corners(image, cfg.camera, cfg.board, opts)
            except CornersNotFound:
                res[name] = None
            t[name] += time.perf_counter() - t0
        a, b = res["without"], res["with"]
        if a is not None and b is None:
            lost.append(p.name)
        if a is None or b is None:
            continue
        diffs.append(_difference(a, b, cfg))
        found_by[(b.detector, int(b.diagnostics["coarse_width_px"]))] += 1
        sig.append((a.diagnostics["sigma_view_px"], b.diagnostics["sigma_view_px"]))
    n = len(paths)
    print(f"{args.data.name}: {n} images, {cfg.camera.width} x {cfg.camera.height}")
    print(f"detect_corners s/image: without the cheap search {t['without'] / n:.3f}, "
          f"with it {t['with'] / n:.3f}, ratio {t['with'] / t['without']:.2f}")  # fmt: skip
    print(f"corner difference px: largest {max(diffs):.2g}, median {np.median(diffs):.2g}")
    print("found by (attempt, columns searched):", dict(found_by))
    s0, s1 = (float(np.median([s[k] for s in sig])) for k in (0, 1))
    print(f"sigma view px median: without {s0:.4f}, with {s1:.4f}")
    print(f"boards lost by the cheap search: {lost or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
