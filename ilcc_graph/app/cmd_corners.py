"""``ilcc-graph lidar-corners`` and ``image-corners``: one stage alone over a data set.

One YAML (and a drawing) per frame and a table; two registrations of this module in ``commands``.
"""

from __future__ import annotations

import argparse
from functools import partial

from ilcc_graph.app.arguments import add_bag_arguments, add_frames_arguments
from ilcc_graph.app.console import Progress
from ilcc_graph.app.flags import bag_options, stage_options
from ilcc_graph.app.folders import output_folder, written

__all__ = ["IMAGE_HELP", "LIDAR_HELP", "add_arguments", "run", "run_image", "run_lidar"]

LIDAR_HELP = "the LiDAR stage alone: board, pose, corners"
IMAGE_HELP = "the image stage alone: corners, drawings"


def add_arguments(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("data", metavar="DATA")
    sp.add_argument("--out", help="output folder (default: out/<timestamp>)")
    add_frames_arguments(sp)
    add_bag_arguments(sp)


def run(args: argparse.Namespace, stage: str) -> int:
    """The ``stage`` (``lidar`` or ``image``) alone over the data set ``args.data``."""
    from ilcc_graph.app.write import write_stage
    from ilcc_graph.datasets import open_source
    from ilcc_graph.observe import stage_alone
    from ilcc_graph.report.text import stage_table

    out = output_folder(args, [args.data])
    source = open_source(args.data, **bag_options(args))
    _, refs, results = stage_alone(source, stage, stage_options(args), Progress(stage))
    rows = write_stage(out, stage, source, refs, results, args.command_line)
    written(args, out)
    print(stage_table(stage, rows, source.skipped(), out))
    return 0


run_lidar = partial(run, stage="lidar")
run_image = partial(run, stage="image")
