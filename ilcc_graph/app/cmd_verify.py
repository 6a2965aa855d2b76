"""``ilcc-graph verify CALIBRATION NEW_DATA``: does the rig (or pair) still match its calibration?

A short new capture (a few boards) against a stored calibration (a rig's or a single pair's
calibration.yaml): per sensor and axis pass / warn / fail, the estimated change with its sigma, the
smallest change this capture could have detected (``rig_verify``, docs/verify.md). Printed, and
written to the output folder as ``verify.yaml`` and ``verdict.txt`` (the word). The exit status is
the verdict's: 0 pass, 4 warn, 5 fail (1, 2, 3 and the signals' as every command's).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ilcc_graph.app.arguments import add_frames_arguments
from ilcc_graph.app.console import DEG_MM, RATE, Progress
from ilcc_graph.app.flags import stage_options
from ilcc_graph.app.folders import output_folder, written

__all__ = ["HELP", "add_arguments", "run"]

HELP = "check a stored calibration (a rig's or a pair's) against a short new capture"


def add_arguments(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("calibration", metavar="CALIBRATION", help="calibration.yaml (of a rig or a pair)")
    help = "the new capture: a rig folder or file (docs/rig.md), or a single-pair data set"
    sp.add_argument("data", metavar="NEW_DATA", help=help)
    sp.add_argument("--out", help="output folder (default: out/<timestamp>, linked as out/latest)")
    help = "the change that must be detectable for pass (default 0.25,10)"
    sp.add_argument("--tolerance", type=DEG_MM, metavar="DEG,MM", default=(0.25, 10.0), help=help)
    help = "false-alarm rate of fail on an unchanged rig (default 0.05)"
    sp.add_argument("--alpha", type=RATE, default=0.05, help=help)
    help = "detection probability of the smallest detectable change (default 0.95)"
    sp.add_argument("--power", type=RATE, default=0.95, help=help)
    add_frames_arguments(sp)


def run(args: argparse.Namespace) -> int:
    """Verify, print, write verify.yaml and verdict.txt; the verdict's exit status."""
    from ilcc_graph.estimation.verify import VerifyOptions
    from ilcc_graph.io import atomic_write, dump_yaml
    from ilcc_graph.io.output_folders import staged
    from ilcc_graph.run.rig_verify import EXIT_CODES, load_stored, verify_capture, verify_text, verify_to_dict

    out = output_folder(args, reads=[args.data, args.calibration])
    stored = load_stored(Path(args.calibration))
    options = VerifyOptions(args.alpha, args.power, args.tolerance[0], args.tolerance[1])
    res = verify_capture(stored, args.data, options, stage_options(args), Progress("moments"))
    print(verify_text(res))
    with staged(out, command=args.command_line) as d:
        atomic_write(d / "verify.yaml", dump_yaml(verify_to_dict(res, options)))
        atomic_write(d / "verdict.txt", res.result.verdict + "\n")
    written(args, out)
    print(f"wrote {out / 'verify.yaml'}")
    return EXIT_CODES[res.result.verdict]
