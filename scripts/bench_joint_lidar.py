"""Monte Carlo of joint sessions whose LiDAR has its own errors (issue 34): is the joint honest?

Each run: one rig (``T_TRUE``) and one LiDAR (VLP-16 beams) that reads ``--offset-mm`` long with
per-beam errors of ``--beam-mm`` (sd) and 4 mm on black print; three sessions of ``--frames`` board
poses each (graph-level frames with their returns, tests/test_lidar_errors.py's ``lidar_frames``:
0.5 px corners on a 4000 x 2000 panorama, 10 mm range noise). The sessions are calibrated jointly
(``estimation.sessions.solve_sessions``, rigid, the sensor model chosen among none / range / beams as
``calibrate`` chooses it, the LiDAR's terms shared) and each alone; the NEES of T_cam_lidar (6 dof)
against the truth and the 95 % coverage (NEES under the chi-square 95 % quantile, 12.59) are counted.
Targets (issue 34): mean NEES 4.5-7.5, coverage 90-98 %. The boards are ideal unless
``--board-beam-mm`` (each beam's own offset on each board, as the recorded rigs show), ``--plane-mm``
or ``--tilt-deg`` (each board's face off its frame's plane) give them their own effects. Each run also
reports the chosen model's own covariance scaled by its boards' jackknife spread (a diagnostic).

Run: ``nice python3 scripts/bench_joint_lidar.py [--runs 50] [--seed 0] [--board-beam-mm 2.5] [--write]``
(``--write``: the table into docs/bench_joint_lidar.md between its markers, those of the boards with
their own effects when given; the doc's hand-written text is kept).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import gtsam
import numpy as np
from _shared import write_between

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from test_lidar_errors import CAMERA, T_TRUE, lidar_frames  # noqa: E402

from ilcc_graph.estimation.chi2 import ppf as chi2_ppf  # noqa: E402
from ilcc_graph.estimation.held_out import board_spread, held_out  # noqa: E402
from ilcc_graph.estimation.selection import AUTO  # noqa: E402
from ilcc_graph.estimation.sessions import JointOptions, Session, solve_sessions  # noqa: E402
from ilcc_graph.types import Estimate  # noqa: E402

DOC = ROOT / "docs" / "bench_joint_lidar.md"
Q95 = chi2_ppf(0.95, 6)


def nees(e: Estimate) -> float:
    """NEES of an estimate of T_cam_lidar against the truth (6 dof)."""
    xi = e.pose.localCoordinates(T_TRUE)
    return float(xi @ np.linalg.solve(e.covariance, xi))


def sessions(rng: np.random.Generator, offsets: np.ndarray, args: argparse.Namespace) -> list[Session]:
    """Three sessions of one rig and one LiDAR, each its own board poses (``args``: frames and the
    boards' own effects)."""
    out = []
    plane = np.array([1e-3 * args.plane_mm, np.radians(args.tilt_deg)])
    for name in "ABC":
        while True:  # a board between two beams' cones gives no returns: draw again
            try:
                fr = lidar_frames(rng, args.frames, offsets, board_beam_m=1e-3 * args.board_beam_mm,
                                  plane_sd=plane)[0]  # fmt: skip
                break
            except ValueError:
                continue
        T0 = T_TRUE.compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6))).matrix()
        out.append(Session(name, fr, CAMERA, T0))
    return out


def one_run(seed: int, args: argparse.Namespace) -> dict:
    """One Monte Carlo run: the joint's and each session's NEES, the model chosen, the global test."""
    rng = np.random.default_rng(seed)
    offsets = 1e-3 * (args.offset_mm + rng.normal(0, args.beam_mm, 16))
    t0 = time.perf_counter()
    sol = solve_sessions(sessions(rng, offsets, args), JointOptions(models=AUTO))
    assert sol.selection is not None
    g = sol.global_test
    assert sol.solution is not None
    own = sol.solution.extrinsic(0)
    r = board_spread(held_out(sol.solution, 0), own.covariance)["jackknife"]
    return {
        "joint": nees(sol.joint),
        "joint_own": nees(own),
        "jackknife_ratio": r,
        "joint_jackknife": nees(Estimate(own.T, max(1.0, r) * own.covariance)),
        "averaged": bool(sol.selection.averaged),
        "alone": [nees(e) for e in sol.alone.values()],
        "model": sol.selection.chosen,
        "factor": float(sol.selection.factor),
        "moved": bool(g is not None and g.moved),
        "global_p": float(g.p_value) if g is not None else float("nan"),
        "sigma_tz_mm": 1e3 * float(np.sqrt(sol.joint.covariance[5, 5])),
        "alone_sigma_tz_mm": float(np.mean([1e3 * np.sqrt(e.covariance[5, 5]) for e in sol.alone.values()])),
        "seconds": time.perf_counter() - t0,
    }


