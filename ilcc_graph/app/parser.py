"""The parser's shell: description, global flags, examples and exit codes, a subparser per command.

The commands are those of the registry ``commands.COMMANDS``. Pure argparse: each command adds its
own arguments (``cmd_<name>.add_arguments``, from the shared groups of ``arguments``); ``flags``
maps the parsed arguments to options.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from ilcc_graph.app.commands import COMMANDS, Command

__all__ = ["EXAMPLES", "build_parser"]

EXAMPLES = """\
examples:
  ilcc-graph demo                                   simulate the standard panoramic set and calibrate it
  ilcc-graph simulate sim/ --lidar hdl32 --camera equirectangular --frames 20 --seed 0
  ilcc-graph simulate os1/ --lidar os1-64-rev6 --format ouster   Ouster-like organised PCDs, raw signal
  ilcc-graph calibrate DATA --out out/run1          scans in DATA/pcd, images in DATA/img, DATA/config.yaml
  ilcc-graph calibrate run.bag --lidar-topic /os_cloud_node/points --image-topic /camera/image_raw
  ilcc-graph calibrate DATA --refine paper          the paper's refinement (no covariance), for comparison
  ilcc-graph calibrate MON/ TUE/ WED/ --mode rigid  three sessions jointly; tells if the mount moved
  ilcc-graph calibrate DATA --range-offset          also estimate the LiDAR's range offset
  ilcc-graph calibrate DATA --sensor-model none     no sensor-error terms (default auto: chosen per run)
  ilcc-graph calibrate DATA --target-sigma 0.05,1   frame by frame (iSAM2) until 0.05 deg / 1 mm
  ilcc-graph lidar-corners DATA --out out/lidar     the LiDAR stage alone: board points, pose, corners
  ilcc-graph image-corners DATA --out out/image     the image stage alone: corners drawn and numbered
  ilcc-graph evaluate DATA2 out/run1/calibration.yaml  the paper's metric on frames not used to calibrate
  ilcc-graph export out/latest/calibration.yaml --format ros-tf
  ilcc-graph check DATA --watch --target-sigma 0.05,1   judge each frame while a recorder fills DATA
  ilcc-graph simulate-rig rig/ --rig backpack       a simulated rig: a folder per sensor, rig.yaml
  ilcc-graph verify out/rig/calibration.yaml NEW/   has a sensor moved? exit 0 pass, 4 warn, 5 fail

exit codes: 0 success, 1 internal error (a bug; log beside the output), 2 bad usage or bad input,
  3 calibration impossible from the data given, 129/130/143 stopped by SIGHUP/SIGINT/SIGTERM;
  verify: 0 pass, 4 warn, 5 fail
"""


def build_parser(commands: Sequence[Command] = COMMANDS) -> argparse.ArgumentParser:
    """The parser of ``ilcc-graph``: the global flags (``-v``, ``--debug``, also after the command)
    and a subparser per command, its ``run`` as ``args.fn``."""
    p = argparse.ArgumentParser(
        prog="ilcc-graph",
        description="Calibrate a 3D LiDAR against a camera (panoramic, pinhole, fisheye) with a printed "
        "chessboard, and say how sure the result is.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    common = argparse.ArgumentParser(add_help=False)  # -v and --debug, also after the command
    for q, default in ((p, False), (common, argparse.SUPPRESS)):
        q.add_argument("-v", "--verbose", action="store_true", default=default, help="log more detail")
        help = "show an internal error's traceback here (it is always written to a log file)"
        q.add_argument("--debug", action="store_true", default=default, help=help)
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in commands:
        sp = sub.add_parser(command.name, help=command.help, description=command.help, parents=[common])
        sp.set_defaults(fn=command.run)
        command.add_arguments(sp)
    return p
