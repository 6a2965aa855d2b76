"""The command line's arguments: the parser of every command, its help and examples.

Pure argparse: ``build_parser(commands)`` takes each command's function by name (``cli.COMMANDS``);
the argument types are ``console``'s. ``cli`` maps the parsed arguments to options.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable, Mapping

from ilcc_graph.app.console import COUNT, DEG_MM, NON_NEGATIVE, PIXELS, POSITIVE, RATE, SEED

__all__ = ["BAG_OPTIONS", "EXAMPLES", "build_parser"]

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

exit codes: 0 success, 1 internal error (a bug; log beside the output), 2 bad usage or bad input,
  3 calibration impossible from the data given, 129/130/143 stopped by SIGHUP/SIGINT/SIGTERM
"""


BAG_OPTIONS = ("config", "lidar_topic", "image_topic", "sync_tolerance", "min_pause", "select")


def _bag_args(sp: argparse.ArgumentParser) -> None:
    g = sp.add_argument_group("ROS 1 / ROS 2 bags (docs/datasets.md)")
    g.add_argument("--config", help="the bag's config (default: <bag>.yaml or config.yaml beside it)")
    g.add_argument("--lidar-topic", help="PointCloud2 topic (default: the only one)")
    g.add_argument("--image-topic", help="Image or CompressedImage topic (default: the only one)")
    g.add_argument("--sync-tolerance", type=POSITIVE, metavar="S", help="scan-image stamp difference (0.05)")
    g.add_argument("--min-pause", type=NON_NEGATIVE, metavar="S", help="shortest pause giving a frame (1.0)")
    help = "frames: one per still pause, or every scan (default auto: pauses when the recording has them)"
    g.add_argument("--select", choices=("auto", "pauses", "all"), help=help)


def _frames_args(sp: argparse.ArgumentParser, jobs: int) -> None:
    """--jobs and --strict: how the per-frame stages run."""
    sp.add_argument("--jobs", type=COUNT, default=jobs, help=f"processes for the per-frame stages ({jobs})")
    help = "stop at the first frame file that cannot be read (default: skip that frame, say why)"
    sp.add_argument("--strict", action="store_true", help=help)


SENSOR_MODEL_HELP = (
    "the model of the sensors' own errors: auto (default) chooses among none, range and beams by "
    "how well each predicts every board's image from the other boards; none: each board the LiDAR "
    "stage's pose; range: one range offset and the dark-print offset from the returns; beams: "
    "per-beam offsets (as --lidar-errors); offset: one range offset on the boards' poses"
)


def _model_args(sp: argparse.ArgumentParser) -> None:
    """--sensor-model (``estimation.selection``)."""
    choices = ("auto", "none", "range", "beams", "offset")
    sp.add_argument("--sensor-model", choices=choices, default="auto", help=SENSOR_MODEL_HELP)


def _solve_args(sp: argparse.ArgumentParser, jobs: int, studies: bool = False) -> None:
    sp.add_argument("--out", help="output folder (default: out/<timestamp>, linked as out/latest)")
    help = "graph: our factor graph with covariance (default); paper: the paper's refinement"
    sp.add_argument("--refine", choices=("graph", "paper"), default="graph", help=help)
    help = "robust kernel on the bearing factors (default: none, least squares with the chi-square gate)"
    sp.add_argument("--robust", choices=("huber", "cauchy"), help=help)
    _model_args(sp)
    help = "refine the camera's intrinsics (prior: the config's values and camera.intrinsics_sigma)"
    sp.add_argument("--refine-intrinsics", action="store_true", help=help)
    help = "estimate the LiDAR's per-beam and dark-print range offsets from the boards' returns"
    sp.add_argument("--lidar-errors", action="store_true", help=help)
    help = (
        "with --lidar-errors: each board's own plane and beam offsets' sigmas estimated (default), or "
        "fixed (5 mm / 0.4 deg, 2 mm)"
    )
    sp.add_argument("--board-plane", choices=("estimated", "fixed"), help=help)
    _frames_args(sp, jobs)
    sp.add_argument("--no-report", dest="report", action="store_false", help="skip the report")
    sp.add_argument("--clouds", action="store_true", help="with the report: coloured clouds (coloured/)")
    sp.add_argument("--full-views", action="store_true", help="with the report: whole pictures at full size")
    help = (
        f"add frames-vs-accuracy and cross-validation to the report (default: {'on' if studies else 'off'})"
    )
    sp.add_argument("--studies", action=argparse.BooleanOptionalAction, default=studies, help=help)
    help = "also estimate the LiDAR's range offset, one per LiDAR (docs/joint.md)"
    sp.add_argument("--range-offset", action="store_true", help=help)


