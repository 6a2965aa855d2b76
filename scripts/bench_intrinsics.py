"""The camera's intrinsics chosen from the boards when the config states them a little off and says
nothing of their uncertainty (``estimation.camera_choice``): Monte Carlo on simulated sets.

Each set: a VLP-16 (the simulator's default systematics plus a 20 mm range offset) and a camera
(``--camera pinhole`` 1920 x 1200 or ``fisheye``), 20 boards 2-5 m away, rendered and observed
once. The config then states the intrinsics right, or off by ``--scale`` x a typical published
calibration's error (``IntrinsicsError.typical``: 0.5 % on f, 2 px on c, the lens coefficients'
typical sigmas) without stating any sigma (what a user's config.yaml says). Each is solved on all
20 boards and on the first 10, four ways, in one run: the camera's choice (``camera_choice``) with
``IntrinsicsOptions.subsets`` ``LIDAR_SUBSETS`` (fx, fy, k1; then k1), with fx, fy, cx, cy, k1
tried first, with none (all intrinsics or none: the default), and the intrinsics held as stated.

NEES of T_cam_lidar (6 dof) against the truth, the 95 % coverage (NEES under 12.59), the
translation error and what the choice refined are tabled in docs/bench_intrinsics.md.

    python scripts/bench_intrinsics.py --sets 20 --camera fisheye --sink /tmp/bi.jsonl [--write]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the command line runs

import argparse
import logging
import sys
import time
from dataclasses import replace
from pathlib import Path

import gtsam
import numpy as np
from _shared import append_sink, load_sink, observe_frame, write_between

import ilcc_graph.estimation.camera_choice as camera_choice
from ilcc_graph.cameras import CameraModel
from ilcc_graph.config import Config
from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem
from ilcc_graph.estimation.batch import solve as solve_batch
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.selection import AUTO
from ilcc_graph.run.prepare import prepare
from ilcc_graph.simulate import (
    ImageRenderer,
    SceneOptions,
    Systematics,
    beam_biases,
    board_placements,
    standard_spec,
)
from ilcc_graph.simulate.intrinsics_error import IntrinsicsError, stated_camera
from ilcc_graph.types import FrameResult

DOC = Path(__file__).resolve().parents[1] / "docs" / "bench_intrinsics.md"
CHI2_6_95 = 12.59
REFINED = ("all", "fx, fy, cx, cy, k1", "fx, fy, k1", "k1")
#: the variants solved: the camera's choice with these subsets (``IntrinsicsOptions.subsets``), or
#: the intrinsics held as stated (None)
VARIANTS: dict[str, tuple[tuple[str, ...], ...] | None] = {
    "subsets fx, fy, k1; k1": camera_choice.LIDAR_SUBSETS,
    "subsets with cx, cy first": (("fx", "fy", "cx", "cy", "k1"), *camera_choice.LIDAR_SUBSETS),
    "all or none (the default)": (),
    "stated": None,
}


def observe(camera: str, seed: int) -> tuple[Config, list[FrameResult], np.ndarray]:
    """(config with the true camera, the frames, T_cam_lidar) of set ``seed``."""
    scene = SceneOptions(room=(-9.0, 9.0, -9.0, 9.0), ceiling_height_m=4.0, board_distance_m=(2.0, 5.0))
    spec = standard_spec("vlp16", camera, frames=20, seed=seed, scene=scene)
    spec = spec.with_(systematics=Systematics(range_offset_m=0.020))
    renderer, biases = ImageRenderer(spec), beam_biases(spec)
    frames = [observe_frame(spec, renderer, biases, i, T) for i, T in enumerate(board_placements(spec))]
    config = Config(board=spec.board, lidar=spec.lidar_model, camera=spec.camera, source=f"sim {seed}")
    return config, frames, np.asarray(spec.T_cam_lidar)


def through(frames: list[FrameResult], camera: CameraModel) -> list[FrameResult]:
    """The frames' image corners as ``camera`` reads their pixels."""
    return [
        f
        if f.corners is None
        else replace(f, corners=replace(f.corners, bearings=camera.bearing(f.corners.uv)))
        for f in frames
    ]


