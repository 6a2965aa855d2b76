"""The ``ilcc-graph`` command line: the only place that decides output folders."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ilcc_graph.errors import (
    EXIT_IMPOSSIBLE,
    EXIT_INPUT,
    CalibrationImpossible,
    IndeterminateSystem,
    InputError,
)

log = logging.getLogger("ilcc_graph")

EXAMPLES = """\
examples:
  ilcc-graph demo                                   simulate the standard panoramic set and calibrate it
  ilcc-graph simulate sim/ --lidar hdl32 --camera equirectangular --frames 20 --seed 0
  ilcc-graph calibrate DATA --out out/run1          scans in DATA/pcd, images in DATA/img, DATA/config.yaml
  ilcc-graph calibrate DATA --refine paper          the paper's refinement (no covariance), for comparison
  ilcc-graph calibrate MON/ TUE/ WED/ --mode rigid  three sessions jointly; tells if the mount moved
  ilcc-graph calibrate DATA --range-offset          also estimate the LiDAR's range offset
  ilcc-graph calibrate DATA --target-sigma 0.05,1   frame by frame (iSAM2) until 0.05 deg / 1 mm
  ilcc-graph lidar-corners DATA --out out/lidar     the LiDAR stage alone: board points, pose, corners
  ilcc-graph image-corners DATA --out out/image     the image stage alone: corners drawn and numbered
  ilcc-graph evaluate DATA2 out/run1/calibration.yaml  the paper's metric on frames not used to calibrate
  ilcc-graph export out/latest/calibration.yaml --format ros-tf

