"""The ``ilcc-graph`` command line: arguments -> options -> run -> outputs.

The only place that decides output folders. Everything else is in ``pipeline`` (the run),
``outputs`` (what is written) and ``report.text`` (what is printed).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

from ilcc_graph import signals
from ilcc_graph.console import (
    COUNT,
    DEG_MM,
    NON_NEGATIVE,
    PIXELS,
    POSITIVE,
    RATE,
    SEED,
    Progress,
    run_command,
    setup_logging,
)
from ilcc_graph.errors import CalibrationImpossible, InputError

if TYPE_CHECKING:
    import numpy as np

log = logging.getLogger("ilcc_graph")

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
  ilcc-graph calibrate DATA --target-sigma 0.05,1   frame by frame (iSAM2) until 0.05 deg / 1 mm
  ilcc-graph lidar-corners DATA --out out/lidar     the LiDAR stage alone: board points, pose, corners
  ilcc-graph image-corners DATA --out out/image     the image stage alone: corners drawn and numbered
  ilcc-graph evaluate DATA2 out/run1/calibration.yaml  the paper's metric on frames not used to calibrate
  ilcc-graph export out/latest/calibration.yaml --format ros-tf
  ilcc-graph check DATA --watch --target-sigma 0.05,1   judge each frame while a recorder fills DATA

exit codes: 0 success, 2 bad usage or bad input, 3 calibration impossible from the data given
"""


def _run_dir(args: argparse.Namespace, root: str = "out") -> Path:
    """``--out`` as given, else ``out/<timestamp>`` (linked as ``out/latest`` once written); checked
    now, before a long run."""
    from ilcc_graph.outputs import check_output

    out = Path(args.out) if args.out else Path(root) / time.strftime("%Y%m%d-%H%M%S")
    check_output(out)
    args.out_dir = out  # where an internal error's log goes (main)
    return out


def _run_options(args: argparse.Namespace):  # noqa: ANN202 - pipeline.RunOptions
    """The run's options from the arguments (the only mapping from flags to options)."""
    from ilcc_graph.estimation import NoiseOptions
    from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
    from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
    from ilcc_graph.estimation.sessions import JointOptions
    from ilcc_graph.pipeline import RunOptions

    joint: dict = {
        "mode": getattr(args, "mode", "rigid"),
        "alpha": getattr(args, "alpha", 0.01),
        "range_offset": getattr(args, "range_offset", False),
    }
    if (drift := getattr(args, "drift_sigma", None)) is not None:
        joint["drift_sigma_deg"], joint["drift_sigma_mm"] = drift
    if (rep := getattr(args, "repeatability", None)) is not None:
        joint["repeatability_deg"], joint["repeatability_mm"] = rep
    target = getattr(args, "target_sigma", None)
    stop = bool(getattr(args, "stop_at_target", False))
    mode = "incremental" if target is not None or stop else getattr(args, "refine", "graph")
    if mode != "graph" and (len(getattr(args, "data", [None])) > 1 or joint["range_offset"]):
        raise InputError("--refine paper and --target-sigma calibrate one data set without a range offset")
    return RunOptions(
        lidar_errors=LidarErrorOptions() if getattr(args, "lidar_errors", False) else None,
        intrinsics=IntrinsicsOptions(refine=bool(getattr(args, "refine_intrinsics", False))),
        mode=mode,
        noise=NoiseOptions(robust=getattr(args, "robust", None)),
        stages=_stage_options(args),
        joint=JointOptions(**joint),
        target_sigma=target,
        stop_at_target=stop,
    )


def _stage_options(args: argparse.Namespace):  # noqa: ANN202 - observe.StageOptions
    from ilcc_graph.observe import StageOptions

    return StageOptions(jobs=args.jobs, strict=bool(getattr(args, "strict", False)))


# ----------------------------------------------------------------------------------------------
# Commands: each maps its arguments and calls into the package


