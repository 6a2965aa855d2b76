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
from pathlib import Path

import numpy as np

from ilcc_graph.cameras import camera_kinds
from ilcc_graph.errors import (
    EXIT_IMPOSSIBLE,
    EXIT_INPUT,
    CalibrationImpossible,
    IndeterminateSystem,
    InputError,
)
from ilcc_graph.lidars.tables import MODEL_NAMES as LIDAR_NAMES

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


class _Progress:
    """One progress-bar helper: a callback (done, total) drawing a tqdm bar on stderr."""

    def __init__(self, desc: str) -> None:
        self.desc, self.bar = desc, None

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(
                total=total, desc=self.desc, unit="frame", leave=False, file=sys.stderr, disable=None
            )
        self.bar.n = done
        self.bar.refresh()
        if done >= total:
            self.bar.close()


def _run_dir(out: str | None, root: str = "out") -> Path:
    """``out`` as given, else ``out/<timestamp>`` (``_link_latest`` points ``out/latest`` at it)."""
    return Path(out) if out else Path(root) / time.strftime("%Y%m%d-%H%M%S")


def _link_latest(path: Path, given: str | None, root: str = "out") -> None:
    if given:
        return
    latest = Path(root) / "latest"
    try:
        if latest.is_symlink() or latest.exists():
            latest.unlink()
        latest.symlink_to(path.name)
    except OSError:
        pass


def _pair(text: str | None, what: str) -> tuple[float, float] | None:
    """'DEG,MM' -> (deg, mm)."""
    if text is None:
        return None
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"{what} expects DEG,MM (e.g. 0.05,1.0), got {text!r}") from None
    return a, b


def _run_options(args: argparse.Namespace):  # noqa: ANN202 - pipeline.RunOptions
    """The run's options from the arguments (the only mapping from flags to options)."""
    from ilcc_graph.estimation import NoiseOptions
    from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
    from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
    from ilcc_graph.estimation.sessions import JointOptions
    from ilcc_graph.observe import StageOptions
    from ilcc_graph.pipeline import RunOptions

    joint: dict = {
        "mode": getattr(args, "mode", "rigid"),
        "alpha": getattr(args, "alpha", 0.01),
        "range_offset": getattr(args, "range_offset", False),
    }
    if (drift := _pair(getattr(args, "drift_sigma", None), "--drift-sigma")) is not None:
        joint["drift_sigma_deg"], joint["drift_sigma_mm"] = drift
    if (rep := _pair(getattr(args, "repeatability", None), "--repeatability")) is not None:
        joint["repeatability_deg"], joint["repeatability_mm"] = rep
    target = _pair(getattr(args, "target_sigma", None), "--target-sigma")
    stop = bool(getattr(args, "stop_at_target", False))
    mode = "incremental" if target is not None or stop else getattr(args, "refine", "graph")
    if mode != "graph" and (len(getattr(args, "data", [None])) > 1 or joint["range_offset"]):
        raise InputError("--refine paper and --target-sigma calibrate one data set without a range offset")
    return RunOptions(
        lidar_errors=LidarErrorOptions() if getattr(args, "lidar_errors", False) else None,
        intrinsics=IntrinsicsOptions(refine=bool(getattr(args, "refine_intrinsics", False))),
        mode=mode,
        noise=NoiseOptions(robust=getattr(args, "robust", None)),
        stages=StageOptions(jobs=args.jobs),
        joint=JointOptions(**joint),
        target_sigma=target,
        stop_at_target=stop,
    )


# ----------------------------------------------------------------------------------------------
# Commands


