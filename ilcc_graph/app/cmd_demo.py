"""``ilcc-graph demo``: the standard set simulated (or reused), calibrated, compared with its truth.

The panoramic standard set lives in the cache (``--cache``) and is reused while it is there.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ilcc_graph.app.arguments import add_solve_arguments
from ilcc_graph.app.cmd_calibrate import calibrate
from ilcc_graph.app.console import PIXELS, SEED, Progress
from ilcc_graph.app.folders import output_folder

__all__ = ["HELP", "add_arguments", "run"]

HELP = "simulate the standard panoramic set (or reuse it), calibrate, compare"


def add_arguments(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("--width", type=PIXELS, default=8000, help="panorama width in pixels (default 8000)")
    sp.add_argument("--seed", type=SEED, default=0, help="the simulation's seed (default 0)")
    sp.add_argument("--data", help="where the simulated set lives (default: under --cache)")
    cache = os.path.join(os.path.expanduser("~"), ".cache", "ilcc_graph")
    sp.add_argument("--cache", default=cache, help="folder for simulated data sets (~/.cache/ilcc_graph)")
    add_solve_arguments(sp, studies=True)


def _stored(folder: Path, cache: bool = True) -> str:
    """'~/.cache/.../name (161 MB; deletable)': where a folder is (home as ~) and its size (a folder
    in the cache may go: the demo makes it again)."""
    size = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6
    home, where = str(Path.home()), str(folder)
    where = "~" + where[len(home) :] if where.startswith(home + os.sep) else where
    return f"{where} ({size:.0f} MB{'; deletable' if cache else ''})"


def run(args: argparse.Namespace) -> int:
    """The standard panoramic set simulated into the cache (JPEG images: a sixth of PNG's bytes,
    the same accuracy, docs/bench_demo.md) or reused from there, then calibrated against its truth."""
    from ilcc_graph.io import read_ground_truth
    from ilcc_graph.simulate.write_set import write_standard_set

    data = Path(args.data or Path(args.cache) / f"demo-hdl32-equirect{args.width}-seed{args.seed}")
    output_folder(args, [data])  # the output folder, claimed before the simulation
    if (data / "ground_truth.yaml").is_file():
        print(f"reusing {_stored(data, not args.data)}")
    else:
        print(
            f"simulating HDL-32E scans and {args.width} px panoramas, 20 frames (a minute or so)", flush=True
        )
        write_standard_set(
            data, Progress("simulate"), width=args.width, seed=args.seed, lidar="hdl32",
            camera="equirectangular", frames=20, image_format="jpg", command=args.command_line,
        )  # fmt: skip
        print(f"kept in {_stored(data, not args.data)}")
    return calibrate([str(data)], args, read_ground_truth(data).T_cam_lidar)