def build_parser(commands: Mapping[str, Callable[[argparse.Namespace], int]]) -> argparse.ArgumentParser:
    """The parser; ``commands``: each command's function by name (``cli.COMMANDS``)."""
    from ilcc_graph.cameras import camera_kinds
    from ilcc_graph.io.pcd import PCD_STYLES
    from ilcc_graph.lidars.tables import MODEL_NAMES as LIDAR_NAMES

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

    def add(name: str, fn: Callable[[argparse.Namespace], int], help: str) -> argparse.ArgumentParser:
        sp = sub.add_parser(name, help=help, description=help, parents=[common])
        sp.set_defaults(fn=fn)
        return sp

    jobs = max(1, min(2, os.cpu_count() or 1))
    sp = add(
        "calibrate",
        commands["calibrate"],
        "calibrate from data sets (DATA/config.yaml, pcd/, img/) or ROS bags",
    )
    sp.add_argument("data", nargs="+", metavar="DATA", help="data sets or bags (several: sessions of a rig)")
    _solve_args(sp, jobs)
    _bag_args(sp)
    g = sp.add_argument_group("several sessions (joint calibration)")
    help = "rigid (default): one extrinsic for all sessions; drift: one per session, tied by --drift-sigma"
    g.add_argument("--mode", choices=("rigid", "drift"), default="rigid", help=help)
    help = "drift mode: how far the mount may move (default 0.1,2)"
    g.add_argument("--drift-sigma", type=DEG_MM, metavar="DEG,MM", help=help)
    help = "false-alarm rate of the moved-mount test (default 0.01)"
    g.add_argument("--alpha", type=RATE, default=0.01, help=help)
    help = "extra per-session spread the test tolerates (default 0,0)"
    g.add_argument("--repeatability", type=DEG_MM, metavar="DEG,MM", help=help)
    g = sp.add_argument_group("incremental (iSAM2)")
    help = "frame by frame until these 1-sigma values"
    g.add_argument("--target-sigma", type=DEG_MM, metavar="DEG,MM", help=help)
    g.add_argument("--stop-at-target", action="store_true", help="read no frame after the target is reached")

    sp = add(
        "demo", commands["demo"], "simulate the standard panoramic set (or reuse it), calibrate, compare"
    )
    sp.add_argument("--width", type=PIXELS, default=8000, help="panorama width in pixels (default 8000)")
    sp.add_argument("--seed", type=SEED, default=0, help="the simulation's seed (default 0)")
    sp.add_argument("--data", help="where the simulated set lives (default: under --cache)")
    cache = os.path.join(os.path.expanduser("~"), ".cache", "ilcc_graph")
    sp.add_argument("--cache", default=cache, help="folder for simulated data sets (~/.cache/ilcc_graph)")
    _solve_args(sp, jobs, studies=True)

    sp = add("simulate", commands["simulate"], "write a simulated data set with ground truth")
    sp.add_argument("out", metavar="OUT")
    lidars = [m for m in LIDAR_NAMES if m != "generic"]
    sp.add_argument(
        "--lidar",
        default="hdl32",
        choices=lidars,
        metavar="MODEL",
        help=f"{', '.join(lidars)} (default hdl32)",
    )
    help = "plain PCD (default); ouster: organised, ring 0 at the top, raw signal; velodyne-csv: laser_id"
    sp.add_argument("--format", default="plain", choices=("plain", "ouster", "velodyne-csv"), help=help)
    help = "PCD files as this tool writes them (default plain; matlab: pcwrite's header comment, no ring)"
    sp.add_argument("--pcd-style", default="plain", choices=PCD_STYLES, help=help)
    sp.add_argument(
        "--camera", default="equirectangular", choices=camera_kinds(), help="(default equirectangular)"
    )
    sp.add_argument("--frames", type=COUNT, default=20, help="board poses (default 20)")
    sp.add_argument("--seed", type=SEED, default=0, help="the simulation's seed (default 0)")
    sp.add_argument(
        "--noise-scale",
        type=NON_NEGATIVE,
        default=1.0,
        help="multiplier on the baseline LiDAR noise (default 1)",
    )
    sp.add_argument(
        "--width",
        type=PIXELS,
        default=None,
        help="image width (default: the camera kind's, 8000 for a panorama)",
    )
    wrong_k = "config.yaml states intrinsics off by SCALE x a typical error (0.5%% f, 2 px c); 0 = the truth"
    sp.add_argument("--intrinsics-error", type=NON_NEGATIVE, default=0.0, metavar="SCALE", help=wrong_k)
    help = "every range reads MM long (a LiDAR's zero error), on top of the per-beam and dark-print offsets"
    sp.add_argument("--range-offset-mm", type=float, default=0.0, metavar="MM", help=help)

    for name, fn, help in (
        (
            "lidar-corners",
            commands["lidar-corners"],
            "the LiDAR stage alone: board, pose, corners",
        ),
        ("image-corners", commands["image-corners"], "the image stage alone: corners, drawings"),
    ):
        sp = add(name, fn, help)
        sp.add_argument("data", metavar="DATA")
        sp.add_argument("--out", help="output folder (default: out/<timestamp>)")
        _frames_args(sp, jobs)
        _bag_args(sp)

    sp = add(
        "evaluate",
        commands["evaluate"],
        "the paper's re-projection metric and corner errors of a calibration",
    )
    sp.add_argument("data", metavar="DATA", help="a data set (may hold frames the calibration did not use)")
    sp.add_argument("calibration", metavar="CALIBRATION", help="a calibration.yaml")
    sp.add_argument("--out", help="folder for evaluation.yaml (default: print only)")
    _frames_args(sp, jobs)
    _bag_args(sp)

    sp = add(
        "check", commands["check"], "check frames as they are captured: board found, new pose, running sigmas"
    )
    sp.add_argument("data", metavar="DATA", help="a data set folder (with --watch: one being filled)")
    sp.add_argument("--watch", action="store_true", help="follow the folder while it fills; Ctrl-C ends")
    sp.add_argument("--until", type=COUNT, metavar="N", help="stop after N frames")
    help = "stop when every sigma is within DEG / MM"
    sp.add_argument("--target-sigma", type=DEG_MM, metavar="DEG,MM", help=help)
    sp.add_argument("--advise", action="store_true", help="with --watch: the next board pose while waiting")
    _model_args(sp)
    sp.add_argument("--out", help="folder for check.yaml and next_pose.png (default: out/<timestamp>)")

    sp = add("export", commands["export"], "write a calibration in another tool's format")
    sp.add_argument("calibration", metavar="CALIBRATION", help="a calibration.yaml")
    sp.add_argument("--format", required=True, choices=("json", "ros-tf", "kitti", "kalibr", "lidar-offsets"))
    sp.add_argument("--out", help="file to write (default: standard output)")
    sp.add_argument("--parent", choices=("lidar", "camera"), help="ros-tf: the parent frame (default lidar)")
    sp.add_argument("--lidar-frame", help="ros-tf: the LiDAR's frame id (default lidar)")
    help = "ros-tf: the camera's frame id (default camera_optical for a lens camera, camera for a panorama)"
    sp.add_argument("--camera-frame", help=help)
    sp.add_argument("--ros", choices=("both", "ros1", "ros2"), help="ros-tf: which ROS (default both)")
    return p
