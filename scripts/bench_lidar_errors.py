"""The LiDAR's own error terms in the graph (issue 11): Monte Carlo on simulated sets, timing, recorded halves.

Monte Carlo: per rig, simulated sets with the simulator's default systematics on (per-beam range bias
3 mm sigma, black print reading 4 mm long, dropouts):

- ``hdl32``: HDL-32E + equirectangular panorama (3000 x 1500 px), 20 boards 1.2-2.6 m (``standard_spec``);
- ``vlp16``: VLP-16 + pinhole (1920 x 1200 px), 12 boards 2.9-5 m (``SceneOptions.board_distance_m``,
  a larger room so that the far boards fit).

Each set is simulated and observed once in memory (``estimate_board`` on the rendered scan,
``detect_corners`` on the rendered image: the pipeline's per-frame stages; a ``FrameError`` drops the
frame) and solved from the same observations by the pipeline's ``solve_observed`` (corner order,
UPnP start, the core's noise policy) with the LiDAR error terms off (each board a 6-dof LiDAR prior)
and on (the boards' returns with per-beam offsets and the dark-print offset), and on with other
``board_plane`` sigmas. Measured against the simulator's truth:

- the extrinsic: NEES ``xi^T C^-1 xi`` (``T_true = T_est Expmap(xi)``), 95 % coverage (NEES <= 12.59),
  rotation (deg) and translation (mm) errors;
- every estimated beam offset against the beam's true bias: ``z = (est - true) / sigma``;
- every used board's corner RMS after the joint solve (``FrameResult.T_lidar_board_refined``) against
  the true corners, taking the closer of the two half turns of a symmetric board.

Timing: the core (``estimation.batch.solve``: gate, variance components, marginals) on 20 and 400
frames of one simulated HDL-32E set (400 frames observed once, cached in the sink's folder).

Recorded data (``--real``): per set, two disjoint halves of the frames (odd / even positions) solved
with the terms on; the beam offsets both halves estimate compared by ``d^T (C_a + C_b)^-1 d``
(chi-square with as many dof as common terms), and the extrinsic halves likewise (6 dof).

    nice python scripts/bench_lidar_errors.py --sets 50 --jobs 2 --sink /tmp/ble/mc.pkl
    python scripts/bench_lidar_errors.py --from-sink /tmp/ble/mc.pkl --timing --real --write
"""

from __future__ import annotations

import argparse
import logging
import pickle
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import gtsam
import numpy as np
from scipy.stats import chi2

from ilcc_graph.config import Config
from ilcc_graph.errors import CalibrationImpossible, FrameError, IndeterminateSystem
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.image import detect_corners
from ilcc_graph.lidar import estimate_board
from ilcc_graph.pipeline import RunOptions, solve_observed
from ilcc_graph.simulate import (
    ImageRenderer,
    SceneOptions,
    beam_biases,
    board_placements,
    frame_scene,
    simulate_scan,
    standard_spec,
)
from ilcc_graph.types import Calibration, FrameResult

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bench_lidar_errors.md"
CHI2_6_95 = float(chi2.ppf(0.95, 6))
DEG = np.pi / 180.0
#: the variants solved from the same observations: name -> LidarErrorOptions (None: terms off)
VARIANTS: dict[str, LidarErrorOptions | None] = {
    "off": None,
    "on": LidarErrorOptions(),
    "on, no board plane": LidarErrorOptions(board_plane=None),
    "on, plane 2 mm / 0.15 deg": LidarErrorOptions(board_plane=(0.002, 0.15 * DEG)),
    "on, plane 10 mm / 0.8 deg": LidarErrorOptions(board_plane=(0.010, 0.8 * DEG)),
}
#: corner RMS targets (mm) and the distance up to which each applies (m)
CORNER_TARGET = {"hdl32": (1.0, 3.0), "vlp16": (1.5, 5.0)}
RIGS = ("hdl32", "vlp16")


