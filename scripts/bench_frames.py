"""Cost that grows with the work (issue 37): ``ilcc-graph calibrate`` of VLP-16 + 1280 x 720 pinhole sets
of 20 / 80 / 320 frames, today's code against this tree: wall time, wall time per frame, the machine's
CPU time, the main process's own CPU time (getrusage of the command: the fork server's workers and the
solve's helper process are not in it; on a shared machine it moves less than the wall time) and the
peak resident memory of the command and all its processes.

The sets are bench_shape.py's rig (VLP-16, 1280 x 720 pinhole, 7 x 9 board of 100 mm squares, 70 mm
margin, 2-4 m, seed 0, the print visible to the LiDAR) with ``--frames`` board poses each, simulated once
into ``--cache``. Each run is ``python -m ilcc_graph.app calibrate DATA --out OUT --jobs 2 --no-report``
(``--report`` also with the report) in its own process, the two versions alternately (``--repeats``);
``--new-only`` sizes are run with this tree only. Targets: 80 frames in at most 0.25 s of wall time
per frame on two cores; 320 frames at most 4.5 times the time of 80.

    nice python scripts/bench_frames.py --frames 20,80 --new-only 320 --write  # docs/bench_speed.md
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
from _shared import baseline_tree
from bench_shape import spec_for  # (scripts/ is the running script's folder)
from bench_speed import DOC, ROOT, replace_section, run_measured

HEADING = "\n## Cost that grows with the work: VLP-16 + 1280 x 720 pinhole\n"


def make_set(n: int, cache: Path) -> Path:
    """The ``n``-frame set, simulated once into ``cache``."""
    data = cache / f"bench-vlp16-720p-{n}"
    if not (data / "ground_truth.yaml").is_file():
        from ilcc_graph.simulate import simulate_dataset

        simulate_dataset(data, dataclasses.replace(spec_for(0, "print"), n_frames=n))
    return data


def run(src: Path, data: Path, out: Path, extra: list[str]) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, PYTHONPATH=str(src))
    cmd = [sys.executable, "-m", "ilcc_graph.app", "calibrate", str(data), "--out", str(out), "--jobs", "2"]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    p, wall, cpu, peak = run_measured(cmd + extra, out.parent, env)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)  # the command's own process (a fork server's
    own = r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime  # workers are not its waited children)
    if p.returncode not in (0, 3):  # 3: calibrated, verdict below the bar
        raise RuntimeError(f"{cmd} failed ({p.returncode}):\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}")
    used = sum(1 for line in (out / "calibration.yaml").read_text().splitlines() if "used: true" in line)
    return {"wall": wall, "cpu": cpu, "own": own, "peak_mb": peak, "rc": p.returncode, "used": used}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", default="20,80", help="sizes run with both versions")
    ap.add_argument("--new-only", default="320", help="sizes run with this tree only ('' for none)")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--report", action="store_true", help="also run with the report")
    ap.add_argument("--baseline", default=None, help="git revision of today's code (default: merge-base)")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "ilcc_bench_frames")
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args(argv)
    both = [int(x) for x in args.frames.split(",") if x]
    new_only = [int(x) for x in args.new_only.split(",") if x]
    rev, head, work, base = baseline_tree(ROOT, args.baseline, "bench_frames_")
    codes = {f"today ({rev[:7]})": base, f"this tree ({head})": ROOT}
    modes = {"--no-report": ["--no-report"], **({"report": []} if args.report else {})}
    rows = []
    for n in sorted(set(both) | set(new_only)):
        data = make_set(n, args.cache)
        names = list(codes) if n in both else list(codes)[1:]
        for mode, extra in modes.items():
            rs: dict[str, list[dict]] = {c: [] for c in names}
            for _ in range(args.repeats):
                for c in names:
                    rs[c].append(run(codes[c], data, work / "out", extra))
                    print(n, mode, c, rs[c][-1], flush=True)
            for c in names:
                rows.append(row(n, mode, c, rs[c]))
    text = section(rows, args, rev, head)
    print(text)
    if args.write:
        replace_section(HEADING, text)
        print(f"wrote {DOC}")
    shutil.rmtree(work, ignore_errors=True)
    return 0


def row(n: int, mode: str, code: str, rs: list[dict]) -> dict:
    wall = float(np.median([r["wall"] for r in rs]))
    return {
        "frames": n, "mode": mode, "code": code, "walls": [r["wall"] for r in rs], "wall": wall,
        "per_frame": wall / n, "cpu": float(np.median([r["cpu"] for r in rs])),
        "own": float(np.median([r["own"] for r in rs])),
        "peak": max(r["peak_mb"] for r in rs), "used": rs[-1]["used"], "rc": rs[-1]["rc"],
    }  # fmt: skip


def section(rows: list[dict], args: argparse.Namespace, rev: str, head: str) -> str:
    lines = [
        "| frames | code | command | wall s (each run) | wall s per frame | CPU s | main process CPU s "
        "| peak MB | frames used | exit |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cmd = "`calibrate --no-report`" if r["mode"] == "--no-report" else "`calibrate`"
        lines.append(
            f"| {r['frames']} | {r['code']} | {cmd} | {', '.join(f'{w:.1f}' for w in r['walls'])} | "
            f"{r['per_frame']:.3f} | {r['cpu']:.1f} | {r['own']:.1f} | {r['peak']:.0f} "
            f"| {r['used']}/{r['frames']} | {r['rc']} |"
        )
    new = {(r["frames"], r["mode"]): r for r in rows if r["code"].startswith("this tree")}
    notes = []
    for mode in dict.fromkeys(r["mode"] for r in rows):
        if (80, mode) in new:
            r80 = new[(80, mode)]
            met = "met" if r80["per_frame"] <= 0.25 else "missed"
            notes.append(f"80 frames, {mode}: {r80['per_frame']:.3f} s per frame (target 0.25: {met})")
            if (320, mode) in new:
                k = new[(320, mode)]["wall"] / r80["wall"]
                notes.append(
                    f"320 / 80 frames, {mode}: {k:.2f}x "
                    f"(target at most 4.5x: {'met' if k <= 4.5 else 'missed'})"
                )
    load = os.getloadavg()
    return (
        HEADING + "\n"
        f"`nice python scripts/bench_frames.py --frames {args.frames} --new-only {args.new_only!r} "
        f"--repeats {args.repeats}{' --report' if args.report else ''}` (issue 37). "
        + __doc__.split("\n\n")[1]
        + "\n\n" + "\n".join(lines) + "\n\n" + "\n".join(f"- {x}" for x in notes) + "\n\n"
        f"Machine: {os.cpu_count()} cores shared with other work; load average {load[0]:.1f} / "
        f"{load[1]:.1f} / {load[2]:.1f} (1 / 5 / 15 min) at the end.\n"
    )  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
