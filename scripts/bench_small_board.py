"""A small hand-held board (issue 38, item 3): Monte Carlo of whole calibrations whose answer the data
may not support.

Each set: a VLP-16 and a wide-angle fisheye (``Fisheye.default(1920)``: 1920 x 1536, equidistant
f = 576 px, about 190 deg across the diagonal), a 7 x 8 board of 50 mm squares with no margin (0.35 x
0.40 m, the print cut to the pattern), held 2-4 m away (no stand; the simulator's person beside it in
60 % of the frames, its LiDAR systematics on), 8-12 frames (8 + seed mod 5), the print visible to the
LiDAR. At 2 m the VLP-16's 2-degree beams put 5-6 lines on the board, at 4 m 2-3. Each set is
calibrated as the command line does it (``pipeline.run``: the stages, the second look, the graph with
its noise policy); a ``CalibrationImpossible`` is the command line's exit 3.

Per set: frames, boards found by each stage, frames used, the verdict, the extrinsic's errors and
NEES against the truth (6 dof; outside the 99.9 % bound above chi2(6) 0.999 = 22.46), or the exit 3's
message, the frames it names and its advice. The target (issue 38): either >= 80 % of frames used
with mean NEES 4.5-7.5, or exit 3 with the reason; never a written result outside its 99.9 % bound
in more than 1 % of sets.

    nice python3 scripts/bench_small_board.py --sets 50 --sink /tmp/small.jsonl
    nice python3 scripts/bench_small_board.py --sets 30 --moved 4 --sink /tmp/small_moved4.jsonl
    python3 scripts/bench_small_board.py --write --section "as simulated=/tmp/small.jsonl" \
        --section "4 boards moved before the photo=/tmp/small_moved4.jsonl"

``--moved K``: in each set K frames (drawn per seed) show in their image the board moved by 20-60 mm
and 1-3 deg from where the scan saw it (a hand-held board that moved between the scan and the
photo; the images of a second simulation with those poses): the gate should drop them, and whatever
is written must still lie within its bound.

``--range-noise-mm MM``: every return moved along its own beam by MM (one sigma) instead of the
simulator's default noise (which moves the board's returns off their beams; docs/bench_noise.md).

Each finished set is appended to the sink at once (a JSON line), so a run can be stopped and resumed.
``--write`` writes docs/bench_small_board.md (a section per ``--section LABEL=SINK``) and
docs/bench_small_board.png (a row of panels per section).
"""

from __future__ import annotations

import argparse
import logging
import shutil
import sys
import tempfile
import textwrap
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from _shared import append_sink, load_sink
from bench_shape import board_nees, pose_error  # (scripts/ is the running script's folder)
from scipy.stats import chi2

from ilcc_graph.board import Board
from ilcc_graph.cameras import Fisheye
from ilcc_graph.datasets import open_source
from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem
from ilcc_graph.report.summary import verdict
from ilcc_graph.run.pipeline import run
from ilcc_graph.run.result import RunOptions
from ilcc_graph.simulate import (
    SceneOptions,
    SimulationSpec,
    board_placements,
    moved_placements,
    simulate_dataset,
)

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bench_small_board.md"
FIGURE = ROOT / "docs" / "bench_small_board.png"
BOUND_999 = float(chi2.ppf(0.999, 6))


def spec_for(seed: int, range_noise_m: float | None = None) -> SimulationSpec:
    """Set ``seed`` (module docstring); ``range_noise_m``: range noise along each beam instead of the
    simulator's default noise (``SimulationSpec.range_noise_m``)."""
    return SimulationSpec(
        lidar="vlp16", camera=Fisheye.default(1920), board=Board(7, 8, 0.05), n_frames=8 + seed % 5,
        seed=seed, scene=SceneOptions(board_distance_m=(2.0, 4.0), stand=False), intensity_field="print",
        range_noise_m=range_noise_m,
    )  # fmt: skip