def _calibrate(data: Sequence[str], args: argparse.Namespace, truth: np.ndarray | None = None) -> int:
    from ilcc_graph.datasets import open_source
    from ilcc_graph.next_pose import for_run as next_pose_for_run
    from ilcc_graph.outputs import link_latest, write_run
    from ilcc_graph.pipeline import run
    from ilcc_graph.report.text import format_update, run_summary

    options = _run_options(args)
    out = _run_dir(args)
    sources = [open_source(d, **_bag_options(args)) for d in data]
    bars: dict[str, Progress] = {}
    t0 = time.perf_counter()
    try:
        result = run(
            sources,
            options,
            progress=lambda name, i, n: bars.setdefault(name, Progress(name))(i, n),
            report=lambda u: print(format_update(u, options.target_sigma), flush=True),
        )
    except CalibrationImpossible as err:  # a short table and one line of advice; details in the folder
        _explain_failure(err, out)
        raise
    t1 = time.perf_counter()
    advice: dict = {}

    def propose():  # noqa: ANN202 - worked out while the report's pictures are drawn
        advice["next"] = next_pose_for_run(result, options.target_sigma)
        return advice["next"]

    write_run(
        out, result, report=args.report, studies=args.studies, truth=truth, command=" ".join(sys.argv[1:]),
        next_pose=propose, clouds=args.clouds, full_views=args.full_views,
    )  # fmt: skip
    if not args.out:
        link_latest(out)
    seconds = (t1 - t0, time.perf_counter() - t1)
    notes = [advice["next"].describe()] if advice.get("next") is not None else []
    print(run_summary(result.calibration, result.joint, truth, out, seconds, args.report, notes))
    return 0


def _explain_failure(err: CalibrationImpossible, out: Path) -> None:
    """A failed run: its frames as a short table and the advice on stderr, the details in a file."""
    from ilcc_graph.outputs import write_failure
    from ilcc_graph.report.text import failure_table

    if err.frames:
        print(failure_table(err.frames), file=sys.stderr)
    if err.advice:  # one line of advice, or the likely set-up mistakes (``likely: ...`` lines)
        print(err.advice if err.advice.startswith("likely: ") else f"advice: {err.advice}", file=sys.stderr)
    print(f"details: {write_failure(out, err)}", file=sys.stderr)


def cmd_calibrate(args: argparse.Namespace) -> int:
    return _calibrate(args.data, args)


def cmd_demo(args: argparse.Namespace) -> int:
    from ilcc_graph.io import read_ground_truth
    from ilcc_graph.simulate.export import write_standard_set

    data = Path(args.data or Path(args.cache) / f"demo-hdl32-equirect{args.width}-seed{args.seed}")
    if not (data / "ground_truth.yaml").is_file():
        print(f"simulating the standard panoramic set (HDL-32E, {args.width} px wide, 20 frames) into {data}")
        kw = {"lidar": "hdl32", "camera": "equirectangular", "frames": 20}
        write_standard_set(data, Progress("simulate"), width=args.width, seed=args.seed, **kw)
    return _calibrate([str(data)], args, read_ground_truth(data).T_cam_lidar)


def cmd_simulate(args: argparse.Namespace) -> int:
    from ilcc_graph.simulate.export import write_standard_set

    names = ("lidar", "camera", "width", "frames", "seed", "noise_scale", "intrinsics_error")
    spec = write_standard_set(
        args.out, Progress("simulate"), sensor_format=args.format, **{k: getattr(args, k) for k in names}
    )
    print(f"wrote {spec.n_frames} frames to {args.out}")
    return 0


