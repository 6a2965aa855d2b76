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
from ilcc_graph.app import parser as cli_parser
from ilcc_graph.app.console import Progress, run_command, setup_logging
from ilcc_graph.app.parser import BAG_OPTIONS
from ilcc_graph.errors import CalibrationImpossible, InputError

if TYPE_CHECKING:
    import numpy as np

log = logging.getLogger("ilcc_graph")


def _run_dir(args: argparse.Namespace, reads: Sequence[str | Path] = (), root: str = "out") -> Path:
    """``--out`` as given (a link: its target), else ``out/<timestamp>`` (linked as ``out/latest``
    once written); claimed now, before a long run: new, empty or an earlier result of ours, and not
    a data set the command ``reads`` (``folders.claim_output``)."""
    from ilcc_graph.app.write import claim_output

    out = getattr(args, "out_dir", None) or (
        Path(args.out) if args.out else Path(root) / time.strftime("%Y%m%d-%H%M%S")
    )
    out = claim_output(out, reads=reads)
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
    model = getattr(args, "sensor_model", "auto")
    if getattr(args, "lidar_errors", False) and model not in ("auto", "beams"):
        raise InputError(f"--lidar-errors is the beams model; it contradicts --sensor-model {model}")
    return RunOptions(
        sensor_model=model,
        lidar_errors=_lidar_errors(args, LidarErrorOptions),
        intrinsics=IntrinsicsOptions(refine=bool(getattr(args, "refine_intrinsics", False))),
        mode=mode,
        noise=NoiseOptions(robust=getattr(args, "robust", None)),
        stages=_stage_options(args),
        joint=JointOptions(**joint),
        target_sigma=target,
        stop_at_target=stop,
    )


def _lidar_errors(args: argparse.Namespace, options: type):  # noqa: ANN202 - LidarErrorOptions | None
    """``--lidar-errors`` (and ``--board-plane``) as options, or None without them."""
    plane = getattr(args, "board_plane", None)
    if not getattr(args, "lidar_errors", False):
        if plane is not None:
            raise InputError("--board-plane applies to --lidar-errors only")
        return None
    return options() if plane is None else options(board_plane_estimate=plane == "estimated")


def _stage_options(args: argparse.Namespace):  # noqa: ANN202 - observe.StageOptions
    from ilcc_graph.observe import StageOptions

    return StageOptions(jobs=args.jobs, strict=bool(getattr(args, "strict", False)))


# ----------------------------------------------------------------------------------------------
# Commands: each maps its arguments and calls into the package


def _calibrate(data: Sequence[str], args: argparse.Namespace, truth: np.ndarray | None = None) -> int:
    from ilcc_graph.app.write import link_latest, write_run
    from ilcc_graph.datasets import open_source
    from ilcc_graph.next_pose import for_run as next_pose_for_run
    from ilcc_graph.pipeline import run
    from ilcc_graph.report.summary import run_summary
    from ilcc_graph.report.text import format_update

    options = _run_options(args)
    out = _run_dir(args, data)
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
        _explain_failure(err, out, args.command_line)
        raise
    t1 = time.perf_counter()
    advice: dict = {}

    def propose():  # noqa: ANN202 - worked out while the report's pictures are drawn
        advice["next"] = next_pose_for_run(result, options.target_sigma)
        return advice["next"]

    write_run(
        out, result, report=args.report, studies=args.studies, truth=truth, command=args.command_line,
        next_pose=propose, clouds=args.clouds, full_views=args.full_views, progress=Progress,
    )  # fmt: skip
    if not args.out:
        link_latest(out)
    seconds = (t1 - t0, time.perf_counter() - t1)
    notes = [advice["next"].describe()] if advice.get("next") is not None else []
    reports = sorted((out / "report").glob("**/index.html"))
    gate = options.noise.chi2_gate_prob
    summary = run_summary(
        result.calibration, result.joint, truth, out, seconds, reports, notes, options.target_sigma, gate
    )
    print(summary)
    return 0


def _explain_failure(err: CalibrationImpossible, out: Path, command: str) -> None:
    """A failed run: its frames as a short table and the advice on stderr, the details in a file."""
    from ilcc_graph.app.write import write_failure
    from ilcc_graph.report.text import failure_table

    if err.frames:
        print(failure_table(err.frames), file=sys.stderr)
    if err.advice:  # one line of advice, or the likely set-up mistakes (``likely: ...`` lines)
        print(err.advice if err.advice.startswith("likely: ") else f"advice: {err.advice}", file=sys.stderr)
    where = write_failure(out, err, command)
    print(f"details: {where}" if where else "details: nowhere (no place to write them)", file=sys.stderr)


def cmd_calibrate(args: argparse.Namespace) -> int:
    return _calibrate(args.data, args)


def _stored(folder: Path, cache: bool = True) -> str:
    """'~/.cache/.../name (161 MB; deletable)': where a folder is (home as ~) and its size (a folder
    in the cache may go: the demo makes it again)."""
    size = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6
    home, where = str(Path.home()), str(folder)
    where = "~" + where[len(home) :] if where.startswith(home + os.sep) else where
    return f"{where} ({size:.0f} MB{'; deletable' if cache else ''})"