def interval(x: np.ndarray) -> str:
    """Mean and its 95 % interval (normal approximation)."""
    m, s = float(np.mean(x)), float(np.std(x, ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")
    return f"{m:.2f} ({m - 1.96 * s:.2f} .. {m + 1.96 * s:.2f})"


def board_effects(args: argparse.Namespace) -> str:
    """The boards' own effects the runs simulate, as a clause of the summary."""
    parts = [
        f"each board's face off its plane (sd {args.plane_mm:g} mm)" if args.plane_mm else "",
        f"each board's face tilted (sd {args.tilt_deg:g} deg)" if args.tilt_deg else "",
        f"each beam its own offset on each board (sd {args.board_beam_mm:g} mm)"
        if args.board_beam_mm
        else "",
    ]
    said = [p for p in parts if p]
    ideal = "; ideal boards (flat, no beam's offset changing from board to board)"
    return "; " + ", ".join(said) if said else ideal


def summary(runs: list[dict], args: argparse.Namespace) -> str:
    """The figures as a markdown section."""
    joint = np.array([r["joint"] for r in runs])
    alone = np.array([a for r in runs for a in r["alone"]])
    own = np.array([r["joint_own"] for r in runs])
    jack = np.array([r["joint_jackknife"] for r in runs])
    models = Counter(r["model"] for r in runs)
    lines = [
        f"{len(runs)} runs (seeds {args.seed}..{args.seed + len(runs) - 1}), 3 sessions of {args.frames} "
        f"boards each; the LiDAR reads {args.offset_mm:g} mm long, per-beam sd {args.beam_mm:g} mm, "
        "4 mm on black print"
        + board_effects(args)
        + "; sensor model chosen among none / range / beams.",
        "",
        "| estimate | count | mean NEES (95 % interval of the mean) | 95 % coverage | mean sigma tz (mm) |",
        "|---|---|---|---|---|",
        f"| joint (rigid) | {len(joint)} | {interval(joint)} | {100 * np.mean(joint < Q95):.1f} % | "
        f"{np.mean([r['sigma_tz_mm'] for r in runs]):.2f} |",
        "| joint, the chosen model's own covariance (not averaged, without its held-out factor) | "
        f"{len(own)} | "
        f"{interval(own)} | {100 * np.mean(own < Q95):.1f} % | |",
        "| joint, the chosen model's own covariance times max(1, r), r its boards' jackknife spread "
        f"against it (mean r {np.mean([r['jackknife_ratio'] for r in runs]):.2f}; a diagnostic) "
        f"| {len(jack)} | "
        f"{interval(jack)} | {100 * np.mean(jack < Q95):.1f} % | |",
        f"| each session alone | {len(alone)} | {interval(alone)} | {100 * np.mean(alone < Q95):.1f} % | "
        f"{np.mean([r['alone_sigma_tz_mm'] for r in runs]):.2f} |",
        "",
        "Targets: mean NEES 4.5-7.5 (6 expected), coverage 90-98 % (95 % expected). Models chosen: "
        + ", ".join(f"{m} {n}" for m, n in models.most_common())
        + f" (the joint covariance averaged over the models in {sum(r['averaged'] for r in runs)} runs)"
        + f"; the global consistency test said 'moved' in {sum(r['moved'] for r in runs)} of {len(runs)} "
        f"runs (alpha 0.01, nothing moved); {np.mean([r['seconds'] for r in runs]):.1f} s per run.",
        "",
        "By the model chosen (the joint's NEES as reported, and of the chosen model's own covariance "
        "without its held-out factor):",
        "",
        "| chosen | runs | mean NEES | own, without the held-out factor | mean held-out factor "
        "| covariance averaged |",
        "|---|---|---|---|---|---|",
    ]
    for m, n in models.most_common():
        rs = [r for r in runs if r["model"] == m]
        lines.append(
            f"| {m} | {n} | {np.mean([r['joint'] for r in rs]):.2f} "
            f"| {np.mean([r['joint_own'] for r in rs]):.2f} "
            f"| {np.mean([r['factor'] for r in rs]):.2f} | {sum(r['averaged'] for r in rs)} |"
        )
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--runs", type=int, default=50)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--offset-mm", type=float, default=20.0)
    p.add_argument("--beam-mm", type=float, default=4.0)
    help = "sd of each beam's extra range offset on each board (mm; the recorded rigs': 2.4-3.0)"
    p.add_argument("--board-beam-mm", type=float, default=0.0, help=help)
    p.add_argument("--plane-mm", type=float, default=0.0, help="sd of each board's face off its plane (mm)")
    p.add_argument("--tilt-deg", type=float, default=0.0, help="sd of each board's face's tilts (deg)")
    p.add_argument("--write", action="store_true")
    args = p.parse_args()
    runs = []
    for k in range(args.runs):
        r = one_run(args.seed + k, args)
        runs.append(r)
        print(
            f"run {k + 1}/{args.runs}: joint NEES {r['joint']:.2f}, alone "
            + " ".join(f"{a:.2f}" for a in r["alone"])
            + f", {r['model']}, global p {r['global_p']:.2f}, {r['seconds']:.1f} s",
            flush=True,
        )
    text = summary(runs, args)
    print(text)
    if args.write:  # between the doc's markers: its hand-written text around them is kept
        boards = args.plane_mm or args.tilt_deg or args.board_beam_mm
        tag = "bench_joint_lidar_boards" if boards else "bench_joint_lidar"
        write_between(DOC, f"<!-- {tag}:begin -->", f"<!-- {tag}:end -->", text)
        print(f"wrote {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