exit codes: 0 success, 2 bad usage or bad input, 3 calibration impossible from the data given
"""


# ----------------------------------------------------------------------------------------------
# Small helpers


class _Progress:
    """One progress-bar helper: a callback (done, total) drawing a tqdm bar on stderr."""

    def __init__(self, desc: str) -> None:
        self.desc = desc
        self.bar = None

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
    """``out`` as given, else ``out/<timestamp>`` with an ``out/latest`` link to it."""
    if out:
        path = Path(out)
        path.mkdir(parents=True, exist_ok=True)
        return path
    path = Path(root) / time.strftime("%Y%m%d-%H%M%S")
    path.mkdir(parents=True, exist_ok=True)
    latest = Path(root) / "latest"
    try:
        if latest.is_symlink() or latest.exists():
            latest.unlink()
        latest.symlink_to(path.name)
    except OSError:
        pass
    return path


def _need_dir(path: str) -> Path:
    p = Path(path)
    if not p.is_dir():
        raise InputError(f"{p}: not a directory (expected a data set with config.yaml, pcd/ and img/)")
    return p


def _print_table(rows: Sequence[Sequence[object]], header: Sequence[str]) -> None:
    cells = [[str(c) for c in header]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    for j, r in enumerate(cells):
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
        if j == 0:
            print("  ".join("-" * w for w in widths))


# ----------------------------------------------------------------------------------------------
# Summaries


def _sigmas(cov: np.ndarray) -> np.ndarray:
    """1-sigma (deg, deg, deg, mm, mm, mm) from a Pose3-tangent covariance (NaN when none)."""
    s = np.sqrt(np.clip(np.diag(cov), 0.0, None)) if np.all(np.isfinite(cov)) else np.full(6, np.nan)
    return np.concatenate([np.degrees(s[:3]), 1e3 * s[3:]])


def summarise(T: np.ndarray, cov: np.ndarray, truth: np.ndarray | None = None) -> str:
    """A short human summary of an extrinsic: matrix, roll/pitch/yaw, translation, 1-sigma values,
    and, when a truth is given, the truth beside each value and the error."""
    import gtsam

    pose = gtsam.Pose3(T)
    rpy = np.degrees(pose.rotation().rpy())
    sig = _sigmas(cov)
    has_cov = bool(np.all(np.isfinite(sig)))
    true_rpy = true_t = None
    if truth is not None:
        true_rpy = np.degrees(gtsam.Pose3(truth).rotation().rpy())
        true_t = 1e3 * np.asarray(truth)[:3, 3]

    def row(name: str, value: float, s: float, true: float | None, fmt: str) -> str:
        text = f"  {name:5s} {value:{fmt}}"
        if has_cov:
            text += f"   sigma {s:.4f}" if fmt.endswith("4f") else f"   sigma {s:.2f}"
        if true is not None:
            text += f"   truth {true:{fmt}}"
        return text

    lines = ["T_cam_lidar (p_cam = R p_lidar + t):"]
    lines += ["  [" + "  ".join(f"{v:+.6f}" for v in row_) + "]" for row_ in T]
    if has_cov:
        lines.append("rotation (deg, Rz(yaw) Ry(pitch) Rx(roll)); 1-sigma about the body axes rx, ry, rz:")
    else:
        lines.append(
            "rotation (deg, Rz(yaw) Ry(pitch) Rx(roll)); no covariance (the paper's refinement gives none):"
        )
    for i, name in enumerate(("roll", "pitch", "yaw")):
        lines.append(row(name, rpy[i], sig[i], None if true_rpy is None else true_rpy[i], "+10.4f"))
    lines.append("translation (mm):")
    for i, name in enumerate("xyz"):
        lines.append(row(name, 1e3 * T[i, 3], sig[3 + i], None if true_t is None else true_t[i], "+10.2f"))
    if truth is not None:
        err = gtsam.Pose3(truth).between(pose)  # T_true^-1 T_est
        rot = np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(err.rotation())))
        trans = 1e3 * np.linalg.norm(T[:3, 3] - truth[:3, 3])
        lines.append(f"against the truth: rotation error {rot:.4f} deg, translation error {trans:.2f} mm")
        if has_cov:
            xi = gtsam.Pose3.Logmap(pose.between(gtsam.Pose3(truth)))  # T_true = T_est Exp(xi)
            nees = float(xi @ np.linalg.solve(cov, xi))
            lines.append(f"  NEES {nees:.2f} (chi-square, 6 dof: 95 % of runs below 12.6)")
    return "\n".join(lines)


def _frames_table(cal) -> None:
    rows = []
    for f in cal.frames:
        rms = "" if f.rms_bearing_error_mrad is None else f"{f.rms_bearing_error_mrad:.3f}"
        rows.append((f.name, "yes" if f.used else "no", rms, f.reason or ""))
    _print_table(rows, ("frame", "used", "rms mrad", "reason"))


# ----------------------------------------------------------------------------------------------
# Commands


def cmd_simulate(args: argparse.Namespace) -> int:
    from ilcc_graph.simulate import simulate_dataset, standard_spec

    spec = standard_spec(
        lidar=args.lidar,
        camera=args.camera,
        width=args.width,
        frames=args.frames,
        seed=args.seed,
        noise_scale=args.noise_scale,
    )
    try:
        out = simulate_dataset(Path(args.out), spec, progress=_Progress("simulate"))
    except FileExistsError as err:
        raise InputError(f"{err}; choose a new folder") from err
    print(f"wrote {spec.n_frames} frames to {out}")
    return 0


def _write_outputs(out: Path, config, cal) -> None:
    from ilcc_graph.config import config_to_dict
    from ilcc_graph.io import write_calibration, write_yaml

    write_yaml(out / "config.resolved.yaml", config_to_dict(config))
    write_calibration(out / "calibration.yaml", cal)


def _write_report(out: Path, data: Path, config, cal, observed, frames, options, args, truth) -> None:
    """OUT/report/index.html with its figures, and OUT/coloured/<frame>.ply (coloured clouds)."""
    from ilcc_graph.io import atomic_write, read_image, read_scan, write_ply
    from ilcc_graph.pipeline import solve_extrinsic
    from ilcc_graph.report import build_report, cross_validate, frames_vs_accuracy

    def solve(subset):
        c = solve_extrinsic(subset, config, options)
        return c.T_cam_lidar, c.covariance

    curve = cv = None
    if args.studies and options.refine == "graph":
        log.info("studies: accuracy against the number of frames, and cross-validation")
        quiet = logging.getLogger("ilcc_graph")
        level = quiet.level
        quiet.setLevel(logging.ERROR)  # subsets of few frames warn by design
        try:
            curve = frames_vs_accuracy(
                observed, solve, config.camera, config.board, truth, progress=_Progress("frames vs accuracy")
            )
            cv = cross_validate(observed, solve, config.camera, config.board, folds=5, T_all=cal.T_cam_lidar)
        finally:
            quiet.setLevel(level)
    sources = ((p.name, read_scan(p.scan, config.intensity_column), read_image(p.image)) for p in frames)

    def coloured(ff, scan) -> None:
        write_ply(out / "coloured" / f"{ff.name}.ply", scan, rgb=ff.coloured.rgb)

    files = build_report(
        cal,
        config.camera,
        config.board,
        sources,
        curve=curve,
        cross_validation=cv,
        T_ground_truth=truth,
        info={"data": str(data), "command": " ".join(sys.argv[1:]) or "ilcc-graph", "refine": options.refine},
        on_frame=coloured,
    )
    for rel, blob in files.items():
        atomic_write(out / "report" / rel, blob)


def _calibrate(data: Path, out: Path, args: argparse.Namespace, truth: np.ndarray | None = None) -> int:
    from ilcc_graph.pipeline import CalibrateOptions, observe_dataset, solve_extrinsic

    options = CalibrateOptions(refine=args.refine, robust=args.robust, jobs=args.jobs)
    t0 = time.perf_counter()
    config, frames, observed = observe_dataset(data, options.jobs, _Progress("frames"))
    cal = solve_extrinsic(observed, config, options)
    _write_outputs(out, config, cal)
    t_cal = time.perf_counter() - t0
    _frames_table(cal)
    print()
    print(summarise(cal.T_cam_lidar, cal.covariance, truth))
    if (vf := cal.diagnostics.get("variance_factor", 1.0)) > 1.0:
        print(
            f"  (the residuals are {vf:.2f} x the stated noise variance: "
            f"sigmas scaled up by {np.sqrt(vf):.2f})"
        )
    n_used = sum(f.used for f in cal.frames)
    print(
        f"\n{n_used} of {len(cal.frames)} frames used; calibrated in {t_cal:.1f} s; "
        f"wrote {out / 'calibration.yaml'}"
    )
    if args.report:
        t1 = time.perf_counter()
        _write_report(out, data, config, cal, observed, frames, options, args, truth)
        print(f"report: {out / 'report' / 'index.html'} ({time.perf_counter() - t1:.1f} s)")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    """The paper's metric and corner errors of a calibration on a data set's frames."""
    from ilcc_graph.io import read_calibration, write_yaml
    from ilcc_graph.pipeline import observe_dataset
    from ilcc_graph.report import eval_frames, evaluate, evaluation_rows, evaluation_to_dict

    data = _need_dir(args.data)
    cal = read_calibration(Path(args.calibration))
    config, _, observed = observe_dataset(data, args.jobs, _Progress("frames"))
    for r in observed:
        if r.board is None or r.corners is None:
            print(f"{r.name}: not evaluated ({r.reason})")
    ev = evaluate(eval_frames(observed), config.camera, config.board, cal.T_cam_lidar)
    header, rows = evaluation_rows(ev)
    _print_table(rows, header)
    if args.out:
        out = _run_dir(args.out)
        write_yaml(out / "evaluation.yaml", evaluation_to_dict(ev))
        print(f"wrote {out / 'evaluation.yaml'}")
    return 0


def _pair(text: str | None, what: str) -> tuple[float, float] | None:
    """'DEG,MM' -> (deg, mm)."""
    if text is None:
        return None
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"{what} expects DEG,MM (e.g. 0.05,1.0), got {text!r}") from None
    return a, b


def _joint_options(args: argparse.Namespace):
    from ilcc_graph.joint import JointOptions

    kw: dict = {"mode": args.mode, "range_offset": args.range_offset, "alpha": args.alpha}
    if (drift := _pair(args.drift_sigma, "--drift-sigma")) is not None:
        kw["drift_sigma_deg"], kw["drift_sigma_mm"] = drift
    if (rep := _pair(args.repeatability, "--repeatability")) is not None:
        kw["repeatability_deg"], kw["repeatability_mm"] = rep
    return JointOptions(**kw)


def _calibrate_sessions(dirs: list[Path], out: Path, args: argparse.Namespace) -> int:
    """Several sessions (or one with --range-offset): the joint graph of ilcc_graph.joint."""
    from ilcc_graph.io import write_calibration, write_yaml
    from ilcc_graph.pipeline import CalibrateOptions
    from ilcc_graph.sessions import calibrate_sessions, format_joint, joint_summary
    from ilcc_graph.types import Calibration

    options = CalibrateOptions(refine="graph", robust=args.robust, jobs=args.jobs)
    bars: dict[str, _Progress] = {}

    def progress(name: str, done: int, total: int) -> None:
        bars.setdefault(name, _Progress(name))(done, total)

    res = calibrate_sessions(dirs, _joint_options(args), options, progress=progress)
    for name in res.names:
        write_calibration(out / "sessions" / name / "calibration.yaml", res.alone[name])
    joint = res.joint.joint
    prefix = len(res.names) > 1
    frames = tuple(
        dataclasses.replace(f, name=f"{name}/{f.name}") if prefix else f
        for name in res.names
        for f in res.alone[name].frames
    )
    cal = Calibration(joint.T, joint.covariance, frames, method=f"joint-{args.mode}")
    write_calibration(out / "calibration.yaml", cal)
    write_yaml(out / "joint.yaml", joint_summary(res.joint))
    print(format_joint(res.joint))
    print()
    print(summarise(joint.T, joint.covariance))
    print(
        f"\nwrote {out / 'calibration.yaml'} (joint), {out / 'joint.yaml'} and each session alone under "
        f"{out / 'sessions'}"
    )
    return 0


def _calibrate_incrementally(data: Path, args: argparse.Namespace) -> int:
    from ilcc_graph.incremental import format_update
    from ilcc_graph.sessions import calibrate_dataset_incrementally

    target = _pair(args.target_sigma, "--target-sigma")
    calibrate_dataset_incrementally(
        data,
        target,
        report=lambda u: print(format_update(u, target), flush=True),
        stop_at_target=args.stop_at_target,
    )
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    dirs = [_need_dir(d) for d in args.data]
    if args.target_sigma is not None or args.stop_at_target:
        if len(dirs) > 1:
            raise InputError("--target-sigma (incremental calibration) takes one data set")
        return _calibrate_incrementally(dirs[0], args)
    if len(dirs) > 1 or args.range_offset:
        if args.refine != "graph":
            raise InputError("--refine paper calibrates one session without a range offset")
        return _calibrate_sessions(dirs, _run_dir(args.out), args)
    return _calibrate(dirs[0], _run_dir(args.out), args)


def cmd_demo(args: argparse.Namespace) -> int:
    from ilcc_graph.io import read_ground_truth
    from ilcc_graph.simulate import simulate_dataset, standard_spec

    spec = standard_spec(lidar="hdl32", camera="equirectangular", width=args.width, frames=20, seed=args.seed)
    data = (
        Path(args.data)
        if args.data
        else Path(args.cache) / f"demo-hdl32-equirect{args.width}-seed{args.seed}"
    )
    if (data / "ground_truth.yaml").is_file():
        print(f"re-using the simulated data set in {data}")
    else:
        print(
            f"simulating the standard panoramic set (HDL-32E, {args.width}x{args.width // 2}, 20 frames) "
            f"into {data}"
        )
        simulate_dataset(data, spec, progress=_Progress("simulate"))
    truth = read_ground_truth(data).T_cam_lidar
    return _calibrate(data, _run_dir(args.out), args, truth)


def _run_stage(args: argparse.Namespace, run: Callable, label: str, **require: bool):
    """A stage command's common part: config (print colour checked), frames, output folder, the
    stage over all frames, and a YAML with the reason for each frame it failed on.

    Returns (frames, unpaired, out, results, rows); rows (frame name -> table row) hold the failed frames.
    """
    from ilcc_graph.config import load_config
    from ilcc_graph.io import list_frames, write_yaml
    from ilcc_graph.pipeline import check_board_colour

    data = _need_dir(args.data)
    config = load_config(data / "config.yaml")
    frames, unpaired = list_frames(data, **require)
    config = check_board_colour(frames, config)  # uses the images where there are any
    out = _run_dir(args.out)
    results = run(frames, config, args.jobs, _Progress(label))
    rows: dict[str, tuple] = {}
    for paths, res in zip(frames, results):
        if isinstance(res, Exception):
            write_yaml(out / f"{paths.name}.yaml", {"name": paths.name, "found": False, "reason": str(res)})
            rows[paths.name] = (paths.name, "no", "", str(res))
    return frames, unpaired, out, results, rows


def _stage_summary(
    frames: list, rows: dict[str, tuple], header: tuple[str, ...], unpaired: list[tuple[str, str]], out: Path
) -> int:
    """The stage commands' closing table (in frame order) and lines."""
    _print_table([rows[p.name] for p in frames], header)
    for stem, why in unpaired:
        print(f"{stem}: skipped ({why})")
    print(f"wrote {out}")
    return 0