def run_one(data: Path, spec: SimulationSpec) -> dict:
    """One calibration of ``data`` as the command line runs it; its numbers against the truth."""
    t0 = time.perf_counter()
    out: dict = {"n_frames": int(spec.n_frames)}
    try:
        res = run([open_source(data)], RunOptions())
    except (CalibrationImpossible, IndeterminateSystem) as err:
        out.update(
            exit=3, failure=f"{type(err).__name__}: {err}", advice=getattr(err, "advice", None),
            frames=[list(f) for f in getattr(err, "frames", ())], seconds=time.perf_counter() - t0,
        )  # fmt: skip
        return out
    cal = res.calibration
    T_true = np.asarray(spec.T_cam_lidar)
    truth = board_placements(spec)
    boards = [(int(f.name) - 1, f.board) for f in res.sessions[0].observation.frames if f.board is not None]
    nb = [board_nees(b, truth[i], spec.board) for i, b in boards]
    xi = pose_error(cal.T_cam_lidar, T_true)
    level, text = verdict(cal)
    out.update(
        exit=0,
        used=int(sum(f.used for f in cal.frames)),
        lidar_boards=int(sum(f.board is not None for f in cal.frames)),
        image_boards=int(sum(f.corners is not None for f in cal.frames)),
        rot_deg=float(np.degrees(np.linalg.norm(xi[:3]))),
        trans_mm=float(1e3 * np.linalg.norm(cal.T_cam_lidar[:3, 3] - T_true[:3, 3])),
        sigma_deg=float(np.degrees(np.sqrt(np.linalg.eigvalsh(cal.covariance[:3, :3])[-1]))),
        sigma_mm=float(1e3 * np.sqrt(np.linalg.eigvalsh(cal.covariance[3:, 3:])[-1])),
        nees=float(xi @ np.linalg.solve(cal.covariance, xi)),
        board_nees=[float(a) for a, _ in nb],
        board_nees_inplane=[float(b) for _, b in nb],
        components=[cal.diagnostics.get(f"variance_component_{k}", 1.0) for k in ("board", "bearing")],
        verdict=level,
        verdict_text=text,
        dropped=[f"{f.name}: {f.reason}" for f in cal.frames if not f.used],
        seconds=time.perf_counter() - t0,
    )
    return out


def run_set(seed: int, cache: Path, moved: int = 0, range_noise_m: float | None = None) -> dict:
    """Set ``seed`` written (``moved`` frames' images from the board moved), calibrated, the cache removed."""
    tmp = Path(tempfile.mkdtemp(prefix=f"bench_small_board_{seed}_", dir=cache))
    try:
        spec = spec_for(seed, range_noise_m)
        data = simulate_dataset(tmp / "set", spec)
        frames = moved_placements(spec, moved) if moved else {}
        if frames:  # the images of the moved boards, from a second simulation of just those poses
            other = simulate_dataset(tmp / "moved", replace(spec, placements=list(frames.values())))
            for j, i in enumerate(frames):
                (image,) = sorted((other / "img").glob(f"{j + 1:04d}.*"))
                shutil.copy(image, data / "img" / f"{i + 1:04d}{image.suffix}")
        names = [f"{i + 1:04d}" for i in frames]
        return {"seed": seed, "moved": names, "range_noise_m": range_noise_m, **run_one(data, spec)}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _reason_kind(s: dict) -> str:
    """A short label of an exit 3's message."""
    msg = s["failure"].split(": ", 1)[-1]
    return msg.split(" (")[0].split(";")[0][:110]


#: a LiDAR board this far from the truth (6-dof NEES) is another object taken for the board, which
#: the calibration refuses (its image is elsewhere); the stage's means leave it out and count it
WRONG_OBJECT_NEES = 1e3


