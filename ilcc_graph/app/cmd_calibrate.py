"""``ilcc-graph calibrate``: data sets or bags -> the calibration, its report and the closing summary.

``calibrate(data, args, truth)`` is also the demo's second half (``cmd_demo``).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ilcc_graph.app.arguments import add_bag_arguments, add_solve_arguments
from ilcc_graph.app.console import DEG_MM, RATE, Progress
from ilcc_graph.app.flags import bag_options, run_options
from ilcc_graph.app.folders import output_folder, written
from ilcc_graph.errors import CalibrationImpossible, InputError

if TYPE_CHECKING:
    import numpy as np

    from ilcc_graph.next_pose import Proposal
    from ilcc_graph.run.result import Result, RunOptions

__all__ = ["HELP", "add_arguments", "calibrate", "run"]

HELP = "calibrate from data sets (DATA/config.yaml, pcd/, img/) or ROS bags"


def add_arguments(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("data", nargs="+", metavar="DATA", help="data sets or bags (several: sessions of a rig)")
    add_solve_arguments(sp)
    add_bag_arguments(sp)
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


def run(args: argparse.Namespace) -> int:
    return calibrate(args.data, args)


#: the run options a rig's graph takes as a pair's run does (``strategies.solve_rig.solve``)
RIG_TAKES = ("stages", "noise", "lidar_errors", "intrinsics", "sensor_model")


def _options(data: Sequence[str], args: argparse.Namespace) -> tuple[RunOptions, bool]:
    """The run's options and whether ``data`` is a rig (one folder with rig.yaml, or a rig file;
    docs/rig.md): a rig runs the ``rig`` strategy with the solve options a pair's run takes
    (``RIG_TAKES``); the others given for one are an InputError naming them."""
    import dataclasses

    from ilcc_graph.datasets.rig_source import is_rig_source
    from ilcc_graph.run.result import RunOptions

    options = run_options(args)
    if not (len(data) == 1 and is_rig_source(Path(data[0]))):
        return options, False
    plain = RunOptions()  # the options a rig does not take, given away from their defaults
    given = [k.name for k in dataclasses.fields(plain) if getattr(options, k.name) != getattr(plain, k.name)]
    if given := [k for k in given if k not in RIG_TAKES]:
        raise InputError(
            f"{data[0]}: a rig (docs/rig.md); the options given ({', '.join(given)}) apply to one "
            "camera-LiDAR pair or to sessions, not to a rig's graph"
        )
    return RunOptions(mode="rig", **{k: getattr(options, k) for k in RIG_TAKES}), True


def calibrate(data: Sequence[str], args: argparse.Namespace, truth: np.ndarray | None = None) -> int:
    """Calibrate the data sets ``data`` as the arguments say (a rig: every sensor's pose in the
    reference frame), write the results, print the summary (``truth``: the true T_cam_lidar (4, 4)
    of a simulated set, compared in the summary)."""
    if getattr(args, "jobs", 1) > 1:  # the workers' fork server imports while this process does
        from ilcc_graph import workers

        workers.prestart()
    from ilcc_graph.app.write import write_run
    from ilcc_graph.datasets import open_source
    from ilcc_graph.run.pipeline import run

    options, rig = _options(data, args)
    out = output_folder(args, data)
    sources = [open_source(d, rig=True) if rig else open_source(d, **bag_options(args)) for d in data]
    bars: dict[str, Progress] = {}
    t0 = time.perf_counter()
    try:
        result = run(
            sources,
            options,
            progress=lambda name, i, n: bars.setdefault(name, Progress(name))(i, n),
            report=lambda line: print(line, flush=True),
        )
    except CalibrationImpossible as err:  # a short table and one line of advice; details in the folder
        _explain_failure(err, out, args.command_line)
        raise
    t1 = time.perf_counter()
    if rig:
        return _rig_summary(result, out, args)
    advice: dict[str, Proposal | None] = {}

    def propose() -> Proposal | None:  # worked out while the report's pictures are drawn
        from ilcc_graph.next_pose import for_run as next_pose_for_run

        advice["next"] = next_pose_for_run(result, options.target_sigma)
        return advice["next"]

    write_run(
        out, result, report=args.report, studies=args.studies, truth=truth, command=args.command_line,
        next_pose=propose, clouds=args.clouds, full_views=args.full_views, progress=Progress,
    )  # fmt: skip
    written(args, out)
    _pair_summary(result, out, options, truth, (t1 - t0, time.perf_counter() - t1), advice.get("next"))
    return 0


def _pair_summary(result: Result, out: Path, options: RunOptions, truth: np.ndarray | None,
                  seconds: tuple[float, float], proposal: Proposal | None) -> None:  # fmt: skip
    """The closing summary of one pair (or joint sessions): report.summary's ``run_summary``."""
    from ilcc_graph.report.summary import run_summary

    notes = [proposal.describe()] if proposal is not None else []
    reports = sorted((out / "report").glob("**/index.html"))
    need, gate = options.target_sigma, options.noise.chi2_gate_prob
    joint = result.documents.get("joint.yaml")  # the sessions' tests, for the verdict
    print(run_summary(result.calibration, joint, truth, out, seconds, reports, notes, need, gate))


def _rig_summary(result: Result, out: Path, args: argparse.Namespace) -> int:
    """A rig's results written (its calibration.yaml, config.resolved.yaml) and its poses printed as
    written (``rig_view``)."""
    import textwrap

    from ilcc_graph.app.rig_view import rig_lines
    from ilcc_graph.app.write import write_run
    from ilcc_graph.report.rig_verdict import rig_verdict, rig_verdict_lines

    cal = result.rig
    if cal is None:
        raise ValueError("a rig's run gave no rig calibration (Result.rig)")
    write_run(out, result, report=args.report, command=args.command_line, progress=Progress)
    written(args, out)
    print("\n".join(rig_lines(cal)))
    print("\n".join(rig_verdict_lines(cal)))
    for part in rig_verdict(cal)[1].split("\n"):  # the verdict, then what it rests on (indented)
        print("\n".join(textwrap.wrap(part, 80, subsequent_indent="  ")))
    print(f"wrote {out / 'calibration.yaml'} (a rig's: docs/rig.md; exports and verify read it)")
    if args.report:
        print(f"report: {out / 'report' / 'index.html'}")
    return 0


def _explain_failure(err: CalibrationImpossible, out: Path, command: str) -> None:
    """A failed run: its frames as a short table and the advice on stderr, the details in a file."""
    from ilcc_graph.app.console import wrapped
    from ilcc_graph.app.write import write_failure
    from ilcc_graph.report.text import failure_table

    if err.frames:
        print(failure_table(err.frames), file=sys.stderr)
    if err.advice:  # one line of advice, or the likely set-up mistakes (``likely: ...`` lines)
        text = err.advice if err.advice.startswith("likely: ") else f"advice: {err.advice}"
        print(wrapped(text), file=sys.stderr)
    where = write_failure(out, err, command)
    print(f"details: {where}" if where else "details: nowhere (no place to write them)", file=sys.stderr)
