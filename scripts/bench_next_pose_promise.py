"""Does the next pose keep its promise? (issue 34, item 3.)

For each rig and seed: a simulated set is calibrated as ``calibrate`` does it (``run.pipeline.run``,
the sensor model chosen from the data), the next board pose proposed after it (``next_pose.for_run``)
with its promised sigmas, then the same set with one more frame, its board at the proposed pose, is
calibrated again: the batch's sigmas with that board are what the promise must match. Figures per
axis of the worst axis now (the one the advice works on) and of the largest translation sigma:
promised / obtained (1 is a kept promise; the issue's bound is a factor 1.5 either way). Beside it
the promise as it was made before the solved problem's sensor terms entered it (the extrinsic's
own information: ``Advisor(solved=None)``).

The LiDARs read every range ``--range-offset-mm`` long (as the recorded Ouster set does), so the
range model is chosen and the offset weakens the translation along the rays.

Run: ``python scripts/bench_next_pose_promise.py --seeds 4 --write`` (docs/bench_next_pose_promise.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ilcc_graph.datasets import open_source
from ilcc_graph.next_pose import for_run
from ilcc_graph.next_pose.advisor import from_calibration
from ilcc_graph.run.pipeline import run
from ilcc_graph.run.result import Result, RunOptions
from ilcc_graph.simulate import board_placements, simulate_dataset
from ilcc_graph.simulate.spec import SimulationSpec
from ilcc_graph.simulate.write_set import standard_set_spec
from ilcc_graph.types import sigmas_deg_mm

AXES = ("rx", "ry", "rz", "tx", "ty", "tz")
READING = """Sigmas in deg (rx, ry, rz) or mm (tx, ty, tz). A twin has the recorded set's camera, board,
measured beam table, extrinsic and the board poses its calibration used, rendered by the simulator
with its own noise (noise x 1 is cleaner than the recordings: the twin of acfr-os1-fisheye has tz
3.1-3.6 mm where the recording has 12.1 mm), every range read 30 mm long. Where the range model is
chosen (the Ouster twin), the promise made from the extrinsic's own information (before) forgot that
the new board's position along its rays shares the range offset with every other board: it promised
up to 2.3 x more than the batch then gave (0.43); through the solved problem's range terms it is
within 0.71-0.79. With the per-beam model (the VLP-16 twin) the new board's mean beam offset is a
share of the beams it spans; before and now agree there. On the recorded acfr-os1-fisheye itself:
12.108 -> 1.515 mm promised before, 12.108 -> 2.099 mm now (no board to add, so not measured).
"""
RIGS = {"vlp16-fisheye": ("vlp16", "fisheye"), "os1-64-fisheye": ("os1-64", "fisheye")}


def _calibrate(spec: object, folder: Path) -> Result:
    simulate_dataset(folder, spec)
    return run([open_source(folder)], RunOptions())


def twin_spec(recorded: Path, seed: int, noise_scale: float, offset_mm: float) -> SimulationSpec:
    """A simulated twin of a recorded set: its camera, board and beam table (as the run measured it),
    its calibration's extrinsic and board poses (the frames it used), every range ``offset_mm`` long."""
    res = run([open_source(recorded)], RunOptions())
    cfg = res.sessions[0].observation.config
    poses = tuple(np.asarray(f.board.T_lidar_board) for f in res.calibration.frames if f.used and f.board)
    spec = SimulationSpec(
        lidar=cfg.lidar, camera=cfg.camera, board=cfg.board, placements=poses, n_frames=len(poses),
        seed=seed, noise_scale=noise_scale, T_cam_lidar=np.asarray(res.calibration.T_cam_lidar),
    )  # fmt: skip
    return spec.with_(systematics=dataclasses.replace(spec.systematics, range_offset_m=1e-3 * offset_mm))