def solve_one(frames: list[FrameResult], config: Config, variant: str, truth: np.ndarray) -> dict:
    """One solve's figures: NEES, translation error (mm), what the camera's choice refined."""
    subsets = VARIANTS[variant]
    t0 = time.perf_counter()
    try:
        prep = prepare(frames, config)
        opts, how = IntrinsicsOptions(subsets=subsets or ()), "stated" if subsets is None else "auto"
        sol = solve_batch(
            prep.frames, config.camera, prep.T_init, models=AUTO, intrinsics=opts, intrinsics_choice=how
        )
    except (CalibrationImpossible, IndeterminateSystem) as err:
        return {"failure": str(err)}
    xi = np.asarray(gtsam.Pose3(sol.T_cam_lidar).localCoordinates(gtsam.Pose3(truth)))
    cc = sol.selection.camera if sol.selection is not None else None
    refined = "none"
    if cc is not None and cc.refined:
        refined = {1: "k1", 3: "fx, fy, k1", 5: "fx, fy, cx, cy, k1"}.get(cc.significance_dof, "all")
    return {
        "nees": float(xi @ np.linalg.solve(sol.covariance, xi)),
        "trans_mm": float(1e3 * np.linalg.norm(sol.T_cam_lidar[:3, 3] - truth[:3, 3])),
        "rot_deg": float(np.degrees(np.linalg.norm(xi[:3]))),
        "refined": refined,
        "reason": "" if cc is None else cc.reason,
        "seconds": time.perf_counter() - t0,
    }


def run_set(camera: str, seed: int, scale: float) -> list[dict]:
    """Every (stated, boards, variant) row of set ``seed``."""
    config, frames, truth = observe(camera, seed)
    rows = []
    for stated, err in (("right", IntrinsicsError()), ("off", IntrinsicsError.typical(scale))):
        cam = stated_camera(config.camera, replace(err, state_sigma=False), seed)
        seen = through(frames, cam)
        for boards, part in (("20", seen), ("10", seen[:10])):
            for v in VARIANTS:
                got = solve_one(part, replace(config, camera=cam), v, truth)
                key = {"camera": camera, "seed": seed, "scale": scale, "stated": stated, "boards": boards}
                rows.append({**key, "variant": v, **got})
    return rows


def table(rows: list[dict], scale: float) -> list[str]:
    """The markdown table of the sink's rows."""
    out = [
        "| camera | intrinsics stated | boards | variant | sets | mean NEES | coverage 95 % | "
        "rot. median / p90 deg | trans. median / p90 mm | "
        "refined: all / fx, fy, cx, cy, k1 / fx, fy, k1 / k1 | failed |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    keys = sorted(
        {(r["camera"], r["stated"], r["boards"]) for r in rows}, key=lambda k: (k[0], k[1] != "right", k[2])
    )
    for cam, stated, boards in keys:
        for v in VARIANTS:
            rs = [
                r
                for r in rows
                if (r["camera"], r["stated"], r["boards"], r["variant"]) == (cam, stated, boards, v)
            ]
            ok = [r for r in rs if "nees" in r]
            if not ok:
                continue
            ne, tr = np.array([r["nees"] for r in ok]), np.array([r["trans_mm"] for r in ok])
            rot = np.array([r["rot_deg"] for r in ok])
            how = " / ".join(str(sum(r["refined"] == k for r in ok)) for k in REFINED)
            k = ok[0].get("scale", scale)
            what = "right" if stated == "right" else f"{k:g} x typical error, no sigma"
            out.append(
                f"| {cam} | {what} | {boards} | {v} | {len(ok)} | {ne.mean():.2f} | "
                f"{100 * np.mean(ne <= CHI2_6_95):.0f} % | "
                f"{np.median(rot):.3f} / {np.percentile(rot, 90):.3f} | "
                f"{np.median(tr):.2f} / {np.percentile(tr, 90):.2f} | "
                f"{how} | {len(rs) - len(ok)} |"
            )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=4000)
    ap.add_argument("--camera", choices=("pinhole", "fisheye"), default="fisheye")
    ap.add_argument("--scale", type=float, default=1.0, help="the stated intrinsics' error, x typical")
    ap.add_argument("--sink", type=Path, required=True, help="results, one JSON line per solve; resumed")
    ap.add_argument("--write", action="store_true", help="the table from the sink into docs/")
    args = ap.parse_args(argv)
    logging.getLogger("ilcc_graph").setLevel(logging.ERROR)
    done = {(r["camera"], r["seed"]) for r in load_sink(args.sink)}
    for seed in range(args.first_seed, args.first_seed + args.sets):
        if (args.camera, seed) in done:
            continue
        t0 = time.perf_counter()
        for row in run_set(args.camera, seed, args.scale):
            append_sink(args.sink, row)
        print(f"{args.camera} {seed}: {time.perf_counter() - t0:.0f} s", flush=True)
    rows = load_sink(args.sink)
    lines = table(rows, args.scale)
    print("\n".join(lines))
    if args.write:
        head = (
            f"`python scripts/bench_intrinsics.py` ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}), "
            f"seeds {min(r['seed'] for r in rows)}..{max(r['seed'] for r in rows)}, sink {args.sink.name}."
        )
        write_between(
            DOC,
            "<!-- bench_intrinsics:begin -->",
            "<!-- bench_intrinsics:end -->",
            "\n".join([head, "", *lines]),
        )
        print(f"wrote {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
