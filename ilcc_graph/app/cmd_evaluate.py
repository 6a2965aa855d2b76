"""``ilcc-graph evaluate``: the paper's metric and corner errors of a calibration on a data set.

Computed by ``evaluation``, printed, and with ``--out`` written as evaluation.yaml.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ilcc_graph.app.arguments import add_bag_arguments, add_frames_arguments
from ilcc_graph.app.console import Progress
from ilcc_graph.app.flags import bag_options, stage_options
from ilcc_graph.app.folders import claim_given
from ilcc_graph.errors import InputError

__all__ = ["HELP", "add_arguments", "run"]

HELP = "the paper's re-projection metric and corner errors of a calibration"


def add_arguments(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("data", metavar="DATA", help="a data set (may hold frames the calibration did not use)")
    sp.add_argument("calibration", metavar="CALIBRATION", help="a calibration.yaml")
    sp.add_argument("--out", help="folder for evaluation.yaml (default: print only)")
    add_frames_arguments(sp)
    add_bag_arguments(sp)


def run(args: argparse.Namespace) -> int:
    """The paper's metric and corner errors of a calibration on a data set's frames."""
    from ilcc_graph.app.write import write_evaluation
    from ilcc_graph.cameras import RefinedIntrinsics
    from ilcc_graph.datasets import open_source
    from ilcc_graph.evaluation import evaluation_rows
    from ilcc_graph.io.rig_results import RigCalibration
    from ilcc_graph.io.stored import read_stored
    from ilcc_graph.report.text import evaluation_text
    from ilcc_graph.run.evaluate import evaluate_on

    claim_given(args, reads=[args.data])
    cal = read_stored(Path(args.calibration))  # the one reader and validation of a stored calibration
    if isinstance(cal, RigCalibration):
        raise InputError(
            f"{args.calibration}: a rig's calibration; evaluate judges a single pair's (verify checks a rig)"
        )
    source = open_source(args.data, **bag_options(args))
    lens = (cal.sensors or {}).get("camera_intrinsics")  # the lens as the calibration refined it
    refined = None if lens is None else RefinedIntrinsics.from_entry(lens)
    ev, skipped = evaluate_on(source, cal.T_cam_lidar, stage_options(args), Progress("frames"), refined)
    print(evaluation_text(evaluation_rows(ev), skipped))
    if args.out:
        print(f"wrote {write_evaluation(Path(args.out), ev, command=args.command_line)}")
    return 0