def rig_spec(rig: str, seed: int, frames: int | None = None):  # noqa: ANN201 - SimulationSpec
    """The simulated set of ``rig`` with ``seed`` (module docstring)."""
    if rig == "hdl32":
        return standard_spec("hdl32", "equirectangular", width=3000, frames=frames or 20, seed=seed)
    if rig == "vlp16":
        scene = SceneOptions(room=(-9.0, 9.0, -9.0, 9.0), ceiling_height_m=4.0, board_distance_m=(2.9, 5.0))
        return standard_spec("vlp16", "pinhole", frames=frames or 12, seed=seed, scene=scene)
    raise ValueError(f"unknown rig {rig!r}")


# ----------------------------------------------------------------------------------------------
# One set


@dataclass
class Observed:
    """One simulated set, observed by the per-frame stages (picklable)."""

    rig: str
    seed: int
    config: Config
    frames: list[FrameResult]
    T_cam_lidar: np.ndarray
    T_lidar_board: dict[str, np.ndarray]
    biases: np.ndarray
    dark_m: float
    seconds: float = 0.0


@dataclass
class Variant:
    """One solve of a set: what it gave against the truth."""

    nees: float = float("nan")
    rot_deg: float = float("nan")
    trans_mm: float = float("nan")
    used: int = 0
    seconds: float = 0.0
    beam_z: list[float] = field(default_factory=list)  # estimated beams: (est - true) / sigma
    beam_err_mm: list[float] = field(default_factory=list)
    beam_sigma_mm: list[float] = field(default_factory=list)
    dark: tuple[float, float] | None = None  # (value, sigma) mm
    left_out: list[tuple[str, str]] = field(default_factory=list)
    corner_rms_mm: list[float] = field(default_factory=list)  # per used board, refined pose
    stage_rms_mm: list[float] = field(default_factory=list)  # per used board, the LiDAR stage's pose
    distance_m: list[float] = field(default_factory=list)  # per used board, its centre's range
    failure: str | None = None


@dataclass
class SetResult:
    rig: str
    seed: int
    n_frames: int
    observe_s: float
    variants: dict[str, Variant]


def observe_set(rig: str, seed: int, frames: Sequence[int] | None = None, n: int | None = None) -> Observed:
    """Simulate set ``seed`` of ``rig`` and run the per-frame stages on every (or the given) frame."""
    t0 = time.perf_counter()
    spec = rig_spec(rig, seed, n)
    placements = board_placements(spec)
    renderer = ImageRenderer(spec)
    biases = beam_biases(spec)
    config = Config(board=spec.board, lidar=spec.lidar_model, camera=spec.camera, source=f"sim {rig} {seed}")
    observed, truth = [], {}
    for i in range(len(placements)) if frames is None else frames:
        T = placements[i]
        name = f"{i + 1:04d}"
        truth[name] = T
        scene = frame_scene(spec, T, i)
        reasons, fit, corners = [], None, None
        try:
            corners = detect_corners(renderer.render(scene, i), spec.camera, spec.board)
        except FrameError as err:
            reasons.append(f"image: {err}")
        try:
            fit = estimate_board(simulate_scan(spec, scene, i, biases), spec.board, spec.lidar_model)
        except FrameError as err:
            reasons.append(f"LiDAR: {err}")
        observed.append(
            FrameResult(name, not reasons, "; ".join(reasons) or None, board=fit, corners=corners)
        )
    return Observed(
        rig, seed, config, observed, np.asarray(spec.T_cam_lidar), truth, biases,
        spec.systematics.dark_range_offset_m, time.perf_counter() - t0,
    )  # fmt: skip


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """xi (6,) with ``T_true = T_est Expmap(xi)``."""
    return np.asarray(gtsam.Pose3(T_est).localCoordinates(gtsam.Pose3(T_true)), dtype=np.float64)


def corner_rms_mm(T_est: np.ndarray, T_true: np.ndarray, config: Config) -> float:
    """RMS distance (mm) of the board's inner corners at ``T_est`` from the true ones (closer half turn)."""
    board = config.board
    K = board.corners_board()
    c = K @ T_est[:3, :3].T + T_est[:3, 3]
    cands = [T_true] + ([T_true @ board.T_half_turn()] if board.half_turn_symmetric else [])
    return min(
        1e3 * float(np.sqrt(np.mean(np.sum((c - (K @ T[:3, :3].T + T[:3, 3])) ** 2, axis=1)))) for T in cands
    )


