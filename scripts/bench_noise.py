"""Boards under range noise (issue 38.1): Monte Carlo of whole calibrations at 15 and 30 mm of range
noise per return, the print invisible to the LiDAR and visible.

Each set is bench_shape.py's (VLP-16 + 1280 x 720 pinhole, 7 x 9 board of 100 mm squares with a 70 mm
margin, 2-4 m, 20 + seed mod 17 frames, the simulator's systematics on) with one of two noises
(``--noise``): ``range`` (default), 15 and 30 mm of range noise along each beam on every surface
(``SimulationSpec.range_noise_m``: a real LiDAR's noise, its beams' directions exact); ``board``, the
simulator's default noise scaled (``SimulationSpec.noise_scale`` 1.5 and 3: the board's returns moved
along its normal by 15 / 30 mm and in its plane by 2.4 / 4.8 mm, other surfaces 45 / 90 mm along the
beam), which also moves each board return off its beam. ``--scene open`` has no walls
(``SceneOptions.room=None``): rays above the horizon return nothing, so the board's outline shows only
where the ground lies behind it, the scene where the issue's boards were refused; ``--scene room`` is
bench_shape.py's. Each calibration is the command line's (``pipeline.run``). Per run: frames used, the
extrinsic's errors and NEES (6 dof), the LiDAR stage's NEES per board found (6 dof and in-plane), and
the reasons of frames not used.

    nice python3 scripts/bench_noise.py --sets 50 --scene open --sink /tmp/bench_noise.jsonl  # ~1 min a set
    python3 scripts/bench_noise.py --from-sink --sink /tmp/bench_noise.jsonl --write  # docs/bench_noise.md
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

from _shared import append_sink, load_sink, write_between
from bench_shape import run_one, spec_for, summary  # (scripts/ is the running script's folder)

from ilcc_graph.run.result import RunOptions
from ilcc_graph.simulate import SimulationSpec, simulate_dataset

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bench_noise.md"
LEVELS = {"15 mm": 0.015, "30 mm": 0.030}  # range noise along the beam, or along the board's normal
FIELDS = ("invisible", "print")
NOISES = ("range", "board")


def noisy_spec(seed: int, field: str, level_m: float, scene: str, noise: str = "range") -> SimulationSpec:
    """bench_shape's set ``seed`` with ``level_m`` of noise (``noise``: "range" along every beam,
    "board" the default noise scaled to that along the board's normal), in a room or an open scene."""
    base = spec_for(seed, field)
    if noise == "range":
        spec = replace(base, range_noise_m=level_m)
    else:
        spec = replace(base, noise_scale=level_m / base.board_noise_sigma_m[2])  # its sigma along the normal
    return replace(spec, scene=replace(spec.scene, room=None)) if scene == "open" else spec


def run_set(seed: int, scene: str, cache: Path, fields: Sequence[str] = FIELDS, noise: str = "range") -> dict:
    """Set ``seed`` at every noise level, the print as each of ``fields`` (invisible, print)."""
    runs = {}
    for label, level in LEVELS.items():
        for field in fields:
            tmp = Path(tempfile.mkdtemp(prefix=f"bench_noise_{seed}_", dir=cache))
            try:
                spec = noisy_spec(seed, field, level, scene, noise)
                runs[f"{field}, {label}"] = run_one(simulate_dataset(tmp / "set", spec), spec, RunOptions())
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
    return {"seed": seed, "scene": scene, "noise": noise, "runs": runs}


def noise_of(record: dict) -> str:
    """A sink record's noise (records before ``--noise`` existed are "board")."""
    return str(record.get("noise", "board"))


def report(sets: Sequence[dict], argv: Sequence[str], scene: str, noise: str) -> str:
    """The markdown of one scene's table under one noise."""
    names = [
        f"{f}, {label}" for label in LEVELS for f in FIELDS if all(f"{f}, {label}" in x["runs"] for x in sets)
    ]
    s = {n: summary(sets, n) for n in names}
    rows = [
        f"| {n} | {r['sets'] - r['failed']}/{r['sets']} | {r['used']}/{r['frames']} "
        f"({r['used'] / max(r['frames'], 1):.0%}) | {r['rot_median']:.3f} / {r['rot_p90']:.3f} | "
        f"{r['trans_median']:.2f} / {r['trans_p90']:.2f} | {r['nees_mean']:.2f} / {r['nees_median']:.2f} | "
        f"{r['board_nees_mean']:.2f} | {r['board_inplane_mean']:.2f} |"
        for n, r in s.items()
    ]
    reasons = Counter(
        d.split(":")[0][:90] for st in sets for n in names for d in st["runs"][n].get("dropped", [])
    )
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return "\n".join([
        f"### Scene: {scene}, {'range noise along the beam' if noise == 'range' else 'board noise scaled'}",
        "",
        f"`python scripts/bench_noise.py {' '.join(argv)}` ({stamp}); {len(sets)} sets (seeds "
        f"{', '.join(str(x['seed']) for x in sets)}).",
        "",
        "| run | sets calibrated | frames used | rotation deg median / 90 % | translation mm median / 90 % | "
        "NEES mean / median | board NEES (6 dof) mean | board in-plane NEES (3 dof) mean |",
        "|---|---|---|---|---|---|---|---|",
        *rows,
        "",
        "Frames not used, by reason: "
        + ("; ".join(f"{k} ({v})" for k, v in reasons.most_common()) or "none."),
        "",
    ])  # fmt: skip


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", type=int, default=5)
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--scene", choices=("open", "room"), default="open")
    ap.add_argument("--noise", choices=NOISES, default="range", help="range: along every beam; board: scaled")
    ap.add_argument("--fields", default=",".join(FIELDS), help="the print: invisible, print or both")
    ap.add_argument("--sink", default=str(Path(tempfile.gettempdir()) / "bench_noise.jsonl"))
    ap.add_argument("--cache", default=tempfile.gettempdir())
    ap.add_argument("--from-sink", action="store_true", help="only summarise the sink")
    ap.add_argument(
        "--write", action="store_true", help="write docs/bench_noise.md (every scene in the sink)"
    )
    args = ap.parse_args(argv)
    sink = Path(args.sink)
    if not args.from_sink:
        done = {(s["seed"], s["scene"], noise_of(s)) for s in load_sink(sink)}
        for seed in range(args.seed0, args.seed0 + args.sets):
            if (seed, args.scene, args.noise) in done:
                continue
            t0 = time.perf_counter()
            res = run_set(seed, args.scene, Path(args.cache), args.fields.split(","), args.noise)
            append_sink(sink, res)
            brief = {
                n: r.get("failure")
                or f"{r['used']}/{r['n_frames']} {r['rot_deg']:.3f} deg {r['trans_mm']:.2f} mm "
                f"NEES {r['nees']:.1f}"
                for n, r in res["runs"].items()
            }
            print(f"set {seed} ({args.scene}): {time.perf_counter() - t0:.0f} s {brief}", flush=True)
    every = load_sink(sink)
    groups = sorted({(noise_of(s), s["scene"]) for s in every}) if args.write else [(args.noise, args.scene)]
    for noise, scene in groups:
        text = report([s for s in every if s["scene"] == scene and noise_of(s) == noise], argv, scene, noise)
        print(text)
        if args.write:
            write_between(
                DOC,
                f"<!-- bench_noise:{noise}:{scene}:begin -->",
                f"<!-- bench_noise:{noise}:{scene}:end -->",
                text,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