def _stage(sets: Sequence[dict]) -> str:
    """The LiDAR stage's boards against the truth: mean 6-dof and in-plane NEES, wrong objects apart."""
    pairs = [(a, b) for s in sets for a, b in zip(s.get("board_nees", []), s.get("board_nees_inplane", []))]
    kept = np.array([(a, b) for a, b in pairs if a < WRONG_OBJECT_NEES]).reshape(-1, 2)
    full, inplane = kept.mean(axis=0) if len(kept) else (float("nan"), float("nan"))
    wrong = len(pairs) - len(kept)
    apart = f"; {wrong} board(s) another object (NEES > {WRONG_OBJECT_NEES:g}) left out" if wrong else ""
    return f"mean NEES {full:.2f} (6 dof, honest 6), in-plane {inplane:.2f} (3 dof, honest 3){apart}"


def report(sets: Sequence[dict], label: str) -> str:
    """One section of docs/bench_small_board.md: the sets of one sink."""
    written = [s for s in sets if s["exit"] == 0]
    failed = [s for s in sets if s["exit"] != 0]
    frames = sum(s["n_frames"] for s in written)
    used = sum(s["used"] for s in written)
    nees = np.array([s["nees"] for s in written])
    outside = [s for s in written if s["nees"] > BOUND_999]
    share = used / frames if frames else float("nan")
    mean_nees = float(nees.mean()) if len(nees) else float("nan")
    rows = [
        f"| {s['seed']} | {s['n_frames']} | {s['lidar_boards']} / {s['image_boards']} | {s['used']} | "
        f"{s['verdict']} | {s['rot_deg']:.3f} | {s['trans_mm']:.1f} | {s['sigma_deg']:.3f} | "
        f"{s['sigma_mm']:.1f} | {s['nees']:.1f} |"
        for s in written
    ]
    frows = [
        f"| {s['seed']} | {s['n_frames']} | {_reason_kind(s)} | {s.get('advice') or ''} |" for s in failed
    ]
    kinds = Counter(_reason_kind(s) for s in failed)
    moved = {len(s.get("moved", [])) for s in sets}
    moved_text = f"; {', '.join(map(str, sorted(moved)))} frames per set moved before the photo"
    met = (not written or (share >= 0.8 and 4.5 <= mean_nees <= 7.5)) and len(outside) <= 0.01 * len(sets)
    return "\n".join([
        f"## {label}",
        "",
        f"{len(sets)} sets (seeds {min(s['seed'] for s in sets)}-{max(s['seed'] for s in sets)}"
        + (moved_text if moved != {0} else "")
        + ").",
        "",
        f"- results written: {len(written)} of {len(sets)} sets; exit 3: {len(failed)}",
        f"- frames used in the written sets: {used} of {frames} ({share:.0%}; target >= 80 %)",
        f"- mean NEES of the written sets: {mean_nees:.2f} (target 4.5-7.5; median "
        f"{float(np.median(nees)) if len(nees) else float('nan'):.2f})",
        f"- written results outside their 99.9 % bound (NEES > {BOUND_999:.2f}): {len(outside)} of "
        f"{len(sets)} sets ({len(outside) / max(len(sets), 1):.0%}; target <= 1 %)"
        + (f": seeds {', '.join(str(s['seed']) for s in outside)}" if outside else ""),
        f"- the LiDAR stage's boards against the truth (sets written): {_stage(sets)}",
        f"- the issue's target (>= 80 % of frames used with mean NEES 4.5-7.5, or exit 3 with the reason; "
        f"a written result outside its 99.9 % bound in at most 1 % of sets): {'met' if met else 'NOT met'}",
        "",
        "### Results written",
        "",
        "| seed | frames | boards LiDAR / image | used | verdict | rotation error deg | translation error mm "
        "| 1-sigma deg (largest) | 1-sigma mm (largest) | NEES |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        "### Exit 3",
        "",
        "Reasons: " + ("; ".join(f"{k} ({v})" for k, v in kinds.most_common()) or "none."),
        "",
        "| seed | frames | reason | advice |",
        "|---|---|---|---|",
        *frows,
        "",
    ])  # fmt: skip