def cmd_lidar_corners(args: argparse.Namespace) -> int:
    from ilcc_graph.io import write_pcd, write_yaml
    from ilcc_graph.pipeline import run_lidar_stage
    from ilcc_graph.types import Scan

    frames, unpaired, out, results, rows = _run_stage(args, run_lidar_stage, "lidar", require_image=False)
    for paths, res in zip(frames, results):
        if isinstance(res, Exception):
            continue
        write_yaml(
            out / f"{paths.name}.yaml",
            {
                "name": paths.name,
                "found": True,
                "T_lidar_board": res.T_lidar_board,
                "covariance": res.covariance,
                "sigma": dict(
                    zip(
                        ("rx_deg", "ry_deg", "rz_deg", "tx_mm", "ty_mm", "tz_mm"),
                        _sigmas(res.covariance).round(4).tolist(),
                    )
                ),
                "half_turn_ambiguous": res.half_turn_ambiguous,
                "corners_lidar": res.corners_lidar,
                "n_points": int(len(res.points_lidar)),
                "cost": res.cost,
                "diagnostics": res.diagnostics,
            },
        )
        write_pcd(out / f"{paths.name}_board.pcd", Scan(res.points_lidar, res.intensity))
        rows[paths.name] = (paths.name, "yes", len(res.points_lidar), "")
    return _stage_summary(frames, rows, ("frame", "found", "points", "reason"), unpaired, out)