def _stage_command(args: argparse.Namespace, stage: str) -> int:
    """A stage alone over a data set: one YAML (and a drawing) per frame, and a table."""
    from ilcc_graph.datasets import open_source
    from ilcc_graph.observe import stage_alone
    from ilcc_graph.outputs import link_latest, write_stage
    from ilcc_graph.report.text import stage_table

    out = _run_dir(args)
    source = open_source(args.data, **_bag_options(args))
    _, refs, results = stage_alone(source, stage, _stage_options(args), Progress(stage))
    rows = write_stage(out, stage, source, refs, results)
    if not args.out:
        link_latest(out)
    print(stage_table(stage, rows, source.skipped(), out))
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    """The paper's metric and corner errors of a calibration on a data set's frames."""
    from ilcc_graph.datasets import open_source
    from ilcc_graph.evaluation import evaluate_on
    from ilcc_graph.io import read_calibration
    from ilcc_graph.outputs import check_output, write_evaluation
    from ilcc_graph.report import evaluation_rows
    from ilcc_graph.report.text import evaluation_text

    if args.out:
        check_output(Path(args.out))
    cal = read_calibration(Path(args.calibration))
    source = open_source(args.data, **_bag_options(args))
    ev, skipped = evaluate_on(source, cal.T_cam_lidar, _stage_options(args), Progress("frames"))
    print(evaluation_text(evaluation_rows(ev), skipped))
    if args.out:
        print(f"wrote {write_evaluation(Path(args.out), ev)}")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    """Per frame as it arrives: board in scan and image, new pose, running sigmas (``live``)."""
    from ilcc_graph.live import CheckOptions
    from ilcc_graph.live_command import check_command
    from ilcc_graph.observe import StageOptions
    from ilcc_graph.outputs import link_latest

    target = args.target_sigma
    options = CheckOptions(
        target_sigma=target,
        until=args.until,
        watch=args.watch,
        stop_at_target=target is not None,
        stages=StageOptions(jobs=1),
    )
    out = _run_dir(args)
    code = check_command(args.data, options, out, advise_live=args.advise)
    if not args.out:
        link_latest(out)
    return code


def cmd_export(args: argparse.Namespace) -> int:
    from ilcc_graph.export import export_calibration
    from ilcc_graph.io import read_calibration_with_camera
    from ilcc_graph.outputs import write_file

    cal = read_calibration_with_camera(args.calibration)
    names = ("parent", "lidar_frame", "camera_frame", "ros") if args.format == "ros-tf" else ()
    options = {k: getattr(args, k) for k in names if getattr(args, k)}
    if args.format == "lidar-offsets":  # a table: CSV when the output file says so
        options["table"] = "csv" if args.out and Path(args.out).suffix.lower() == ".csv" else "yaml"
    try:
        text = export_calibration(cal, args.format, **options)
    except ValueError as err:
        raise InputError(f"{args.calibration}: {err}") from None
    if args.out:
        print(f"wrote {write_file(Path(args.out), text)}")
    else:
        sys.stdout.write(text)
    return 0


# ----------------------------------------------------------------------------------------------
# Parser and entry point

_BAG_OPTIONS = ("config", "lidar_topic", "image_topic", "sync_tolerance", "min_pause", "select")


def _bag_options(args: argparse.Namespace) -> dict:
    return {k: getattr(args, k, None) for k in _BAG_OPTIONS}


def _bag_args(sp: argparse.ArgumentParser) -> None:
    g = sp.add_argument_group("ROS 1 / ROS 2 bags (docs/datasets.md)")
    g.add_argument("--config", help="the bag's config (default: <bag>.yaml or config.yaml beside it)")
    g.add_argument("--lidar-topic", help="PointCloud2 topic (default: the only one)")
    g.add_argument("--image-topic", help="Image or CompressedImage topic (default: the only one)")
    g.add_argument("--sync-tolerance", type=POSITIVE, metavar="S", help="scan-image stamp difference (0.05)")
    g.add_argument("--min-pause", type=NON_NEGATIVE, metavar="S", help="shortest pause giving a frame (1.0)")
    g.add_argument("--select", choices=("auto", "pauses", "all"), help="frames: one per pause, or all scans")


def _frames_args(sp: argparse.ArgumentParser, jobs: int) -> None:
    """--jobs and --strict: how the per-frame stages run."""
    sp.add_argument("--jobs", type=COUNT, default=jobs, help=f"processes for the per-frame stages ({jobs})")
    help = "stop at the first frame file that cannot be read (default: skip that frame, say why)"
    sp.add_argument("--strict", action="store_true", help=help)