def one(
    rig: str, seed: int, frames: int, offset_mm: float, tmp: Path, spec: object = None
) -> dict[str, object]:
    """One rig and seed: the promise (now and as before) and what the batch gives with the board."""
    if spec is None:
        lidar, camera = RIGS[rig]
        spec = standard_set_spec(
            0.0, offset_mm, lidar=lidar, camera=camera, width=800, frames=frames, seed=seed
        )
    res = _calibrate(spec, tmp / f"{rig.replace(' ', '-')}-{seed}-a")
    p = for_run(res)
    if p is None:
        return {"rig": rig, "seed": seed, "skipped": "no proposal"}
    config = res.sessions[0].observation.config
    old = from_calibration(res.calibration, config, None, None)
    placements = [*board_placements(spec), np.asarray(p.T_lidar_board)]
    more = dataclasses.replace(spec, placements=placements, n_frames=len(placements))
    res2 = _calibrate(more, tmp / f"{rig.replace(' ', '-')}-{seed}-b")
    got = sigmas_deg_mm(res2.calibration.covariance)
    used = sum(f.used for f in res2.calibration.frames)
    k = AXES.index(p.worst)
    t = 3 + int(np.argmax(p.sigmas_now[3:]))
    return {
        "rig": rig, "seed": seed, "worst": p.worst, "now": float(p.sigmas_now[k]),
        "promised": float(p.sigmas_after[k]), "obtained": float(got[k]),
        "before": float(old.sigmas_after[k]) if old is not None else float("nan"),
        "t_axis": AXES[t], "t_now": float(p.sigmas_now[t]), "t_promised": float(p.sigmas_after[t]),
        "t_obtained": float(got[t]), "used": f"{used}/{len(placements)}",
        "model": (res.calibration.sensors or {}).get("model", {}).get("chosen", "?"),
    }  # fmt: skip


def table(rows: list[dict[str, object]]) -> str:
    head = (
        "| rig | seed | model | worst axis | now | promised | obtained with the board | promised / obtained "
        "| as promised before | largest translation: promised / obtained | frames used |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    body = []
    for r in rows:
        if "skipped" in r:
            body.append(f"| {r['rig']} | {r['seed']} | {r['skipped']} |" + " |" * 8)
            continue
        ratio = r["promised"] / r["obtained"]  # type: ignore[operator]
        tr = r["t_promised"] / r["t_obtained"]  # type: ignore[operator]
        body.append(
            f"| {r['rig']} | {r['seed']} | {r['model']} | {r['worst']} | {r['now']:.4g} "
            f"| {r['promised']:.4g} "
            f"| {r['obtained']:.4g} | {ratio:.2f} | {r['before']:.4g} ({r['before'] / r['obtained']:.2f}) "
            f"| {r['t_axis']} {tr:.2f} | {r['used']} |"
        )
    return head + "\n".join(body) + "\n"


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--range-offset-mm", type=float, default=30.0)
    ap.add_argument("--rigs", default=",".join(RIGS))
    ap.add_argument("--twin", action="append", default=[], help="a recorded set: its simulated twin too")
    ap.add_argument("--twin-noise", type=float, default=1.0, help="the twins' noise scale")
    ap.add_argument("--write", action="store_true", help="write docs/bench_next_pose_promise.md")
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    rows: list[dict[str, object]] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="promise-") as tmp:
        for rec in a.twin:
            for seed in range(a.seeds):
                spec = twin_spec(Path(rec), seed, a.twin_noise, a.range_offset_mm)
                rows.append(one(f"twin of {Path(rec).name}", seed, 0, 0.0, Path(tmp), spec))
                print(table(rows[-1:]).splitlines()[-1], flush=True)
        for rig in [r for r in a.rigs.split(",") if r]:
            for seed in range(a.seeds):
                rows.append(one(rig, seed, a.frames, a.range_offset_mm, Path(tmp)))
                print(table(rows[-1:]).splitlines()[-1], flush=True)
    ratios = [r["promised"] / r["obtained"] for r in rows if "skipped" not in r]  # type: ignore[operator]
    within = sum(1 / 1.5 <= x <= 1.5 for x in ratios)
    twins = ", ".join(Path(t).name for t in a.twin)
    sets = [f"twins of {twins} (noise x {a.twin_noise:g})"] if a.twin else []
    sets += [f"{a.rigs} ({a.frames} frames, 800 px)"] if a.rigs else []
    summary = (
        f"{len(ratios)} sets ({'; '.join(sets)}; every range {a.range_offset_mm:g} mm long): "
        "the worst axis's promise within a factor 1.5 of the batch's "
        f"in {within} of {len(ratios)}; "
        f"median promised / obtained {np.median(ratios):.2f}. {time.perf_counter() - t0:.0f} s."
    )
    print(summary)
    if a.write:
        doc = Path(__file__).resolve().parents[1] / "docs" / "bench_next_pose_promise.md"
        text = (
            "# The next pose's promise against the batch with that board\n\n"
            f"`scripts/bench_next_pose_promise.py` (issue 34, item 3); its docstring says how.\n\n"
            f"{summary}\n\n{table(rows)}\n{READING}"
        )
        doc.write_text(text, encoding="utf-8")
        print(f"wrote {doc}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