def cmd_image_corners(args: argparse.Namespace) -> int:
    from ilcc_graph.io import read_image, write_image, write_yaml
    from ilcc_graph.pipeline import run_image_stage
    from ilcc_graph.report.overlays import draw_corners

    frames, unpaired, out, results, rows = _run_stage(args, run_image_stage, "images", require_scan=False)
    for paths, res in zip(frames, results):
        if isinstance(res, Exception):
            rows[paths.name] = (paths.name, "no", "", "", str(res))
            continue
        sig = np.sqrt(np.mean(np.trace(res.cov_px, axis1=1, axis2=2) / 2))
        write_yaml(
            out / f"{paths.name}.yaml",
            {
                "name": paths.name,
                "found": True,
                "detector": res.detector,
                "half_turn_ambiguous": res.half_turn_ambiguous,
                "image_corners": res.uv,
                "bearings": res.bearings,
                "cov_px": res.cov_px,
                "diagnostics": res.diagnostics,
            },
        )
        write_image(out / f"{paths.name}_corners.png", draw_corners(read_image(paths.image), res.uv))
        rows[paths.name] = (paths.name, "yes", res.detector, f"{sig:.3f}", "")
    header = ("frame", "found", "detector", "sigma px", "reason")
    return _stage_summary(frames, rows, header, unpaired, out)