def _calibrate(data: Sequence[str], args: argparse.Namespace, truth: np.ndarray | None = None) -> int:
    from ilcc_graph.datasets import open_source
    from ilcc_graph.next_pose import for_run as next_pose_for_run
    from ilcc_graph.outputs import write_run
    from ilcc_graph.pipeline import run
    from ilcc_graph.report.text import format_joint, format_update, frames_table, summarise

    options = _run_options(args)
    sources = [open_source(d, **_bag_options(args)) for d in data]
    bars: dict[str, _Progress] = {}
    t0 = time.perf_counter()
    out = _run_dir(args.out)
    try:
        result = run(
            sources,
            options,
            progress=lambda name, i, n: bars.setdefault(name, _Progress(name))(i, n),
            report=lambda u: print(format_update(u, options.target_sigma), flush=True),
        )
    except CalibrationImpossible as err:  # a short table and one line of advice; details in the folder
        _explain_failure(err, out, args.out)
        raise
    t_cal = time.perf_counter() - t0
    t1 = time.perf_counter()
    advice: dict = {}

    def propose():  # noqa: ANN202 - worked out while the report's pictures are drawn
        advice["next"] = next_pose_for_run(result, options.target_sigma)
        return advice["next"]

    write_run(
        out, result, report=args.report, studies=args.studies, truth=truth, command=" ".join(sys.argv[1:]),
        next_pose=propose, clouds=args.clouds, full_views=args.full_views,
    )  # fmt: skip
    proposal = advice.get("next")
    _link_latest(out, args.out)
    cal = result.calibration
    print(frames_table(cal), "", sep="\n")
    if result.joint is not None:
        print(format_joint(result.joint), "", sep="\n")
    print(summarise(cal.T_cam_lidar, cal.covariance, truth))
    if (vf := cal.diagnostics.get("variance_factor", 1.0)) > 1.0:
        print(f"  (the residuals are {vf:.2f} x the stated noise variance: sigmas x {np.sqrt(vf):.2f})")
    if proposal is not None:
        print(proposal.describe())
    n_used = sum(f.used for f in cal.frames)
    what = "calibration.yaml and the report" if args.report else "calibration.yaml"
    print(
        f"\n{n_used} of {len(cal.frames)} frames used; calibrated in {t_cal:.1f} s; "
        f"wrote {what} to {out} ({time.perf_counter() - t1:.1f} s)"
    )
    return 0


def _explain_failure(err: CalibrationImpossible, out: Path, given: str | None) -> None:
    from ilcc_graph.outputs import write_failure
    from ilcc_graph.report.text import failure_table

    if err.frames:
        print(failure_table(err.frames), file=sys.stderr)
    if err.advice:
        print(f"advice: {err.advice}", file=sys.stderr)
    write_failure(out, err)
    _link_latest(out, given)
    print(f"details: {out / 'failure.yaml'}", file=sys.stderr)


def cmd_calibrate(args: argparse.Namespace) -> int:
    return _calibrate(args.data, args)


def cmd_demo(args: argparse.Namespace) -> int:
    from ilcc_graph.io import read_ground_truth
    from ilcc_graph.simulate import simulate_dataset, standard_spec

    data = (
        Path(args.data)
        if args.data
        else Path(args.cache) / f"demo-hdl32-equirect{args.width}-seed{args.seed}"
    )
    if (data / "ground_truth.yaml").is_file():
        print(f"re-using the simulated data set in {data}")
    else:
        size = f"{args.width}x{args.width // 2}"
        print(f"simulating the standard panoramic set (HDL-32E, {size}, 20 frames) into {data}")
        spec = standard_spec(
            lidar="hdl32", camera="equirectangular", width=args.width, frames=20, seed=args.seed
        )
        simulate_dataset(data, spec, progress=_Progress("simulate"))
    return _calibrate([str(data)], args, read_ground_truth(data).T_cam_lidar)


def cmd_simulate(args: argparse.Namespace) -> int:
    from ilcc_graph.simulate import IntrinsicsError, simulate_dataset, standard_spec

    try:
        spec = standard_spec(
            lidar=args.lidar,
            camera=args.camera,
            width=args.width,
            frames=args.frames,
            seed=args.seed,
            noise_scale=args.noise_scale,
            sensor_format=args.format,
            intrinsics_error=IntrinsicsError.typical(args.intrinsics_error),
        )
    except ValueError as err:
        raise InputError(f"simulate: {err}") from None
    try:
        out = simulate_dataset(Path(args.out), spec, progress=_Progress("simulate"))
    except FileExistsError as err:
        raise InputError(f"{err}; choose a new folder") from err
    print(f"wrote {spec.n_frames} frames to {out}")
    return 0


def _stage_command(args: argparse.Namespace, stage: str, header: tuple[str, ...]) -> int:
    """A stage alone over a data set: one YAML (and a drawing) per frame, and a table."""
    from ilcc_graph.datasets import open_source
    from ilcc_graph.observe import (
        StageOptions,
        check_board_colour,
        resolve_lidar,
        run_image_stage,
        run_lidar_stage,
    )
    from ilcc_graph.outputs import write_stage
    from ilcc_graph.report.text import format_table

    source = open_source(args.data, **_bag_options(args))
    config = source.config()
    refs = source.frames(require_image=stage == "image", require_scan=stage == "lidar")
    config = resolve_lidar(source, refs, config)  # the beam table the scans show
    config, _ = check_board_colour(source, refs, config)  # uses the images where there are any
    fn = run_lidar_stage if stage == "lidar" else run_image_stage
    results = fn(source, refs, config, StageOptions(jobs=args.jobs), _Progress(stage))
    out = _run_dir(args.out)
    rows = write_stage(out, stage, source, refs, results)
    _link_latest(out, args.out)
    print(format_table(rows, header))
    for name, why in source.skipped():
        print(f"{name}: skipped ({why})")
    print(f"wrote {out}")
    return 0