def measure(obs: Observed, cal: Calibration, seconds: float) -> Variant:
    """A solve's numbers against the set's truth."""
    xi = pose_error(cal.T_cam_lidar, obs.T_cam_lidar)
    v = Variant(
        nees=float(xi @ np.linalg.solve(cal.covariance, xi)),
        rot_deg=float(np.degrees(np.linalg.norm(xi[:3]))),
        trans_mm=float(1e3 * np.linalg.norm(cal.T_cam_lidar[:3, 3] - obs.T_cam_lidar[:3, 3])),
        used=sum(f.used for f in cal.frames),
        seconds=seconds,
    )
    le = cal.sensors.get("lidar_errors")
    if le is not None:
        for n, val, s in zip(le["names"], le["values"], le["sigmas"], strict=True):
            if n.startswith("offset["):
                err = val - obs.biases[int(n[7:-1])]
                v.beam_z.append(float(err / s))
                v.beam_err_mm.append(1e3 * float(err))
                v.beam_sigma_mm.append(1e3 * float(s))
            elif n == "dark":
                v.dark = (1e3 * float(val), 1e3 * float(s))
        v.left_out = [tuple(x) for x in le["left_out"]]
    board = obs.config.board
    for f in cal.frames:
        if not f.used or f.T_lidar_board_refined is None:
            continue
        T_true = obs.T_lidar_board[f.name]
        v.corner_rms_mm.append(corner_rms_mm(f.T_lidar_board_refined, T_true, obs.config))
        v.stage_rms_mm.append(corner_rms_mm(f.board.T_lidar_board, T_true, obs.config))
        v.distance_m.append(float(np.linalg.norm(T_true[:3, :3] @ board.pattern_centre + T_true[:3, 3])))
    return v


def run_set(rig: str, seed: int) -> SetResult:
    """Observe set ``seed`` of ``rig`` once and solve every variant from the same observations."""
    logging.getLogger("ilcc_graph").setLevel(logging.ERROR)
    obs = observe_set(rig, seed)
    out: dict[str, Variant] = {}
    for name, lo in VARIANTS.items():
        t0 = time.perf_counter()
        try:
            cal = solve_observed(obs.frames, obs.config, RunOptions(lidar_errors=lo))
        except (CalibrationImpossible, IndeterminateSystem) as err:
            out[name] = Variant(failure=str(err))
            continue
        out[name] = measure(obs, cal, time.perf_counter() - t0)
    return SetResult(rig, seed, len(obs.frames), obs.seconds, out)


# ----------------------------------------------------------------------------------------------
# Tables


def _fmt(x: float, f: str = ".2f") -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, f)


