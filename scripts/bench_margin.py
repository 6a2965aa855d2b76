"""A board whose white margin is not the configured one (issue 38, "the margin as a measured
quantity"): Monte Carlo of whole calibrations, print visible, the configured margin right and 100 mm
narrower than the board's.

Each set is bench_shape.py's (VLP-16, 1280 x 720 pinhole, 7 x 9 board of 100 mm squares, 2-4 m, a
stand behind the board, a person in 60 % of the frames, the simulator's systematics on, 20-36 frames),
the print on a panel with a 170 mm white margin (the 70 mm of bench_shape's board plus 100 mm a
side). The set is simulated once and calibrated as the command line does (``pipeline.run``) with
config.yaml's ``board.margin`` as:

- ``right``: 0.17 (the board's);
- ``narrow``: 0.07 (100 mm narrower: the LiDAR stage measures the margin where the print shows and
  the outline checks the fit as the board measured; the run warns once with the measured margin);
- ``narrow, not measured``: 0.07 with ``LidarOptions(margin_contradiction_m=inf)``: no board's margin
  ever contradicts the configured one, so the outline checks and pulls the print's fit with the
  configured margin (the code path before the margin was measured; ``--before`` sets only).

Per run: frames used, the extrinsic's errors (rotation deg, translation mm) and NEES against the truth
(6 dof), the margin the run reported (calibration.yaml's ``lidar_margin_*`` diagnostics) and the
warnings the run logged about it.

    nice -n 10 python3 scripts/bench_margin.py --sets 50 --before 10 --sink /tmp/bench_margin.jsonl
    python3 scripts/bench_margin.py --from-sink /tmp/bench_margin.jsonl --write   # docs/bench_margin.md

Sinks of runs in parallel (other ``--first``) are joined by concatenating the files.

Each finished set is appended to the sink (one JSON line), so a run can be stopped and resumed.
"""

from __future__ import annotations

import argparse
import logging
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import yaml
from _shared import append_sink, load_sink, write_between  # (scripts/ is the running script's folder)
from bench_shape import CHI2_6_95, _nees, board_nees, pose_error, spec_for

from ilcc_graph.board import Board
from ilcc_graph.datasets import open_source
from ilcc_graph.errors import BoardNotFound, CalibrationError
from ilcc_graph.lidar import LidarOptions, estimate_board
from ilcc_graph.run.pipeline import run
from ilcc_graph.run.result import RunOptions
from ilcc_graph.run.stages import StageOptions
from ilcc_graph.simulate import SimulationSpec, board_placements, simulate_dataset, simulate_frames

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bench_margin.md"
TRUE_MARGIN, NARROW = 0.17, 0.07
BLIND = RunOptions(stages=StageOptions(lidar=LidarOptions(margin_contradiction_m=float("inf"))))
RUNS = {  # name -> (configured margin, run options)
    "right": (TRUE_MARGIN, RunOptions()),
    "narrow": (NARROW, RunOptions()),
    "narrow, not measured": (NARROW, BLIND),
}


def spec(seed: int) -> SimulationSpec:
    """bench_shape's set ``seed`` (print visible) on a panel with a 170 mm margin."""
    return replace(spec_for(seed, "print"), board=Board(7, 9, 0.1, TRUE_MARGIN, TRUE_MARGIN))


def set_margin(data: Path, margin: float) -> None:
    """config.yaml's ``board.margin`` set to ``margin`` (m)."""
    cfg = yaml.safe_load((data / "config.yaml").read_text(encoding="utf-8"))
    cfg["board"]["margin"] = margin
    (data / "config.yaml").write_text(yaml.safe_dump(cfg), encoding="utf-8")


