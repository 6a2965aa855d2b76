"""``ilcc-graph check``: each frame judged as it is captured (board found, new pose, running sigmas).

What is shown and written is ``check_view``, the check itself ``live``.
"""

from __future__ import annotations

import argparse

from ilcc_graph.app.arguments import add_cache_argument, add_sensor_model_argument
from ilcc_graph.app.console import COUNT, DEG_MM
from ilcc_graph.app.flags import check_options
from ilcc_graph.app.folders import output_folder, written

__all__ = ["HELP", "add_arguments", "run"]

HELP = "check frames as they are captured: board found, new pose, running sigmas"


def add_arguments(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("data", metavar="DATA", help="a data set folder (with --watch: one being filled)")
    sp.add_argument("--watch", action="store_true", help="follow the folder while it fills; Ctrl-C ends")
    sp.add_argument("--until", type=COUNT, metavar="N", help="stop after N frames")
    help = "stop when every sigma is within DEG / MM"
    sp.add_argument("--target-sigma", type=DEG_MM, metavar="DEG,MM", help=help)
    sp.add_argument("--advise", action="store_true", help="with --watch: the next board pose while waiting")
    add_sensor_model_argument(sp)
    add_cache_argument(sp)
    sp.add_argument("--out", help="folder for check.yaml and next_pose.png (default: out/<timestamp>)")


def run(args: argparse.Namespace) -> int:
    """Per frame as it arrives: board in scan and image, new pose, running sigmas (``live``)."""
    from ilcc_graph.app.check_view import check_command

    options = check_options(args)
    out = output_folder(args, [args.data])
    code = check_command(args.data, options, out, advise_live=args.advise, command=args.command_line)
    written(args, out)
    return code