def cmd_demo(args: argparse.Namespace) -> int:
    """The standard panoramic set simulated into the cache (JPEG images: a sixth of PNG's bytes,
    the same accuracy, docs/bench_demo.md) or reused from there, then calibrated against its truth."""
    from ilcc_graph.io import read_ground_truth
    from ilcc_graph.simulate.export import write_standard_set

    data = Path(args.data or Path(args.cache) / f"demo-hdl32-equirect{args.width}-seed{args.seed}")
    _run_dir(args, [data])  # the output folder, claimed before the simulation
    if (data / "ground_truth.yaml").is_file():
        print(f"reusing {_stored(data, not args.data)}")
    else:
        print(
            f"simulating HDL-32E scans and {args.width} px panoramas, 20 frames (a minute or so)", flush=True
        )
        kw = {"lidar": "hdl32", "camera": "equirectangular", "frames": 20, "image_format": "jpg"}
        kw["command"] = args.command_line
        write_standard_set(data, Progress("simulate"), width=args.width, seed=args.seed, **kw)
        print(f"kept in {_stored(data, not args.data)}")
    return _calibrate([str(data)], args, read_ground_truth(data).T_cam_lidar)


def cmd_simulate(args: argparse.Namespace) -> int:
    from ilcc_graph.simulate.export import write_standard_set

    names = (
        "lidar",
        "camera",
        "width",
        "frames",
        "seed",
        "noise_scale",
        "intrinsics_error",
        "pcd_style",
        "range_offset_mm",
    )
    spec = write_standard_set(
        args.out,
        Progress("simulate"),
        sensor_format=args.format,
        command=args.command_line,
        **{k: getattr(args, k) for k in names},
    )
    print(f"wrote {spec.n_frames} frames to {args.out}")
    return 0


def _stage_command(args: argparse.Namespace, stage: str) -> int:
    """A stage alone over a data set: one YAML (and a drawing) per frame, and a table."""
    from ilcc_graph.app.write import link_latest, write_stage
    from ilcc_graph.datasets import open_source
    from ilcc_graph.observe import stage_alone
    from ilcc_graph.report.text import stage_table

    out = _run_dir(args, [args.data])
    source = open_source(args.data, **_bag_options(args))
    _, refs, results = stage_alone(source, stage, _stage_options(args), Progress(stage))
    rows = write_stage(out, stage, source, refs, results, args.command_line)
    if not args.out:
        link_latest(out)
    print(stage_table(stage, rows, source.skipped(), out))
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    """The paper's metric and corner errors of a calibration on a data set's frames."""
    from ilcc_graph.app.write import claim_output, write_evaluation
    from ilcc_graph.datasets import open_source
    from ilcc_graph.evaluation import evaluate_on
    from ilcc_graph.io import read_calibration
    from ilcc_graph.report import evaluation_rows
    from ilcc_graph.report.text import evaluation_text

    if args.out:
        claim_output(args.out, reads=[args.data])
    cal = read_calibration(Path(args.calibration))
    source = open_source(args.data, **_bag_options(args))
    ev, skipped = evaluate_on(source, cal.T_cam_lidar, _stage_options(args), Progress("frames"))
    print(evaluation_text(evaluation_rows(ev), skipped))
    if args.out:
        print(f"wrote {write_evaluation(Path(args.out), ev, command=args.command_line)}")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    """Per frame as it arrives: board in scan and image, new pose, running sigmas (``live``)."""
    from ilcc_graph.app.check_view import check_command
    from ilcc_graph.app.write import link_latest
    from ilcc_graph.estimation.selection import AUTO
    from ilcc_graph.live import CheckOptions
    from ilcc_graph.observe import StageOptions

    target = args.target_sigma
    options = CheckOptions(
        target_sigma=target,
        until=args.until,
        watch=args.watch,
        stop_at_target=target is not None,
        stages=StageOptions(jobs=1),
        models=AUTO if args.sensor_model == "auto" else (args.sensor_model,),
    )
    out = _run_dir(args, [args.data])
    code = check_command(args.data, options, out, advise_live=args.advise, command=args.command_line)
    if not args.out:
        link_latest(out)
    return code


def cmd_export(args: argparse.Namespace) -> int:
    from ilcc_graph.app.write import write_file
    from ilcc_graph.export import export_calibration
    from ilcc_graph.io import read_calibration_with_camera

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


def _bag_options(args: argparse.Namespace) -> dict:
    return {k: getattr(args, k, None) for k in BAG_OPTIONS}


COMMANDS: dict[str, Callable[[argparse.Namespace], int]] = {
    "calibrate": cmd_calibrate,
    "demo": cmd_demo,
    "simulate": cmd_simulate,
    "lidar-corners": partial(_stage_command, stage="lidar"),
    "image-corners": partial(_stage_command, stage="image"),
    "evaluate": cmd_evaluate,
    "check": cmd_check,
    "export": cmd_export,
}


def build_parser() -> argparse.ArgumentParser:
    """The command line's parser (``cli_parser``) with this module's commands."""
    return cli_parser.build_parser(COMMANDS)


def main(argv: Sequence[str] | None = None) -> int:
    # one BLAS thread unless the user says otherwise: the sensor models' many small dense products
    # run 3-8x slower in wall time with OpenBLAS's threads on a loaded machine (docs/bench_live.md)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    args = argparse.Namespace(debug="--debug" in (sys.argv[1:] if argv is None else argv))

    def command() -> int:  # under the signal handlers from the first import on
        nonlocal args
        args = build_parser().parse_args(argv)
        args.command_line = " ".join(sys.argv[1:] if argv is None else argv)  # for the folders' markers
        setup_logging(args.verbose)
        return args.fn(args)

    code = run_command(command, lambda: getattr(args, "out_dir", None), lambda: args.debug)
    if signals.stop_requested() is not None:
        signals.exit_now(code)  # after a stop: no interpreter teardown (signals.exit_now)
    return code