class _Warnings(logging.Handler):
    """The warnings logged about the margin during one run."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if "margin" in record.getMessage():
            self.lines.append(record.getMessage())


def run_arm(data: Path, sp: SimulationSpec, options: RunOptions) -> dict:
    """One calibration of ``data`` as the command line runs it; its figures against the truth."""
    t0 = time.perf_counter()
    out: dict = {"n_frames": int(sp.n_frames)}
    catch = _Warnings()
    logging.getLogger("ilcc_graph").addHandler(catch)
    try:
        res = run([open_source(data)], options)
    except CalibrationError as err:
        out.update(failure=f"{type(err).__name__}: {err}", seconds=time.perf_counter() - t0)
        return out
    finally:
        logging.getLogger("ilcc_graph").removeHandler(catch)
    cal = res.calibration
    T_true = np.asarray(sp.T_cam_lidar)
    xi = pose_error(cal.T_cam_lidar, T_true)
    truth = dict(zip([f"{i + 1:04d}" for i in range(sp.n_frames)], board_placements(sp), strict=True))
    boards = [(f.name, f.board) for f in res.sessions[0].observation.frames if f.board is not None]
    said = Board(7, 9, 0.1, 0.0, 0.0)  # the pattern's frame is the same whatever the margin
    out.update(
        used=int(sum(f.used for f in cal.frames)),
        rot_deg=float(np.degrees(np.linalg.norm(xi[:3]))),
        trans_mm=float(1e3 * np.linalg.norm(cal.T_cam_lidar[:3, 3] - T_true[:3, 3])),
        nees=_nees(xi, cal.covariance),
        board_nees=[float(board_nees(b, truth[n], said)[0]) for n, b in boards],
        margin={k: v for k, v in cal.diagnostics.items() if k.startswith("lidar_margin")},
        board_margin=[[b.diagnostics.get(f"margin_{a}_mm", np.nan) for a in ("long", "short")]
                      for _, b in boards],
        board_contradicted=int(sum(1 for _, b in boards if b.diagnostics.get("margin_contradicted"))),
        warnings=catch.lines,
        seconds=time.perf_counter() - t0,
    )  # fmt: skip
    return out


def run_set(seed: int, cache: Path, before: bool) -> dict:
    """Set ``seed`` simulated once and calibrated with each configured margin; the cache removed."""
    tmp = Path(tempfile.mkdtemp(prefix=f"bench_margin_{seed}_", dir=cache))
    try:
        sp = spec(seed)
        data = simulate_dataset(tmp / "set", sp)
        runs = {}
        for name, (margin, options) in RUNS.items():
            if name == "narrow, not measured" and not before:
                continue
            set_margin(data, margin)
            runs[name] = run_arm(data, sp, options)
        return {"seed": seed, "runs": runs}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def stage_set(seed: int) -> dict:
    """The LiDAR stage alone on set ``seed``'s scans, sharp and realistic edges
    (``Systematics.edge_returns``), with each run's configured margin: per board the NEES (6 dof) and
    its in-plane part (rz, tx, ty; 3 dof) against the true pose, and whether the margin contradicted."""
    out: dict = {"seed": seed, "stage": {}}
    for edges in (False, True):
        sp = spec(seed)
        sp = replace(sp, systematics=replace(sp.systematics, edge_returns=edges))
        rows: dict[str, list] = {n: [] for n in RUNS}
        for f in simulate_frames(sp):
            for name, (margin, options) in RUNS.items():
                board = Board(7, 9, 0.1, margin, margin)
                try:
                    fit = estimate_board(f.scan, board, sp.lidar_model, options=options.stages.lidar)
                except BoardNotFound:
                    rows[name].append(None)
                    continue
                n6, n3 = board_nees(fit, f.T_lidar_board, board)
                rows[name].append([n6, n3, fit.diagnostics.get("margin_contradicted", 0.0)])
        out["stage"]["realistic" if edges else "sharp"] = rows
    return out


def stage_report(sets: Sequence[dict]) -> list[str]:
    """The stage's table: per edge model and run, boards found, mean NEES (6 dof, < 100) and in-plane."""
    lines = [
        "## The LiDAR stage alone",
        "",
        f"{len(sets)} sets (seeds {min(x['seed'] for x in sets)}..{max(x['seed'] for x in sets)}), every "
        "scan through `estimate_board` with each run's configured margin, sharp edges and realistic ones "
        "(`Systematics.edge_returns`: the footprint's returns at the outline). Per board against its true "
        "pose: NEES 6 dof (mean 6 when honest) and its in-plane part (rz, tx, ty; 3 dof, mean 3).",
        "",
        "| edges | run | boards found | NEES 6 dof mean | in-plane NEES mean | in-plane <= 7.81 | "
        "margin contradicted |",
        "|---|---|---|---|---|---|---|",
    ]
    for edges in ("sharp", "realistic"):
        for name in RUNS:
            rows = [r for s in sets for r in s["stage"][edges][name]]
            ok = np.array([r for r in rows if r is not None and r[0] < 100]).reshape(-1, 3)
            lines.append(
                f"| {edges} | {name} | {sum(r is not None for r in rows)}/{len(rows)} | "
                f"{ok[:, 0].mean():.2f} | {ok[:, 1].mean():.2f} | {100 * np.mean(ok[:, 1] <= 7.81):.0f} % | "
                f"{int(ok[:, 2].sum())} |"
            )
    return lines