def figure(sections: dict[str, list[dict]]) -> None:
    """docs/bench_small_board.png: per section (a row) each written set's NEES against its 99.9 %
    bound, and the share of frames used per set (exit 3 hatched)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(sections), 2, figsize=(10, 3.8 * len(sections)), squeeze=False)
    for (label, sets), (a, b) in zip(sections.items(), axes, strict=True):
        _panels(sets, a, b, label)
    fig.tight_layout()
    fig.savefig(FIGURE, dpi=90)


def _panels(sets: Sequence[dict], a, b, label: str) -> None:  # noqa: ANN001 - matplotlib axes
    seeds = [s["seed"] for s in sets]
    for s in sets:
        if s["exit"] == 0:
            a.semilogy(s["seed"], max(s["nees"], 1e-2), "o", color="C3" if s["nees"] > BOUND_999 else "C0")
            b.bar(s["seed"], s["used"] / s["n_frames"], color="C0")
        else:
            b.bar(s["seed"], 1.0, color="none", edgecolor="C3", hatch="//")
    a.axhline(BOUND_999, color="C3", lw=1, label="99.9 % bound (22.46)")
    a.axhline(6.0, color="0.5", lw=1, ls="--", label="honest mean (6)")
    a.set(xlabel="seed", ylabel="NEES (6 dof)")
    title = textwrap.fill(label, 60)
    a.set_title(f"{title}\nNEES of the results written", fontsize=8)
    a.legend(fontsize=8)
    b.axhline(0.8, color="0.5", lw=1, ls="--")
    b.set(xlabel="seed", ylabel="share of frames used", ylim=(0, 1.05))
    b.set_title(f"{title}\nframes used (hatched: exit 3)", fontsize=8)
    if seeds:
        a.set_xlim(min(seeds) - 1, max(seeds) + 1)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", type=int, default=20)
    ap.add_argument("--moved", type=int, default=0, help="frames per set whose board moved before the photo")
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument(
        "--range-noise-mm",
        type=float,
        default=None,
        help="range noise along each beam (mm) instead of the simulator's default noise",
    )
    ap.add_argument("--sink", default=str(Path(tempfile.gettempdir()) / "bench_small_board.jsonl"))
    ap.add_argument("--cache", default=tempfile.gettempdir())
    ap.add_argument("--from-sink", action="store_true", help="only summarise the sink")
    ap.add_argument("--write", action="store_true", help="write docs/bench_small_board.md and its figure")
    ap.add_argument("--section", action="append", default=[], help="LABEL=SINK: a section of the doc")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    sink = Path(args.sink)
    if not args.from_sink:
        done = {s["seed"] for s in load_sink(sink)}
        for seed in range(args.seed0, args.seed0 + args.sets):
            if seed in done:
                continue
            rn = None if args.range_noise_mm is None else 1e-3 * args.range_noise_mm
            res = run_set(seed, Path(args.cache), args.moved, rn)
            append_sink(sink, res)
            brief = res.get("failure") or (
                f"{res['used']}/{res['n_frames']} {res['verdict']} {res['rot_deg']:.3f} deg "
                f"{res['trans_mm']:.1f} mm NEES {res['nees']:.1f}"
            )
            print(f"set {seed}: {res['seconds']:.0f} s {brief}", flush=True)
    pairs = [x.split("=", 1) for x in args.section] or [["sets", str(sink)]]
    sections = {label: sorted(load_sink(Path(path)), key=lambda s: s["seed"]) for label, path in pairs}
    text = "\n".join(report(sets, label) for label, sets in sections.items() if sets)
    print(text)
    if args.write:
        stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        shown = [a.split("=", 1)[0] + "=" + Path(a.split("=", 1)[1]).name if "=" in a else a for a in argv]
        shown = [f'"{a}"' if " " in a else a for a in shown]  # the sinks by their names, not where they lay
        DOC.write_text(DOC_HEAD.format(command=" ".join(shown), stamp=stamp) + text + DOC_TAIL)
        figure({k: v for k, v in sections.items() if v})
    return 0


DOC_HEAD = """# A small hand-held board: Monte Carlo