def _solve_args(sp: argparse.ArgumentParser, jobs: int, studies: bool = False) -> None:
    sp.add_argument("--out", help="output folder (default: out/<timestamp>, linked as out/latest)")
    help = "graph: our factor graph with covariance (default); paper: the paper's refinement"
    sp.add_argument("--refine", choices=("graph", "paper"), default="graph", help=help)
    sp.add_argument("--robust", choices=("huber", "cauchy"), help="robust kernel on the bearing factors")
    help = "refine the camera's intrinsics (prior: the config's values and camera.intrinsics_sigma)"
    sp.add_argument("--refine-intrinsics", action="store_true", help=help)
    help = "estimate the LiDAR's per-beam and dark-print range offsets from the boards' returns"
    sp.add_argument("--lidar-errors", action="store_true", help=help)
    _frames_args(sp, jobs)
    sp.add_argument("--no-report", dest="report", action="store_false", help="skip the report")
    sp.add_argument("--clouds", action="store_true", help="with the report: coloured clouds (coloured/)")
    sp.add_argument("--full-views", action="store_true", help="with the report: whole pictures at full size")
    help = "add frames-vs-accuracy and cross-validation to the report"
    sp.add_argument("--studies", action=argparse.BooleanOptionalAction, default=studies, help=help)