def _pct(x: Sequence[float], q: float) -> float:
    return float(np.percentile(x, q)) if len(x) else float("nan")


def summary(sets: Sequence[dict], name: str) -> dict:
    """One run's figures over the sets that have it."""
    runs = [s["runs"][name] for s in sets if name in s["runs"]]
    ok = [r for r in runs if "failure" not in r]
    nees = np.array([r["nees"] for r in ok])
    reported = [r for r in ok if r["margin"]]
    got = {a: [r["margin"][f"lidar_margin_{a}_mm"] for r in reported if f"lidar_margin_{a}_mm" in r["margin"]]
           for a in ("long", "short")}  # fmt: skip
    boards = np.array([m for r in ok for m in r["board_margin"]], dtype=np.float64).reshape(-1, 2)
    return {
        "sets": len(runs), "failed": len(runs) - len(ok),
        "used": sum(r["used"] for r in ok), "frames": sum(r["n_frames"] for r in ok),
        "rot": _pct([r["rot_deg"] for r in ok], 50), "mm": _pct([r["trans_mm"] for r in ok], 50),
        "rot90": _pct([r["rot_deg"] for r in ok], 90), "mm90": _pct([r["trans_mm"] for r in ok], 90),
        "nees": float(nees.mean()) if ok else np.nan, "nees_med": _pct(nees, 50),
        "cover": float(np.mean(nees <= CHI2_6_95)) if ok else np.nan,
        "reported": len(reported), "warned": sum(1 for r in ok if r["warnings"]),
        "warnings_max": max((len(r["warnings"]) for r in ok), default=0),
        "long": got["long"], "short": got["short"],
        "boards_measured": int(np.isfinite(boards).any(axis=1).sum()), "boards": len(boards),
        "contradicted": sum(r.get("board_contradicted", 0) for r in ok),
        "board_nees": _board_nees(ok),
        "board_long": boards[:, 0][np.isfinite(boards[:, 0])].tolist(),
        "board_short": boards[:, 1][np.isfinite(boards[:, 1])].tolist(),
        "failures": [r["failure"] for r in runs if "failure" in r],
    }  # fmt: skip


def _board_nees(runs: Sequence[dict]) -> float:
    """Mean LiDAR NEES (6 dof) of the runs' boards, those below 100 (a half-turn mix-up aside)."""
    v = [x for r in runs for x in r["board_nees"] if x < 100]
    return float(np.mean(v)) if v else float("nan")


def _spread(v: Sequence[float]) -> str:
    """median [min, max] of values (mm), or "-"."""
    return f"{np.median(v):.1f} [{min(v):.1f}, {max(v):.1f}]" if len(v) else "-"


def paired(sets: Sequence[dict], a: str, b: str) -> str:
    """Run ``a`` against ``b`` on the sets both calibrated: median differences of the errors."""
    both = [(s["runs"][a], s["runs"][b]) for s in sets if a in s["runs"] and b in s["runs"]]
    both = [(x, y) for x, y in both if "failure" not in x and "failure" not in y]
    if not both:
        return f"{a} against {b}: no set calibrated by both."
    dr = [x["rot_deg"] - y["rot_deg"] for x, y in both]
    dt = [x["trans_mm"] - y["trans_mm"] for x, y in both]
    na, nb = (np.mean([r["nees"] for r in x]) for x in zip(*both, strict=True))
    ba, bb = (_board_nees(x) for x in zip(*both, strict=True))
    return (
        f"{a} minus {b}, same {len(both)} sets: rotation error median {np.median(dr):+.4f} deg "
        f"(|difference| median {np.median(np.abs(dr)):.4f}), translation {np.median(dt):+.2f} mm "
        f"(|difference| median {np.median(np.abs(dt)):.2f}); mean NEES {na:.2f} against {nb:.2f}; the "
        f"boards' LiDAR NEES {ba:.2f} against {bb:.2f}."
    )