Issue 38, item 3: a 7 x 8 board of 50 mm squares (0.35 x 0.40 m, the print cut to the pattern) held
2-4 m from a VLP-16 and a wide-angle fisheye gave a real rig 2 of 8 frames used and a result 3.4 deg /
99 mm from the authors' own whose covariance claimed 0.42 deg / 14 mm: a wrong answer written at 8
sigma. The target: either >= 80 % of frames used with mean NEES 4.5-7.5, or exit 3 with the reason;
never a written result outside its 99.9 % bound in more than 1 % of sets.

`python scripts/bench_small_board.py {command}` ({stamp}). The simulator's set: VLP-16 + fisheye
(1920 x 1536, equidistant f = 576 px, about 190 deg across the diagonal), the board without a margin
held 2-4 m away (no stand, the simulator's person beside it in 60 % of the frames, the LiDAR's
systematics on), 8-12 frames, print visible; each set calibrated as the command line does it. The
issue asks 50 sets per case; the machine's two shared cores gave time for the numbers below (each
section says how many). NEES against the truth, 6 dof (mean 6 when honest; 99.9 % bound 22.46).

"""
DOC_TAIL = """
![NEES and frames used per set](bench_small_board.png)

## Reading

The first two sections are this tree (session 48): 100 sets as simulated and 100 sets with range
noise along each beam (``--range-noise-mm 10``, `SimulationSpec.range_noise_m`) instead of the
simulator's default noise. The next two are the same seeds on the tree before it (811567b), whose
simulator gave each LiDAR footprint 7 points. The sections marked 5452562 ran the held-out gate;
24a0702 adds the consensus check; those marked 9c80ee7 ran the tree just before the gate, all on the
same seeds and the 7-point footprint.

