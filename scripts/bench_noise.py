"""Boards under range noise (issue 38.1): Monte Carlo of whole calibrations at 15 and 30 mm of range
noise per return, the print invisible to the LiDAR and visible.

Each set is bench_shape.py's (VLP-16 + 1280 x 720 pinhole, 7 x 9 board of 100 mm squares with a 70 mm
margin, 2-4 m, 20 + seed mod 17 frames, the simulator's systematics on) with the simulator's LiDAR noise
scaled (``SimulationSpec.noise_scale``: the board's returns have 10 mm along its normal and 1.6 mm in its
plane at scale 1, other surfaces the model's 30 mm range sigma), 1.5 and 3 for 15 and 30 mm along the
board's normal. ``--scene open`` has no walls (``SceneOptions.room=None``): rays above the horizon return
nothing, so the board's outline shows only where the ground lies behind it, the scene where the issue's
boards were refused; ``--scene room`` is bench_shape.py's. Each calibration is the command line's
(``pipeline.run``). Per run: frames used, the extrinsic's errors and NEES (6 dof), the LiDAR stage's
NEES per board found (6 dof and in-plane), and the reasons of frames not used.

    nice python3 scripts/bench_noise.py --sets 5 --scene open --sink /tmp/bench_noise.jsonl  # ~10 min a set
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

from _shared import append_sink, load_sink
from bench_shape import run_one, spec_for, summary  # (scripts/ is the running script's folder)

from ilcc_graph.run.result import RunOptions
from ilcc_graph.simulate import SimulationSpec, simulate_dataset

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bench_noise.md"
SCALES = {"15 mm": 1.5, "30 mm": 3.0}  # noise along the board's normal: 10 mm x scale
FIELDS = ("invisible", "print")


def noisy_spec(seed: int, field: str, scale: float, scene: str) -> SimulationSpec:
    """bench_shape's set ``seed`` with the LiDAR noise times ``scale``, in a room or an open scene."""
    spec = replace(spec_for(seed, field), noise_scale=scale)
    return replace(spec, scene=replace(spec.scene, room=None)) if scene == "open" else spec


def run_set(seed: int, scene: str, cache: Path, fields: Sequence[str] = FIELDS) -> dict:
    """Set ``seed`` at every noise level, the print as each of ``fields`` (invisible, print)."""
    runs = {}
    for label, scale in SCALES.items():
        for field in fields:
            tmp = Path(tempfile.mkdtemp(prefix=f"bench_noise_{seed}_", dir=cache))
            try:
                spec = noisy_spec(seed, field, scale, scene)
                runs[f"{field}, {label}"] = run_one(simulate_dataset(tmp / "set", spec), spec, RunOptions())
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
    return {"seed": seed, "scene": scene, "runs": runs}


def report(sets: Sequence[dict], argv: Sequence[str], scene: str) -> str:
    """The markdown of one scene's table."""
    names = [
        f"{f}, {label}" for label in SCALES for f in FIELDS if all(f"{f}, {label}" in x["runs"] for x in sets)
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
        f"## Scene: {scene}",
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
        done = {(s["seed"], s["scene"]) for s in load_sink(sink)}
        for seed in range(args.seed0, args.seed0 + args.sets):
            if (seed, args.scene) in done:
                continue
            t0 = time.perf_counter()
            res = run_set(seed, args.scene, Path(args.cache), args.fields.split(","))
            append_sink(sink, res)
            brief = {
                n: r.get("failure")
                or f"{r['used']}/{r['n_frames']} {r['rot_deg']:.3f} deg {r['trans_mm']:.2f} mm "
                f"NEES {r['nees']:.1f}"
                for n, r in res["runs"].items()
            }
            print(f"set {seed} ({args.scene}): {time.perf_counter() - t0:.0f} s {brief}", flush=True)
    every = load_sink(sink)
    scenes = sorted({s["scene"] for s in every}) if args.write else [args.scene]
    text = "\n".join(report([s for s in every if s["scene"] == sc], argv, sc) for sc in scenes)
    print(text)
    if args.write:
        DOC.write_text(DOC_HEAD + text)
    return 0


DOC_HEAD = """# Boards under range noise: Monte Carlo

Issue 38.1: with 15 and 30 mm of range noise per return, boards whose print the LiDAR does not show
were refused as "a board-sized object at 2.0 m, but its outline explains only 100% of the returns and
rays about it". Reproduced in the simulator without walls (`SceneOptions.room=None`: nothing returns
above the horizon); in its room every board was found at either noise.

1. The rule that refused was not the one named: an outline fit had to score `good_fit_score` (0.9),
   its score being the share the outline explains times `min(1, 3 x share of rays passing beside the
   board)`. That share counts the samples within reach of the fitted outline, a band 4 sigma wide of
   a return's in-plane shift; the sigma grows with the plane noise, the band reaches deeper into the
   board, and where nothing returns beside the board no ray is added outside: the same board scored
   0.99 at 0 mm, 0.89 at 15 mm and 0.76 at 30 mm (seed 16, frame 0). An outline fit is now refused by
   the outline's own rules only (`outline.refuse_outline`) and by its in-plane uncertainty
   (`max_inplane_2sigma_squares`, from the posterior, which widens with the noise); its score ranks.
   Every refusal states its rule and figures, `(rule: value < limit)` (`options.breach`).
2. The boards then found were placed off: an edge with nothing behind it was bounded only by the
   board's own returns, which the noise pushes outwards, so the outline grew (15 mm at 30 mm) and slid
   towards the edges with nothing behind them (17 mm; in-plane NEES 7.8 for 3 dof). The rays a beam
   fired there that returned nothing now bound those edges too (`lidar/silent.py`).

The LiDAR stage alone, VLP-16, open scene, seeds 16-17 (56 boards), print invisible
(`estimate_board` on `simulate_scan` frames against the true pose; a session's script, not kept):

| noise | before: found | after 1: found, in-plane NEES | after 1 and 2: found, in-plane / 6-dof NEES |
|---|---|---|---|
| 0 mm | 33/36 (seed 16) | 56/56, 2.8 | 56/56, 1.5 / 5.5 |
| 15 mm | 22/36 (seed 16) | 36/36 (seed 16) | 56/56, 2.6 / 7.2 |
| 30 mm | 3/36 (seed 16) | 56/56, 7.8 / 12.4 | 56/56, 3.2 / 7.8 |

Calibrations after 1 only (open scene, sets 0-1, `bench_noise_step1`): print invisible 3.8 and 7.8 mm
at 15 mm (NEES 41, 42), 9.9 and 13.6 mm at 30 mm (NEES 48, 67); every frame used.

"""


if __name__ == "__main__":
    raise SystemExit(main())