def build_parser() -> argparse.ArgumentParser:
    from ilcc_graph.cameras import camera_kinds
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
        "calibrate", cmd_calibrate, "calibrate from data sets (DATA/config.yaml, pcd/, img/) or ROS bags"
    )
    sp.add_argument("data", nargs="+", metavar="DATA", help="data sets or bags (several: sessions of a rig)")
    _solve_args(sp, jobs)
    _bag_args(sp)
    g = sp.add_argument_group("several sessions (joint calibration)")
    help = "rigid: one extrinsic for all sessions; drift: one per session, tied by --drift-sigma"
    g.add_argument("--mode", choices=("rigid", "drift"), default="rigid", help=help)
    help = "drift mode: how far the mount may move (0.1,2)"
    g.add_argument("--drift-sigma", type=DEG_MM, metavar="DEG,MM", help=help)
    g.add_argument("--alpha", type=RATE, default=0.01, help="false-alarm rate of the moved-mount test")
    help = "extra per-session spread the test tolerates"
    g.add_argument("--repeatability", type=DEG_MM, metavar="DEG,MM", help=help)
    g.add_argument("--range-offset", action="store_true", help="estimate the LiDAR's range offset")
    g = sp.add_argument_group("incremental (iSAM2)")
    help = "frame by frame until these 1-sigma values"
    g.add_argument("--target-sigma", type=DEG_MM, metavar="DEG,MM", help=help)
    g.add_argument("--stop-at-target", action="store_true", help="read no frame after the target is reached")

    sp = add("demo", cmd_demo, "simulate the standard panoramic set (or reuse it), calibrate, compare")
    sp.add_argument("--width", type=PIXELS, default=8000, help="panorama width in pixels (default 8000)")
    sp.add_argument("--seed", type=SEED, default=0)
    sp.add_argument("--data", help="where the simulated set lives (default: under --cache)")
    cache = os.path.join(os.path.expanduser("~"), ".cache", "ilcc_graph")
    sp.add_argument("--cache", default=cache, help="folder for simulated data sets (~/.cache/ilcc_graph)")
    _solve_args(sp, jobs, studies=True)

    sp = add("simulate", cmd_simulate, "write a simulated data set with ground truth")
    sp.add_argument("out", metavar="OUT")
    sp.add_argument("--lidar", default="hdl32", choices=[m for m in LIDAR_NAMES if m != "generic"])
    help = "plain PCD; ouster: organised, ring 0 at the top, raw signal; velodyne-csv: hardware laser_id"
    sp.add_argument("--format", default="plain", choices=("plain", "ouster", "velodyne-csv"), help=help)
    sp.add_argument("--camera", default="equirectangular", choices=camera_kinds())
    sp.add_argument("--frames", type=COUNT, default=20)
    sp.add_argument("--seed", type=SEED, default=0)
    sp.add_argument(
        "--noise-scale", type=NON_NEGATIVE, default=1.0, help="multiplier on the baseline LiDAR noise"
    )
    sp.add_argument("--width", type=PIXELS, default=None, help="image width (default 8000 for panoramas)")
    wrong_k = "config.yaml states intrinsics off by SCALE x a typical error (0.5%% f, 2 px c); 0 = the truth"
    sp.add_argument("--intrinsics-error", type=NON_NEGATIVE, default=0.0, metavar="SCALE", help=wrong_k)

    for name, fn, help in (
        (
            "lidar-corners",
            partial(_stage_command, stage="lidar"),
            "the LiDAR stage alone: board, pose, corners",
        ),
        ("image-corners", partial(_stage_command, stage="image"), "the image stage alone: corners, drawings"),
    ):
        sp = add(name, fn, help)
        sp.add_argument("data", metavar="DATA")
        sp.add_argument("--out", help="output folder (default: out/<timestamp>)")
        _frames_args(sp, jobs)
        _bag_args(sp)

    sp = add("evaluate", cmd_evaluate, "the paper's re-projection metric and corner errors of a calibration")
    sp.add_argument("data", metavar="DATA", help="a data set (may hold frames the calibration did not use)")
    sp.add_argument("calibration", metavar="CALIBRATION", help="a calibration.yaml")
    sp.add_argument("--out", help="folder for evaluation.yaml (default: print only)")
    _frames_args(sp, jobs)
    _bag_args(sp)

    sp = add("check", cmd_check, "check frames as they are captured: board found, new pose, running sigmas")
    sp.add_argument("data", metavar="DATA", help="a data set folder (with --watch: one being filled)")
    sp.add_argument("--watch", action="store_true", help="follow the folder while it fills; Ctrl-C ends")
    sp.add_argument("--until", type=COUNT, metavar="N", help="stop after N frames")
    help = "stop when every sigma is within DEG / MM"
    sp.add_argument("--target-sigma", type=DEG_MM, metavar="DEG,MM", help=help)
    sp.add_argument("--advise", action="store_true", help="with --watch: the next board pose while waiting")
    sp.add_argument("--out", help="folder for check.yaml and next_pose.png (default: out/<timestamp>)")

    sp = add("export", cmd_export, "write a calibration in another tool's format")
    sp.add_argument("calibration", metavar="CALIBRATION", help="a calibration.yaml")
    sp.add_argument("--format", required=True, choices=("json", "ros-tf", "kitti", "kalibr", "lidar-offsets"))
    sp.add_argument("--out", help="file to write (default: standard output)")
    sp.add_argument("--parent", choices=("lidar", "camera"), help="ros-tf: the parent frame (default lidar)")
    sp.add_argument("--lidar-frame", help="ros-tf: the LiDAR's frame id (default lidar)")
    sp.add_argument("--camera-frame", help="ros-tf: the camera's frame id (default camera)")
    sp.add_argument("--ros", choices=("both", "ros1", "ros2"), help="ros-tf: which ROS (default both)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = argparse.Namespace(debug="--debug" in (sys.argv[1:] if argv is None else argv))

    def command() -> int:  # under the signal handlers from the first import on
        nonlocal args
        args = build_parser().parse_args(argv)
        setup_logging(args.verbose)
        return args.fn(args)

    code = run_command(command, lambda: getattr(args, "out_dir", None), lambda: args.debug)
    if signals.stop_requested() is not None:
        signals.exit_now(code)  # after a stop: no interpreter teardown (signals.exit_now)
    return code


if __name__ == "__main__":
    sys.exit(main())