- **Session 48: the over-confidence was mostly the simulator's footprint; the target is met on 100
  sets of each noise model, at its limit.**
  - **What it was.** The simulator averaged the print's colour over 7 points of each beam's
    footprint (its centre and 6 round it). Across an edge that blend is a staircase of a few steps
    (the share of the footprint on one side is off the disc's by up to 0.21), and the soft-edge fit
    placed the print's edges by the steps. With a LiDAR without noise or systematics the small
    board's 988 LiDAR fits read in-plane NEES 4.38 (3 when honest), 2.9 % beyond chi2(3)'s 99.9 %
    point; and 6.46 (4.5 %) without intensity noise, where nothing else hides the steps. A footprint
    of 177 points on a grid read 2.92 (0.3 %) and 65 on a hexagonal grid 2.87 (0.2 %), both on seeds
    0..59; the hexagonal one 3.15 (0.5 %) without intensity noise on seeds 0..99: its rows still
    step. The footprint is now 128 points on Vogel's spiral and its reflection
    (`simulate.edges.FOOTPRINT`, used for the intensity and for the mixed returns at the board's
    outline): within 0.03 of the disc's share for an edge at any angle. The 988 boards read 2.81
    (0.7 % beyond the 99 % point, 0.1 % beyond 99.9 %), and 0.98 without intensity noise (the
    sampling term's floor then dominates: conservative). A real spot's light is spread, not in 7
    lumps: the estimator is unchanged, the simulator was wrong.
  - **The calibrations, 100 sets each, seeds 0..99.** As simulated: mean NEES 6.73 (was 7.64), 1 of
    100 outside its 99.9 % bound (seed 61, 26.5; was 3: seeds 0, 69, 71). Range noise of 10 mm:
    5.19 (was 7.12), 1 of 100 outside (seed 49, 22.9 against the bound 22.46; was seed 55 at 34.7).
    1 % is the target's limit ("never ... in more than 1 % of sets"), not comfortably inside it: an
    honest covariance puts 0.1 % there.
  - **What remains, measured.** Seed 61 (as simulated) reads 26.5 with its LiDAR boards at 6-dof
    NEES 3.6-23.6 against the truth (mean 11), but its components at 1.06 and 1.0: its boards err
    together in a way the residuals do not show. It is the simulator's default noise: with a LiDAR
    without noise or systematics seed 61 reads 7.8 (boards 0.5-7.6), without the systematics but
    with the default noise 34.7 (an earlier, 177-point run). That noise moves each return off its
    beam (1.6, 1.6 and 10 mm along the board's x, y and normal, the paper's baseline); a LiDAR's
    returns stay on their beams, and the stage puts them on the plane along their rays, which turns
    the 10 mm along the normal into in-plane shifts of 10 mm x tan(incidence). The stage's boards
    read 3.04 in-plane and 7.57 over 6 dof as simulated (0.8 % and 2.4 % beyond the 99.9 % points),
    3.20 and 6.60 with range noise (0.8 % and 1.4 %; one board of seed 33 left out of these: at
    3.8 m and 10 mm of noise the small board failed the board tests and the stage took a
    board-sized patch of no contrast 1.8 m away by its outline, NEES in the millions, which the
    calibration's corner-order check refuses).
  - **The held-out gate** (`held_out.held_out_gate`) now counts a board that a model's own
    chi-square gate dropped as failing under that model. Seed 3 with four boards moved (the test
    of tests/test_moved_board.py then): under `none` the moved frame 0003 stayed in (held-out chi2
    35.5) and let the moved frame 0011 pass (13.5), while `range` and `beams` had dropped 0003 and
    put 0011 at 37.7 and 36.2; the gate asked for a failure under every model, so neither went, and
    the run exited 3 ("the result uses frames whose image puts the board far from where the scan
    saw it (0011)"). With the new rule 0003 is dropped first, then 0011, and the result is written
    at NEES 3.5 (these on the 65-point hexagonal footprint). On the final footprint seed 3 exits 3
    earlier (the corner order: two extrinsics fit 8 frames each), and the test uses seed 21, where
    the rule drops the moved 0005 (before, the run wrote from 7 frames with two moved ones in). With
    four boards moved (the fifth section, 30 sets): 22
    written, none outside its bound, mean NEES 5.01, 140 of 226 frames used (62 %: the moved ones
    are a third to a half); before, 21 written, one outside (seed 11, now 4.7), mean 6.61.

The bullets below are the earlier readings, on the 7-point footprint; their figures are those of
the sections marked 811567b and before.

- **As simulated, 100 sets: over-confident, target not met.** The small board is found and placed
  in almost every frame (988 of 1000 used), but the mean NEES is 7.64 (median 6.76) and 3 of 100
  written results lie beyond their 99.9 % bound (seeds 0, 69 and 71, NEES 23.8, 24.4, 24.4, each
  GOOD with every frame used). The first 50 seeds alone read 6.49 with one set outside, which an
  earlier reading took for honest on average; seeds 50..99 read 8.8 with two. The LiDAR stage's
  boards are over-confident at 2-6 beams (mean 6-dof NEES 7.92 against 6, in-plane 3.37 against 3).
  Measured in session 47, and not changed:
  - **It does not go away with more frames.** Mean NEES by frames per set (20 sets each): 8 frames
    8.95, 9 8.14, 10 6.22, 11 7.84, 12 7.06 (range noise, 10 sets each: 9.36, 7.66, 7.02, 7.05,
    6.44); but seeds 50..79 simulated with 16 and with 24 frames read 6.73 and 7.45 (30 sets each,
    se 0.73; none outside): no trend beyond the noise, and no growth either. The over-confidence is
    a constant factor.
  - **Not the sensor model.** Seeds 0, 69, 71, 80 and 88 forced to each model: NEES 19-26 under
    `none`, `range` and `beams` alike (`none` 30-42 in two of them).
  - **Partly the image.** The detected corners lie 0.04-0.08 px RMS from the true projections, the
    residuals at 0.77 of the stated noise (chi2/dof), but each board's corners share an offset of
    0.005-0.035 px, random per board, that the per-corner noise model cannot hold and the residuals
    cannot show (the board's pose absorbs it): a board's pose from its image alone, under the stated
    noise, has mean NEES 7.74 (median 4.68; 22 sets, seeds 50..71, about 220 boards). With a common
    shift of 0.01 px per board added to its corners' covariance (an experiment, a rank-2 term in
    each view's whitening) the camera side reads 5.36, but seed 69's extrinsic only 24.4 -> 24.0
    (0.02 px: 22.8).
  - **And the LiDAR side**, whose boards read 7.92 (above). In the three sets outside (69, 0, 71;
    chosen for it) the mean over a set's boards of the LiDAR fit's centre error (in the camera
    frame, the fit mapped by the true extrinsic) lies 2.0-2.2 stated sigmas of that mean from the
    truth along the depth (+1.1, -1.0, +1.3 mm) and 1.0-2.2 across (chi2 of the mean 9.6, 7.7, 5.3
    for 3 dof); the camera side's mean reads chi2 3.5, 0.2 and 14.8.
  - **An error common to a set's boards, which no board-level test sees.** Under the true extrinsic
    each board's camera pose and LiDAR pose disagree at mean chi2 7.52 (median 6.16; 6 dof, their
    two covariances; 156 boards of seeds 50..65). Under the solved extrinsic they agree: in seeds
    69, 71 and 0 each board's image held out and predicted from the other boards reads chi2/6 of
    0.88-1.11 on average, under every model, and the components stay at 1.0-1.19. So the extrinsic
    takes up an error all of a set's boards share, and its covariance does not carry it; with the
    constant factor above, as an estimated quantity common to the boards would (a global term whose
    stated uncertainty is too small), not as independent boards would. Its source is not found:
    the LiDAR's systematics are part of it (above), but without them the calibrations still read
    8.42; a common shift of 0.02 px per view in the corners' covariance gives 8.55, and 9.10 with
    components free below 1, against 8.82 (seeds 50..79).
  - **A lead: the edges' sampling term at few beams.** With a LiDAR without noise or systematics
    (`range_noise_m=0`, systematics off) seeds 50..79 still read 6.91 (median 5.20) and seed 55 lies
    outside (35.9); with 10 mm of range noise and no systematics 7.28 (seed 55: 40.0). Seed 55's frame
    0008 (2.66 m, 5 beams, no noise): the pattern's fit alone (outline off) is 1.8 mm off along the
    board's x with a stated 0.38 mm (in-plane NEES 43). Its sampling term
    (`covariance.sampling_covariance`) is 0.11 mm: the fitted footprint blur (5 mm) exceeds half the
    returns' spacing along the ring (9.3 mm), so the edges' quantisation is discounted to
    `(delta / 10)^2 / 12`, while the simulator's footprint is a 7-sample disc, coarser than the
    soft-edge model's Gaussian blur. Without the discount (blur 0 in that term) frame 0008 reads NEES
    6.0 and the set's other boards 0.1-0.7 (too wide); over the stage's 297 boards of seeds 0..29
    (default noise) the in-plane NEES goes from 3.34 to 1.74 (3 when honest): the truth lies
    between, and the over-confidence is in the tail (boards like 0008), not the mean. A ring-free
    clustering of the soft-edge sandwich by the nearest grid node moves 0008 only from 41.7 to 32.4.
    With the discount's floor at a third of the gap instead of a tenth (`(delta / 3)^2 / 12`): the
    stage's 297 boards 2.86 in-plane (beyond chi2(3)'s 99 % point 1.3 %, beyond 99.9 % none; with a
    tenth 3.34, 3.7 % and 0.7 %); bench_shape's larger board (135 boards, seeds 0..5) 2.46 against
    2.83; the calibrations of seeds 50..79 7.84 (one outside) against 8.82 (two). Better, not
    enough, and a constant fitted to this simulator's footprint: not changed.
  - **Partly the LiDAR's systematics.** The stage alone (30 sets, 250 boards; mean 6-dof NEES 8.05):
    its errors per axis are within their sigmas (z^2 0.66-1.02) but not along its covariance's
    tightest directions (z^2 2.22 along the tightest out-of-plane one, the plane's offset); the
    boards' normal offset is common to a set's boards (the per-set mean of z, times sqrt(n), has
    variance 1.83 against 1 for independent boards): the per-beam biases (3 mm) and the dark print's
    4 mm, shared by every frame of a set. Without those systematics the stage reads 6.67 (out of
    plane 2.49, in-plane 3.04), but the calibrations of seeds 50..70 still read 8.42 (none outside).
  - **Partly the simulator's default noise.** With 10 mm of range noise along each beam instead
    (the second section) seeds 50..99 read 7.51 (median 6.11), one set outside (seed 55, NEES 34.7:
    two of its seven boards 19.6 and 37.4 against the truth, in-plane 10.0 and 15.7).
  - **Not the components' floor.** Components estimated below 1 (floor 0.01 instead of 1, seeds
    50..66): 9.42 against 8.59 on the same seeds; the boards' component rises to 0.5-2.3 but the
    bearings' falls to 0.5-1.0, and the extrinsic is no more honest. The like change (floor 0.05)
    takes the joint sessions' Monte Carlo from 4.41 to 4.98 (docs/bench_joint_lidar.md): the noise
    policy's conservatism there partly hides the small board's over-confidence here, so it is left
    as it is until the error the small board's sets share is found.
- **With 4 boards of 8-12 moved 20-60 mm and 1-3 deg before the photo** (a hand-held board, sensors
  not synchronised: a third to a half of the frames wrong by construction, so the 80 % branch cannot
  hold) the corner-order check and the gates drop most moved frames. Before the held-out gate, seeds
  3 and 11 were written outside their bound (NEES 50.2 and 29.9): a moved board the gate kept had
  inflated the LiDAR boards' variance component itself (14.0 in seed 3; 138 in seed 11), so the
  chi-square gate, judging it under that noise, passed it. Held out, predicted from the other boards,
  such a board stands out under every sensor model (seed 3's frame 0011, moved 27 mm and 1.7 deg:
  chi2 34-40 against 13 at most for the other boards). With the gate it is dropped
  (`held_out.held_out_gate`, p = 0.001 under every candidate model after each model's median
  scale): seed 3 is 1.4 mm and 0.026 deg from the truth at NEES 2.7 (was 10.7 mm, 0.195 deg), seed
  16 0.9 mm (was 6.7 mm), seed 22 1.4 mm (was 8.2 mm); mean NEES of the written sets 9.09 -> 7.04,
  outside the bound 2 -> 1 of 30.
- **Two moved boards that pull the extrinsic together** are not caught board by board: each is
  predicted from an extrinsic the other pulled, and the board component they inflate (68 in seed
  20, 138 in seed 11) widens every held-out test. The run's refusal for residuals far above the
  stated noise (`finish.require_within_noise`) named no frame, because under the solve's extrinsic
  no image lies 5 x its LiDAR fit's sigma from its scan. It now also looks under the extrinsic
  most frames agree on (`causes.moved_boards` with `consensus`: the boards' LiDAR corners mapped
  onto their images' corners, each frame Cauchy-weighted by its gap, iterated from the solve's
  extrinsic):
  seed 20, written before at 25 mm and 0.39 deg from the truth (FAIR), now exits 3 naming 0002
  (the good boards fall to 2-5 mm from their scans, the moved ones stay at 20-30 mm). The check is
  reached only when a component is far above (board 16, bearing 4; the honest sets' largest 2.3
  and 1.0, the recorded sets' 5.5-6.7), so nothing else changes: written 20 of 30, mean NEES 6.80.
  **Seed 11 is still written outside** (16 mm, NEES 29.9): under the consensus its moved boards sit
  23 and 20 mm from their scans, 1.7 and 3.8 x their LiDAR fits' stated sigmas (13.7 and 5.3 mm),
  below the 5 x that names a frame. Five sets exit 3 in the
  corner-order check before the graph ("cannot be decided", advice: turn the board in its plane),
  whose advice does not see the moved boards (issue 38's fifth item).
"""


if __name__ == "__main__":
    raise SystemExit(main())