def cmd_export(args: argparse.Namespace) -> int:
    from ilcc_graph.export import export_calibration
    from ilcc_graph.io import atomic_write, read_calibration, read_yaml

    path = Path(args.calibration)
    camera = None
    resolved = path.parent / "config.resolved.yaml"  # written by `calibrate` beside its result
    if resolved.is_file():
        camera = read_yaml(resolved).get("camera")
    options = {}
    if args.format == "ros-tf":
        options = {
            "parent": args.parent,
            "lidar_frame": args.lidar_frame,
            "camera_frame": args.camera_frame,
            "ros": args.ros,
        }
    options = {k: v for k, v in options.items() if v is not None}
    try:
        text = export_calibration(read_calibration(path), args.format, camera=camera, **options)
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

    def solve_args(sp: argparse.ArgumentParser, studies: bool = False) -> None:
        sp.add_argument("--out", help="output folder (default: out/<timestamp>, linked as out/latest)")
        sp.add_argument(
            "--refine",
            choices=("graph", "paper"),
            default="graph",
            help="graph: our factor graph with covariance (default); paper: the paper's refinement",
        )
        sp.add_argument(
            "--robust", choices=("huber", "cauchy"), default=None, help="robust kernel on the bearing factors"
        )
        sp.add_argument("--jobs", type=int, default=jobs, help=f"processes for the per-frame stages ({jobs})")
        sp.add_argument(
            "--no-report",
            dest="report",
            action="store_false",
            help="skip OUT/report/index.html and the coloured clouds",
        )
        sp.add_argument(
            "--studies",
            action=argparse.BooleanOptionalAction,
            default=studies,
            help="add the frames-vs-accuracy and cross-validation studies to the report (re-solve many "
            f"times; default {'on' if studies else 'off'})",
        )

    sp = add(
        "calibrate",
        cmd_calibrate,
        "calibrate from one or more data sets (DATA/config.yaml, DATA/pcd, DATA/img)",
    )
    sp.add_argument("data", nargs="+", metavar="DATA", help="one data set, or several sessions of one rig")
    solve_args(sp)
    g = sp.add_argument_group("several sessions (joint calibration)")
    g.add_argument(
        "--mode",
        choices=("rigid", "drift"),
        default="rigid",
        help="rigid: one extrinsic for all sessions; drift: one per session, tied by --drift-sigma",
    )
    g.add_argument("--drift-sigma", metavar="DEG,MM", help="drift mode: how far the mount may move (0.1,2)")
    g.add_argument(
        "--alpha", type=float, default=0.01, help="false-alarm rate of the mount-moved test (0.01)"
    )
    g.add_argument(
        "--repeatability",
        metavar="DEG,MM",
        help="extra per-session spread the moved test tolerates (default 0,0)",
    )
    g.add_argument(
        "--range-offset",
        action="store_true",
        help="estimate a LiDAR range offset (metres read long) with its sigma",
    )
    g = sp.add_argument_group("incremental (iSAM2)")
    g.add_argument(
        "--target-sigma",
        metavar="DEG,MM",
        help="print the estimate after each frame and say when these 1-sigma values are reached",
    )
    g.add_argument(
        "--stop-at-target", action="store_true", help="stop reading frames once the target is reached"
    )

    sp = add(
        "demo", cmd_demo, "simulate the standard panoramic set (or reuse it), calibrate, compare to truth"
    )
    sp.add_argument("--width", type=int, default=8000, help="panorama width in pixels (default 8000)")
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--data", help="where the simulated set lives (default: under --cache)")
    sp.add_argument(
        "--cache",
        default=os.path.join(os.path.expanduser("~"), ".cache", "ilcc_graph"),
        help="folder for simulated data sets (default ~/.cache/ilcc_graph)",
    )
    solve_args(sp, studies=True)

    sp = add("simulate", cmd_simulate, "write a simulated data set with ground truth")
    sp.add_argument("out", metavar="OUT")
    sp.add_argument("--lidar", default="hdl32", choices=("hdl32", "hdl64", "vlp16", "vlp32c", "os1-64"))
    sp.add_argument("--camera", default="equirectangular", choices=("equirectangular", "pinhole", "fisheye"))
    sp.add_argument("--frames", type=int, default=20)
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--noise-scale", type=float, default=1.0, help="multiplier on the baseline LiDAR noise")
    sp.add_argument("--width", type=int, default=None, help="image width (default 8000 for panoramas)")

    sp = add("lidar-corners", cmd_lidar_corners, "the LiDAR stage alone: board, pose, covariance, corners")
    sp.add_argument("data", metavar="DATA")
    sp.add_argument("--out", help="output folder (default: out/<timestamp>)")
    sp.add_argument("--jobs", type=int, default=jobs)

    sp = add("image-corners", cmd_image_corners, "the image stage alone: corners, uncertainty, drawings")
    sp.add_argument("data", metavar="DATA")
    sp.add_argument("--out", help="output folder (default: out/<timestamp>)")
    sp.add_argument("--jobs", type=int, default=jobs)

    sp = add("evaluate", cmd_evaluate, "the paper's re-projection metric and corner errors of a calibration")
    sp.add_argument("data", metavar="DATA", help="a data set (may hold frames the calibration did not use)")
    sp.add_argument("calibration", metavar="CALIBRATION", help="a calibration.yaml")
    sp.add_argument("--out", help="folder for evaluation.yaml (default: print only)")
    sp.add_argument("--jobs", type=int, default=jobs)

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
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s: %(message)s"
    )
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