def report(sets: Sequence[dict], argv: Sequence[str]) -> str:
    """The markdown of docs/bench_margin.md."""
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    s = {n: summary(sets, n) for n in RUNS}
    lines = [
        "# A margin not the configured one (`scripts/bench_margin.py`)",
        "",
        (__doc__ or "").split("\n\n")[0].strip(),
        "",
        f"`python scripts/bench_margin.py {' '.join(argv)}` ({stamp}); {len(sets)} sets (seeds "
        f"{min(x['seed'] for x in sets)}..{max(x['seed'] for x in sets)}). Errors of T_cam_lidar against the "
        "truth; NEES with its covariance (6 dof, mean 6 when honest; 95 % below 12.59).",
        "",
        "| run | sets calibrated | frames used | rotation deg median / 90 % | translation mm median / 90 % | "
        "NEES mean / median | NEES <= 12.59 | runs that reported a measured margin | margin reported, "
        "long / short mm: median [min, max] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for n, r in s.items():
        if not r["sets"]:
            continue
        lines.append(
            f"| {n} | {r['sets'] - r['failed']}/{r['sets']} | {r['used']}/{r['frames']} | {r['rot']:.3f} / "
            f"{r['rot90']:.3f} | {r['mm']:.2f} / {r['mm90']:.2f} | {r['nees']:.2f} / {r['nees_med']:.2f} | "
            f"{100 * r['cover']:.0f} % | {r['reported']}/{r['sets'] - r['failed']} (warned: "
            f"{r['warned']}, at most {r['warnings_max']} warning a run) | {_spread(r['long'])} / "
            f"{_spread(r['short'])} |"
        )
    lines += ["", "Each board's measured margin (mm; the truth 170), over the runs' boards:", ""]
    for n, r in s.items():
        if r["sets"]:
            lines.append(
                f"- {n}: {r['boards_measured']} of {r['boards']} boards measured on an axis, "
                f"{r['contradicted']} contradicting config.yaml's margin, the boards' LiDAR NEES (6 dof, "
                f"< 100) mean {r['board_nees']:.2f}; long "
                f"{_spread(r['board_long'])} ({len(r['board_long'])} boards), short "
                f"{_spread(r['board_short'])} ({len(r['board_short'])} boards)"
            )
    lines += ["", "- " + paired(sets, "narrow", "right")]
    if s["narrow, not measured"]["sets"]:
        lines.append("- " + paired(sets, "narrow, not measured", "right"))
    failures = [f"- {n}: {f}" for n, r in s.items() for f in r["failures"]]
    lines += ["", "Calibrations that failed:" if failures else "No calibration failed.", *failures, ""]
    return "\n".join(lines)


def main(argv: Sequence[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", type=int, default=50)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--before", type=int, default=0, help="the first sets also run as before (not measured)")
    ap.add_argument("--sink", type=Path, default=Path(tempfile.gettempdir()) / "bench_margin.jsonl")
    ap.add_argument("--from-sink", type=Path, default=None)
    ap.add_argument("--write", action="store_true", help="write docs/bench_margin.md")
    ap.add_argument("--stage", type=int, default=0, help="the LiDAR stage alone on this many sets")
    ap.add_argument("--stage-sink", type=Path, default=Path(tempfile.gettempdir()) / "bench_margin_st.jsonl")
    args = ap.parse_args(argv)
    done = {s["seed"] for s in load_sink(args.stage_sink)}
    for seed in (s for s in range(args.first, args.first + args.stage) if s not in done):
        append_sink(args.stage_sink, stage_set(seed))
        print(f"stage, set {seed} done", flush=True)
    if args.stage:
        print("\n".join(stage_report(load_sink(args.stage_sink))))
        return 0
    if args.from_sink is None:
        done = {s["seed"] for s in load_sink(args.sink)}
        cache = Path(tempfile.mkdtemp(prefix="bench_margin_"))
        for seed in range(args.first, args.first + args.sets):
            if seed in done:
                continue
            t0 = time.perf_counter()
            got = run_set(seed, cache, seed < args.first + args.before)
            append_sink(args.sink, got)
            brief = {
                n: r.get("failure") or f"{r['used']}/{r['n_frames']} {r['rot_deg']:.3f} deg "
                f"{r['trans_mm']:.2f} mm NEES {r['nees']:.1f} "
                f"margin {r['margin'].get('lidar_margin_long_mm', '-')}"
                for n, r in got["runs"].items()
            }  # fmt: skip
            print(f"set {seed}: {time.perf_counter() - t0:.0f} s {brief}", flush=True)
        shutil.rmtree(cache, ignore_errors=True)
    sets = load_sink(args.from_sink or args.sink)
    text = report(sets, argv)
    if stage := load_sink(args.stage_sink):
        text += "\n" + "\n".join(stage_report(stage)) + "\n"
    print(text)
    if args.write:  # the figures between the markers; a reading written beside them is kept
        write_between(DOC, "<!-- bench_margin:begin -->", "<!-- bench_margin:end -->", text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