def cmd_lidar_corners(args: argparse.Namespace) -> int:
    return _stage_command(args, "lidar", ("frame", "found", "points", "reason"))


def cmd_image_corners(args: argparse.Namespace) -> int:
    return _stage_command(args, "image", ("frame", "found", "detector", "sigma px", "reason"))


def cmd_evaluate(args: argparse.Namespace) -> int:
    """The paper's metric and corner errors of a calibration on a data set's frames."""
    from ilcc_graph.datasets import open_source
    from ilcc_graph.io import read_calibration, write_yaml
    from ilcc_graph.observe import StageOptions, observe
    from ilcc_graph.report import eval_frames, evaluate, evaluation_rows, evaluation_to_dict
    from ilcc_graph.report.text import format_table

    cal = read_calibration(Path(args.calibration))
    obs = observe(
        open_source(args.data, **_bag_options(args)), StageOptions(jobs=args.jobs), _Progress("frames")
    )
    for r in obs.frames:
        if r.board is None or r.corners is None:
            print(f"{r.name}: not evaluated ({r.reason})")
    ev = evaluate(eval_frames(obs.frames), obs.config.camera, obs.config.board, cal.T_cam_lidar)
    header, rows = evaluation_rows(ev)
    print(format_table(rows, header))
    if args.out:
        write_yaml(Path(args.out) / "evaluation.yaml", evaluation_to_dict(ev))
        print(f"wrote {Path(args.out) / 'evaluation.yaml'}")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    """Per frame as it arrives: board in scan and image, new pose, running sigmas (``live``)."""
    from ilcc_graph.live import CheckOptions
    from ilcc_graph.live_command import check_command
    from ilcc_graph.observe import StageOptions

    target = _pair(args.target_sigma, "--target-sigma")
    options = CheckOptions(
        target_sigma=target,
        until=args.until,
        watch=args.watch,
        stop_at_target=target is not None,
        stages=StageOptions(jobs=1),
    )
    out = _run_dir(args.out)
    code = check_command(args.data, options, out, advise_live=args.advise)
    _link_latest(out, args.out)
    return code


def cmd_export(args: argparse.Namespace) -> int:
    from ilcc_graph.export import export_calibration
    from ilcc_graph.io import atomic_write, read_calibration, read_yaml

    path = Path(args.calibration)
    cal = read_calibration(path)
    camera = cal.camera
    resolved = path.parent / "config.resolved.yaml"  # calibration.yaml of older versions had no camera
    if camera is None and resolved.is_file():
        camera = read_yaml(resolved).get("camera")
    names = ("parent", "lidar_frame", "camera_frame", "ros") if args.format == "ros-tf" else ()
    options = {k: getattr(args, k) for k in names if getattr(args, k) is not None}
    try:
        text = export_calibration(cal, args.format, camera=camera, **options)
    except ValueError as err:
        raise InputError(f"{path}: {err}") from err
    if args.out:
        atomic_write(Path(args.out), text)
        print(f"wrote {args.out}")
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
    g.add_argument("--sync-tolerance", type=float, metavar="S", help="scan-image stamp difference (0.05)")
    g.add_argument("--min-pause", type=float, metavar="S", help="shortest still pause giving a frame (1.0)")
    g.add_argument("--select", choices=("auto", "pauses", "all"), help="frames: one per pause, or all scans")


