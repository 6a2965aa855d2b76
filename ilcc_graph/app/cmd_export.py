"""``ilcc-graph export``: a calibration in another tool's format (``export``), to a file or stdout."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ilcc_graph.app.console import lazy_choices
from ilcc_graph.errors import InputError

if TYPE_CHECKING:
    from ilcc_graph.io.rig_results import RigCalibration

__all__ = ["HELP", "add_arguments", "run"]

HELP = "write a calibration in another tool's format"


def _formats() -> tuple[str, ...]:
    """Every export format: a pair's (``exports.FORMATS``), then a rig's not among them
    (``exports_rig.RIG_FORMATS``)."""
    from ilcc_graph.exports import FORMATS
    from ilcc_graph.exports_rig import RIG_FORMATS

    return FORMATS + tuple(f for f in RIG_FORMATS if f not in FORMATS)


def add_arguments(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("calibration", metavar="CALIBRATION", help="a calibration.yaml (of a pair or a rig)")
    help = "a rig's calibration: ros-tf (a launch file), urdf, kalibr or json (docs/rig.md)"
    lazy_choices(sp.add_argument("--format", required=True, help=help), _formats)
    sp.add_argument("--out", help="file to write (default: standard output)")
    sp.add_argument("--parent", choices=("lidar", "camera"), help="ros-tf: the parent frame (default lidar)")
    sp.add_argument("--lidar-frame", help="ros-tf: the LiDAR's frame id (default lidar)")
    help = "ros-tf: the camera's frame id (default camera_optical for a lens camera, camera for a panorama)"
    sp.add_argument("--camera-frame", help=help)
    sp.add_argument("--ros", choices=("both", "ros1", "ros2"), help="ros-tf: which ROS (default both)")


def run(args: argparse.Namespace) -> int:
    from ilcc_graph.exports import export_calibration
    from ilcc_graph.io.rig_results import RigCalibration
    from ilcc_graph.io.stored import read_stored

    cal = read_stored(args.calibration)  # the one reader and validation of a stored calibration
    if isinstance(cal, RigCalibration):
        return _rig(args, cal)
    if args.format == "urdf":
        raise InputError(f"{args.calibration}: urdf is an export of a rig's calibration (docs/rig.md)")
    names = ("parent", "lidar_frame", "camera_frame", "ros") if args.format == "ros-tf" else ()
    options = {k: getattr(args, k) for k in names if getattr(args, k)}
    if args.format == "lidar-offsets":  # a table: CSV when the output file says so
        options["table"] = "csv" if args.out and Path(args.out).suffix.lower() == ".csv" else "yaml"
    return _emit(args, lambda: export_calibration(cal, args.format, **options))


def _rig(args: argparse.Namespace, cal: RigCalibration) -> int:
    """A rig's calibration.yaml in one of ``exports_rig.RIG_FORMATS``."""
    from ilcc_graph.exports_rig import RIG_FORMATS, export_rig

    if args.format not in RIG_FORMATS:
        raise InputError(
            f"{args.calibration}: a rig's calibration exports as {', '.join(RIG_FORMATS)}, not {args.format}"
        )
    return _emit(args, lambda: export_rig(cal, args.format))


def _emit(args: argparse.Namespace, export: Callable[[], str]) -> int:
    """The text ``export()`` makes to ``--out`` or stdout; its ValueError is the calibration's problem."""
    from ilcc_graph.io.output_folders import write_file

    try:
        text = export()
    except ValueError as err:
        raise InputError(f"{args.calibration}: {err}") from None
    if args.out:
        print(f"wrote {write_file(Path(args.out), text)}")
    else:
        sys.stdout.write(text)
    return 0