def mc_tables(results: Sequence[SetResult]) -> list[str]:
    """The Monte Carlo tables (markdown lines)."""
    lines: list[str] = []
    for rig in RIGS:
        sets = [r for r in results if r.rig == rig]
        if not sets:
            continue
        target, dmax = CORNER_TARGET[rig]
        lines += [
            f"### {rig}: {len(sets)} sets (seeds {min(r.seed for r in sets)}-{max(r.seed for r in sets)})",
            "",
            "| variant | mean NEES | coverage 95 % | rot. median / p90 deg | trans. median / p90 mm | "
            "beams within 3 sigma | beam z RMS | dark mm (mean est. +- sd over sets; mean sigma) | "
            f"corner RMS mm, boards <= {dmax:g} m: median / p90 / max | boards <= {target} mm | "
            "set medians <= target | used | solve s (median) |",
            "|" + "---|" * 13,
        ]
        for name in VARIANTS:
            vs = [r.variants[name] for r in sets if name in r.variants and r.variants[name].failure is None]
            fails = sum(1 for r in sets if r.variants.get(name) is not None and r.variants[name].failure)
            if not vs:
                continue
            ne = np.array([v.nees for v in vs])
            rot = np.array([v.rot_deg for v in vs])
            tr = np.array([v.trans_mm for v in vs])
            z = np.concatenate([v.beam_z for v in vs]) if any(v.beam_z for v in vs) else np.zeros(0)
            darks = np.array([v.dark for v in vs if v.dark is not None])
            rms = np.concatenate([np.asarray(v.corner_rms_mm)[np.asarray(v.distance_m) <= dmax] for v in vs])
            set_med = [
                np.median(np.asarray(v.corner_rms_mm)[np.asarray(v.distance_m) <= dmax])
                for v in vs
                if np.any(np.asarray(v.distance_m) <= dmax)
            ]
            beams = f"{100 * np.mean(np.abs(z) < 3):.1f} % of {len(z)}" if len(z) else "-"
            dark = (
                f"{darks[:, 0].mean():.2f} +- {darks[:, 0].std():.2f}; {darks[:, 1].mean():.2f}"
                if len(darks)
                else "-"
            )
            lines.append(
                f"| {name} | {ne.mean():.2f} | {100 * np.mean(ne <= CHI2_6_95):.0f} % | "
                f"{np.median(rot):.4f} / {np.percentile(rot, 90):.4f} | {np.median(tr):.2f} / "
                f"{np.percentile(tr, 90):.2f} | {beams} | {_fmt(np.sqrt(np.mean(z**2)) if len(z) else np.nan)} | "
                f"{dark} | {np.median(rms):.2f} / {np.percentile(rms, 90):.2f} / {rms.max():.2f} | "
                f"{100 * np.mean(rms <= target):.0f} % | {sum(m <= target for m in set_med)}/{len(set_med)} | "
                f"{np.mean([v.used for v in vs]):.1f}/{sets[0].n_frames} | "
                f"{np.median([v.seconds for v in vs]):.2f} |" + (f" ({fails} sets failed)" if fails else "")
            )
        stage = np.concatenate(
            [np.asarray(r.variants["off"].stage_rms_mm) for r in sets if "off" in r.variants]
        )
        lines += [
            "",
            f"The LiDAR stage's own boards (intensity fit, before the graph), all distances: corner RMS median "
            f"{np.median(stage):.2f} mm, p90 {np.percentile(stage, 90):.2f} mm. Observation (stages) "
            f"{np.median([r.observe_s for r in sets]):.1f} s per set (median).",
            "",
        ]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", type=int, default=0, help="simulated sets per rig")
    ap.add_argument("--first-seed", type=int, default=2000)
    ap.add_argument("--rigs", default=",".join(RIGS))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--sink", help="append every finished set to this pickle")
    ap.add_argument("--from-sink", help="tables from a sink written before")
    ap.add_argument("--write", action="store_true", help=f"write {DOC.relative_to(ROOT)} and its figure")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR, format="%(levelname)s: %(message)s")
    results: list[SetResult] = []
    if args.from_sink:
        with open(args.from_sink, "rb") as fh:
            while True:
                try:
                    results.append(pickle.load(fh))
                except EOFError:
                    break
    jobs = [(rig, args.first_seed + k) for k in range(args.sets) for rig in args.rigs.split(",")]
    if jobs:
        sink = open(args.sink, "ab") if args.sink else None  # noqa: SIM115
        t0 = time.perf_counter()
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            futures = [pool.submit(run_set, rig, seed) for rig, seed in jobs]
            for k, fut in enumerate(futures):
                r = fut.result()
                results.append(r)
                if sink is not None:
                    pickle.dump(r, sink)
                    sink.flush()
                on = r.variants.get("on")
                off = r.variants.get("off")
                print(
                    f"[{k + 1}/{len(jobs)} {time.perf_counter() - t0:.0f} s] {r.rig} {r.seed}: "
                    f"NEES off {_fmt(off.nees if off else np.nan)} on {_fmt(on.nees if on else np.nan)}",
                    flush=True,
                )
        if sink is not None:
            sink.close()
    print("\n".join(mc_tables(results)))


if __name__ == "__main__":
    sys.exit(main())