def _solve_args(sp: argparse.ArgumentParser, jobs: int, studies: bool = False) -> None:
    sp.add_argument("--out", help="output folder (default: out/<timestamp>, linked as out/latest)")
    sp.add_argument(
        "--refine",
        choices=("graph", "paper"),
        default="graph",
        help="graph: our factor graph with covariance (default); paper: the paper's refinement",
    )
    sp.add_argument("--robust", choices=("huber", "cauchy"), help="robust kernel on the bearing factors")
    help = "refine the camera's intrinsics (prior: the config's values and camera.intrinsics_sigma)"
    sp.add_argument("--refine-intrinsics", action="store_true", help=help)
    help = "estimate the LiDAR's per-beam and dark-print range offsets from the boards' returns"
    sp.add_argument("--lidar-errors", action="store_true", help=help)
    sp.add_argument("--jobs", type=int, default=jobs, help=f"processes for the per-frame stages ({jobs})")
    sp.add_argument("--no-report", dest="report", action="store_false", help="skip the report")
    sp.add_argument("--clouds", action="store_true", help="with the report: coloured clouds (coloured/)")
    sp.add_argument("--full-views", action="store_true", help="with the report: whole pictures at full size")
    help = "add frames-vs-accuracy and cross-validation to the report"
    sp.add_argument("--studies", action=argparse.BooleanOptionalAction, default=studies, help=help)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ilcc-graph",
        description="Calibrate a 3D LiDAR against a camera (panoramic, pinhole, fisheye) with a printed "
        "chessboard, and say how sure the result is.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log more detail")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)

    def add(name: str, fn: Callable[[argparse.Namespace], int], help: str) -> argparse.ArgumentParser:
        sp = sub.add_parser(name, help=help, description=help)
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
    g.add_argument("--drift-sigma", metavar="DEG,MM", help="drift mode: how far the mount may move (0.1,2)")
    g.add_argument("--alpha", type=float, default=0.01, help="false-alarm rate of the moved-mount test")
    g.add_argument("--repeatability", metavar="DEG,MM", help="extra per-session spread the test tolerates")
    g.add_argument("--range-offset", action="store_true", help="estimate the LiDAR's range offset")
    g = sp.add_argument_group("incremental (iSAM2)")
    g.add_argument("--target-sigma", metavar="DEG,MM", help="frame by frame until these 1-sigma values")
    g.add_argument("--stop-at-target", action="store_true", help="read no frame after the target is reached")

    sp = add("demo", cmd_demo, "simulate the standard panoramic set (or reuse it), calibrate, compare")
    sp.add_argument("--width", type=int, default=8000, help="panorama width in pixels (default 8000)")
    sp.add_argument("--seed", type=int, default=0)
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
    sp.add_argument("--frames", type=int, default=20)
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--noise-scale", type=float, default=1.0, help="multiplier on the baseline LiDAR noise")
    sp.add_argument("--width", type=int, default=None, help="image width (default 8000 for panoramas)")
    wrong_k = "config.yaml states intrinsics off by SCALE x a typical error (0.5%% f, 2 px c); 0 = the truth"
    sp.add_argument("--intrinsics-error", type=float, default=0.0, metavar="SCALE", help=wrong_k)

    for name, fn, help in (
        ("lidar-corners", cmd_lidar_corners, "the LiDAR stage alone: board, pose, covariance, corners"),
        ("image-corners", cmd_image_corners, "the image stage alone: corners, uncertainty, drawings"),
    ):
        sp = add(name, fn, help)
        sp.add_argument("data", metavar="DATA")
        sp.add_argument("--out", help="output folder (default: out/<timestamp>)")
        sp.add_argument("--jobs", type=int, default=jobs)
        _bag_args(sp)

    sp = add("evaluate", cmd_evaluate, "the paper's re-projection metric and corner errors of a calibration")
    sp.add_argument("data", metavar="DATA", help="a data set (may hold frames the calibration did not use)")
    sp.add_argument("calibration", metavar="CALIBRATION", help="a calibration.yaml")
    sp.add_argument("--out", help="folder for evaluation.yaml (default: print only)")
    sp.add_argument("--jobs", type=int, default=jobs)
    _bag_args(sp)

    sp = add("check", cmd_check, "check frames as they are captured: board found, new pose, running sigmas")
    sp.add_argument("data", metavar="DATA", help="a data set folder (with --watch: one being filled)")
    sp.add_argument("--watch", action="store_true", help="follow the folder while it fills; Ctrl-C ends")
    sp.add_argument("--until", type=int, metavar="N", help="stop after N frames")
    sp.add_argument("--target-sigma", metavar="DEG,MM", help="stop when every sigma is within DEG / MM")
    sp.add_argument("--advise", action="store_true", help="with --watch: the next board pose while waiting")
    sp.add_argument("--out", help="folder for check.yaml and next_pose.png (default: out/<timestamp>)")

    sp = add("export", cmd_export, "write a calibration in another tool's format")
    sp.add_argument("calibration", metavar="CALIBRATION", help="a calibration.yaml")
    sp.add_argument("--format", required=True, choices=("json", "ros-tf", "kitti", "kalibr"))
    sp.add_argument("--out", help="file to write (default: standard output)")
    sp.add_argument("--parent", choices=("lidar", "camera"), help="ros-tf: the parent frame (default lidar)")
    sp.add_argument("--lidar-frame", help="ros-tf: the LiDAR's frame id (default lidar)")
    sp.add_argument("--camera-frame", help="ros-tf: the camera's frame id (default camera)")
    sp.add_argument("--ros", choices=("both", "ros1", "ros2"), help="ros-tf: which ROS (default both)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    level = logging.DEBUG if args.verbose else logging.INFO
    logging.basicConfig(level=level, format="%(levelname)s: %(message)s")
    try:
        return args.fn(args)
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_INPUT
    except (CalibrationImpossible, IndeterminateSystem) as err:
        print(f"calibration impossible: {err}", file=sys.stderr)
        return EXIT_IMPOSSIBLE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
