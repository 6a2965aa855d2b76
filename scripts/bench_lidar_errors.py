"""The LiDAR's own error terms in the graph (issue 11): Monte Carlo on simulated sets, timing, recorded
halves.

Monte Carlo: per rig, simulated sets with the simulator's default systematics on (per-beam range bias
3 mm sigma, black print reading 4 mm long, dropouts):

- ``hdl32``: HDL-32E + equirectangular panorama (3000 x 1500 px), 20 boards 1.2-2.6 m (``standard_spec``);
- ``vlp16``: VLP-16 + pinhole (1920 x 1200 px), 12 boards 2.9-5 m (``SceneOptions.board_distance_m``,
  a larger room so that the far boards fit);
- ``hdl32-bent``, ``vlp16-bent`` (``--rigs``): the same with bent boards, each frame's board returns
  off the print by a random plane of 5 mm / 0.4 deg (``Systematics.board_plane_sigma``).

Each set is simulated and observed once in memory (``estimate_board`` on the rendered scan,
``detect_corners`` on the rendered image: the pipeline's per-frame stages; a ``FrameError`` drops the
frame) and solved from the same observations by the pipeline's ``solve_observed`` (corner order,
UPnP start, the core's noise policy) with the LiDAR error terms off (each board a 6-dof LiDAR prior)
and on (the boards' returns with per-beam offsets and the dark-print offset) with each board's own
random plane at fixed ``board_plane`` sigmas (or none) and with those sigmas estimated from the
boards (``board_plane_estimate``); "on" is the default ``LidarErrorOptions()``. Measured against the
simulator's truth:

- the extrinsic: NEES ``xi^T C^-1 xi`` (``T_true = T_est Expmap(xi)``), 95 % coverage (NEES <= 12.59),
  rotation (deg) and translation (mm) errors;
- every estimated beam offset against the beam's true bias: ``z = (est - true) / sigma``, and the
  beams' mean error per set (their common level);
- every used board's corner RMS after the joint solve (``FrameResult.T_lidar_board_refined``) against
  the true corners, taking the closer of the two half turns of a symmetric board.

Timing: the core (``estimation.batch.solve``: gate, variance components, marginals) on 20 and 400
frames of one simulated HDL-32E set (400 frames observed once, cached in the sink's folder).

BLAS: the script runs each process with one OpenBLAS thread (``OPENBLAS_NUM_THREADS=1`` unless set):
on the shared 2-core machine, threaded BLAS in the core's small dense products made the solve 3-8x
slower in wall time.

Recorded data (``--real``): per set, two disjoint halves of the frames (odd / even positions) solved
with the terms on; the beam offsets both halves estimate compared by ``d^T (C_a + C_b)^-1 d``
(chi-square with as many dof as common terms), and the extrinsic halves likewise (6 dof).

    nice python scripts/bench_lidar_errors.py --sets 50 --jobs 2 --sink /tmp/ble/mc.pkl
    python scripts/bench_lidar_errors.py --from-sink /tmp/ble/mc.pkl --timing --real --write

``--obs-cache DIR`` keeps each observed set (``DIR/<rig>-<seed>.pkl``) so that solving the variants
again skips the observation (~90 % of the time); ``--observe-only`` only fills it.
"""

from __future__ import annotations

import os

# one BLAS thread per process: the core's small dense products slow down many times over when
# OpenBLAS threads compete with the other process and the machine's other jobs (measured: docs)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import logging
import pickle
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import gtsam
import numpy as np
from _shared import observe_frame
from scipy.stats import chi2

from ilcc_graph.config import Config
from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.pipeline import solve_observed
from ilcc_graph.run.result import RunOptions
from ilcc_graph.simulate import (
    ImageRenderer,
    SceneOptions,
    beam_biases,
    board_placements,
    standard_spec,
)
from ilcc_graph.types import Calibration, FrameResult

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bench_lidar_errors.md"
CHI2_6_95 = float(chi2.ppf(0.95, 6))
DEG = np.pi / 180.0
#: the two ways of the boards' random effects' sigmas: fixed at the configured 5 mm / 0.4 deg (plane)
#: and 2 mm (each beam's offset on a board), or estimated
FIXED, ESTIMATED = "on, plane 5 mm / 0.4 deg, beams 2 mm (fixed)", "on, plane and beams estimated"
#: the variants solved from the same observations: name -> LidarErrorOptions (None: terms off)
VARIANTS: dict[str, LidarErrorOptions | None] = {
    "off": None,
    FIXED: LidarErrorOptions(board_plane_estimate=False),
    "on, no board plane, no beam term": LidarErrorOptions(
        board_plane=None, board_beam=None, board_plane_estimate=False
    ),
    "on, plane 2 mm / 0.15 deg, no beam term": LidarErrorOptions(
        board_plane=(0.002, 0.15 * DEG), board_beam=None, board_plane_estimate=False
    ),
    "on, plane 10 mm / 0.8 deg, no beam term": LidarErrorOptions(
        board_plane=(0.010, 0.8 * DEG), board_beam=None, board_plane_estimate=False
    ),
    "on, plane estimated, no beam term": LidarErrorOptions(board_beam=None),
    ESTIMATED: LidarErrorOptions(board_plane_estimate=True),
}
#: "on" is the default ``LidarErrorOptions()`` (what ``--lidar-errors`` does): one of the two above
DEFAULT_ON = ESTIMATED if LidarErrorOptions().board_plane_estimate else FIXED
#: corner RMS targets (mm) and the distance up to which each applies (m)
CORNER_TARGET = {"hdl32": (1.0, 3.0), "vlp16": (1.5, 5.0)}
RIGS = ("hdl32", "vlp16")
#: the same rigs with bent boards: each board's returns off its print by a random plane per frame
BENT = (0.005, 0.4 * DEG)
ALL_RIGS = (*RIGS, *(f"{r}-bent" for r in RIGS))


def rig_spec(rig: str, seed: int, frames: int | None = None):  # noqa: ANN201 - SimulationSpec
    """The simulated set of ``rig`` with ``seed`` (module docstring)."""
    if rig.endswith("-bent"):
        spec = rig_spec(rig[: -len("-bent")], seed, frames)
        return spec.with_(systematics=replace(spec.systematics, board_plane_sigma=BENT))
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
    plane: dict | None = None  # the boards' plane sigmas used (``plane.BoardPlane`` as a dict)


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
        frame = observe_frame(spec, renderer, biases, i, placements[i])
        truth[frame.name] = placements[i]
        observed.append(frame)
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
        v.plane = le.get("board_plane")
    board = obs.config.board
    for f in cal.frames:
        if not f.used or f.T_lidar_board_refined is None:
            continue
        T_true = obs.T_lidar_board[f.name]
        v.corner_rms_mm.append(corner_rms_mm(f.T_lidar_board_refined, T_true, obs.config))
        v.stage_rms_mm.append(corner_rms_mm(f.board.T_lidar_board, T_true, obs.config))
        v.distance_m.append(float(np.linalg.norm(T_true[:3, :3] @ board.pattern_centre + T_true[:3, 3])))
    return v


def cached_observation(rig: str, seed: int, cache: str | None) -> Observed:
    """Set ``seed`` of ``rig`` observed, read from ``cache/<rig>-<seed>.pkl`` when there (else written)."""
    path = Path(cache) / f"{rig}-{seed}.pkl" if cache else None
    if path is not None and path.is_file():
        with open(path, "rb") as fh:
            return pickle.load(fh)
    obs = observe_set(rig, seed)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        with open(tmp, "wb") as fh:
            pickle.dump(obs, fh)
        tmp.replace(path)
    return obs


def run_set(rig: str, seed: int, cache: str | None = None, observe_only: bool = False) -> SetResult:
    """Observe set ``seed`` of ``rig`` once (or read it from ``cache``) and solve every variant from
    the same observations (none with ``observe_only``)."""
    logging.getLogger("ilcc_graph").setLevel(logging.ERROR)
    obs = cached_observation(rig, seed, cache)
    if observe_only:
        return SetResult(rig, seed, len(obs.frames), obs.seconds, {})
    out: dict[str, Variant] = {}
    for name, lo in VARIANTS.items():
        t0 = time.perf_counter()
        try:
            cal = solve_observed(obs.frames, obs.config, RunOptions(lidar_errors=lo))
        except (CalibrationImpossible, IndeterminateSystem) as err:
            out[name] = Variant(failure=str(err))
            continue
        out[name] = measure(obs, cal, time.perf_counter() - t0)
    out["on"] = out[DEFAULT_ON]
    return SetResult(rig, seed, len(obs.frames), obs.seconds, out)


# ----------------------------------------------------------------------------------------------
# Tables


def _fmt(x: float, f: str = ".2f") -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, f)


def _paired(sets: Sequence[SetResult]) -> str:
    """The default's extrinsic errors against the terms off, set by set (sign test, mean log ratio)."""
    from scipy.stats import binomtest

    both = [r for r in sets if "off" in r.variants and "on" in r.variants]
    both = [r for r in both if r.variants["off"].failure is None and r.variants["on"].failure is None]
    parts = []
    for what, q in (("rotation", "rot_deg"), ("translation", "trans_mm")):
        off = np.array([getattr(r.variants["off"], q) for r in both])
        on = np.array([getattr(r.variants["on"], q) for r in both])
        d = np.log(on / off)
        k = int(np.sum(on < off))
        parts.append(
            f"{what} smaller in {k}/{len(both)} sets (sign test p = {binomtest(k, len(both)).pvalue:.2f}), "
            f"mean log ratio {d.mean():+.3f} +- {d.std(ddof=1) / np.sqrt(len(d)):.3f}"
        )
    return "Paired, the default against the terms off on the same sets: " + "; ".join(parts) + "."


def mc_tables(results: Sequence[SetResult]) -> list[str]:
    """The Monte Carlo tables (markdown lines)."""
    lines: list[str] = []
    for rig in ALL_RIGS:
        sets = [r for r in results if r.rig == rig]
        if not sets:
            continue
        target, dmax = CORNER_TARGET[rig.removesuffix("-bent")]
        lines += [
            f"### {rig}: {len(sets)} sets (seeds {min(r.seed for r in sets)}-{max(r.seed for r in sets)})",
            "",
            "| variant | mean NEES | coverage 95 % | rot. median / p90 deg | trans. median / p90 mm | "
            "beams within 3 sigma | beam z RMS | beams' mean error mm (mean +- sd over sets) | "
            "dark mm (mean est. +- sd over sets; mean sigma) | "
            f"corner RMS mm, boards <= {dmax:g} m: median / p90 / max | boards <= {target} mm | "
            "set medians <= target | used | solve s (median) |",
            "|" + "---|" * 14,
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
            level = np.array([np.mean(v.beam_err_mm) for v in vs if v.beam_err_mm])
            level_s = f"{level.mean():+.2f} +- {level.std():.2f}" if len(level) else "-"
            dark = (
                f"{darks[:, 0].mean():.2f} +- {darks[:, 0].std():.2f}; {darks[:, 1].mean():.2f}"
                if len(darks)
                else "-"
            )
            lines.append(
                f"| {name} | {ne.mean():.2f} | {100 * np.mean(ne <= CHI2_6_95):.0f} % | "
                f"{np.median(rot):.4f} / {np.percentile(rot, 90):.4f} | {np.median(tr):.2f} / "
                f"{np.percentile(tr, 90):.2f} | {beams} | "
                f"{_fmt(np.sqrt(np.mean(z**2)) if len(z) else np.nan)} | {level_s} | "
                f"{dark} | {np.median(rms):.2f} / {np.percentile(rms, 90):.2f} / {rms.max():.2f} | "
                f"{100 * np.mean(rms <= target):.0f} % | "
                f"{sum(m <= target for m in set_med)}/{len(set_med)} | "
                f"{np.mean([v.used for v in vs]):.1f}/{sets[0].n_frames} | "
                f"{np.median([v.seconds for v in vs]):.2f} |" + (f" ({fails} sets failed)" if fails else "")
            )
        est = [r.variants[ESTIMATED].plane for r in sets if ESTIMATED in r.variants]
        est = [p for p in est if p is not None and p.get("estimated")]
        if est:
            off = 1e3 * np.array([p["offset_m"] for p in est])
            tilt = np.degrees([p["tilt_rad"] for p in est])
            n_off = sum("offset at its floor" in p["note"] for p in est)
            n_tilt = sum("tilt at its floor" in p["note"] for p in est)
            sd_off = np.nanmean([1e3 * p["offset_sd"] for p in est])
            sd_tilt = np.nanmean(np.degrees([p["tilt_sd"] for p in est]))
            beam = 1e3 * np.array([p.get("beam_m", np.nan) for p in est])
            n_beam = sum("beams at its floor" in p["note"] for p in est)
            lines += [
                "",
                f"Estimated sigmas ({ESTIMATED}; {len(est)} sets): plane offset median "
                f"{np.median(off):.2f} mm (p90 {np.percentile(off, 90):.2f}; at the floor in {n_off}), "
                f"tilt median {np.median(tilt):.3f} deg (p90 {np.percentile(tilt, 90):.3f}; at the floor "
                f"in {n_tilt}); mean stated sd {sd_off:.2f} mm / {sd_tilt:.3f} deg; each beam's offset on "
                f"a board median {np.nanmedian(beam):.2f} mm (p90 {np.nanpercentile(beam, 90):.2f}; at "
                f"the floor in {n_beam}).",
            ]
        lines += ["", f'The default (`--lidar-errors`, `LidarErrorOptions()`) is "{DEFAULT_ON}".']
        lines += ["", _paired(sets)]
        stage = np.concatenate(
            [np.asarray(r.variants["off"].stage_rms_mm) for r in sets if "off" in r.variants]
        )
        lines += [
            "",
            f"The LiDAR stage's own boards (intensity fit, before the graph), all distances: corner "
            f"RMS median "
            f"{np.median(stage):.2f} mm, p90 {np.percentile(stage, 90):.2f} mm. Observation (stages) "
            f"{np.median([r.observe_s for r in sets]):.1f} s per set (median).",
            "",
        ]
    return lines


# ----------------------------------------------------------------------------------------------
# Timing: the core on 20 and 400 frames of one simulated set


def observe_many(rig: str, seed: int, n: int, jobs: int, cache: Path | None) -> Observed:
    """``n`` frames of one simulated set, observed in ``jobs`` processes (cached in ``cache``)."""
    if cache is not None and cache.is_file():
        with cache.open("rb") as fh:
            return pickle.load(fh)
    chunks = [list(range(k, n, jobs)) for k in range(jobs)]
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        parts = list(pool.map(observe_set, [rig] * jobs, [seed] * jobs, chunks, [n] * jobs))
    by_name = {f.name: f for p in parts for f in p.frames}
    obs = parts[0]
    obs.frames = [by_name[k] for k in sorted(by_name)]
    obs.T_lidar_board = {k: v for p in parts for k, v in p.T_lidar_board.items()}
    obs.seconds = sum(p.seconds for p in parts)
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        with cache.open("wb") as fh:
            pickle.dump(obs, fh)
    return obs


def timing(obs: Observed, sizes: Sequence[int] = (20, 400), repeats: int = 3) -> list[str]:
    """Wall and CPU time of ``estimation.batch.solve`` (gate, variance components, marginals) with the
    terms off and on, on the first frames of ``obs``; and of the effects' extra solves."""
    from ilcc_graph.estimation import NoiseOptions
    from ilcc_graph.estimation.batch import solve
    from ilcc_graph.run.prepare import prepare

    logging.getLogger("ilcc_graph").setLevel(logging.ERROR)
    lines = [
        "| frames | terms | solve + marginals s, wall (CPU) | of which marginals s | effects' re-solve s | "
        "used | iterations |",
        "|---|---|---|---|---|---|---|",
    ]
    for n in sizes:
        prep = prepare(obs.frames[:n], obs.config)
        for name in ("off", "on"):
            lo = None if name == "off" else LidarErrorOptions()
            walls, cpus = [], []
            for _ in range(repeats if n <= 50 else 1):
                t0, c0 = time.perf_counter(), time.process_time()
                sol = solve(prep.frames, obs.config.camera, prep.T_init, NoiseOptions(), lo)
                walls.append(time.perf_counter() - t0)
                cpus.append(time.process_time() - c0)
            eff = ""
            if lo is not None:
                t0 = time.perf_counter()
                solve(prep.frames, obs.config.camera, prep.T_init, NoiseOptions(), lo, effects=True)
                eff = f"{time.perf_counter() - t0 - min(walls):.2f}"
            k = int(np.argmin(walls))
            lines.append(
                f"| {len(prep.frames)} | {name} | {walls[k]:.2f} ({cpus[k]:.2f}) | "
                f"{sol.timings.get('marginals', float('nan')):.2f} | {eff or '-'} | "
                f"{len(sol.T_lidar_board)} | "
                f"{sol.iterations} |"
            )
            print(lines[-1], flush=True)
    return lines


# ----------------------------------------------------------------------------------------------
# Recorded data: two disjoint halves


REAL_SETS = ("acfr-vlp16-fisheye", "acfr-os1-fisheye")


def _halves_test(a: Calibration, b: Calibration) -> tuple[float, int, float, int, str]:
    """(extrinsic chi2, 6, beam-offset chi2, dof, dark note) between two halves' calibrations."""
    D = gtsam.Pose3(a.T_cam_lidar).between(gtsam.Pose3(b.T_cam_lidar))
    d = np.asarray(gtsam.Pose3.Logmap(D))
    Ad = D.inverse().AdjointMap()
    m2 = float(d @ np.linalg.solve(a.covariance + Ad @ b.covariance @ Ad.T, d))
    la, lb = a.sensors.get("lidar_errors"), b.sensors.get("lidar_errors")
    if not la or not lb or "covariance" not in la or "covariance" not in lb:
        return m2, 6, float("nan"), 0, "-"
    common = [n for n in la["names"] if n.startswith("offset[") and n in lb["names"]]
    ia = [la["names"].index(n) for n in common]
    ib = [lb["names"].index(n) for n in common]
    dv = np.asarray(la["values"])[ia] - np.asarray(lb["values"])[ib]
    C = np.asarray(la["covariance"])[np.ix_(ia, ia)] + np.asarray(lb["covariance"])[np.ix_(ib, ib)]
    b2 = float(dv @ np.linalg.solve(C, dv)) if common else float("nan")
    note = "-"
    if "dark" in la["names"] and "dark" in lb["names"]:
        i, j = la["names"].index("dark"), lb["names"].index("dark")
        va, vb = 1e3 * la["values"][i], 1e3 * lb["values"][j]
        sa, sb = 1e3 * la["sigmas"][i], 1e3 * lb["sigmas"][j]
        note = f"{va:.1f} +- {sa:.1f} / {vb:.1f} +- {sb:.1f} ({(va - vb) / np.hypot(sa, sb):+.1f} sigma)"
    return m2, 6, b2, len(common), note


def _plane_note(cal: Calibration, halves: Sequence[Calibration]) -> str:
    """The boards' plane sigmas of a solve and its halves, when estimated ('-' otherwise)."""

    def one(c: Calibration) -> str:
        p = c.sensors.get("lidar_errors", {}).get("board_plane")
        if p is None or not p.get("estimated"):
            return "-"
        off = f"{1e3 * p['offset_m']:.1f} +- {1e3 * p['offset_sd']:.1f}"
        beam = (
            ""
            if not np.isfinite(p.get("beam_m", np.nan))
            else f", {1e3 * p['beam_m']:.2f} +- {1e3 * p['beam_sd']:.2f}"
        )
        return f"{off}, {np.degrees(p['tilt_rad']):.2f} +- {np.degrees(p['tilt_sd']):.2f}{beam}"

    return f"{one(cal)} ({one(halves[0])}; {one(halves[1])})"


def _held_out(halves: Sequence[Calibration], parts: Sequence[Observation]) -> str:
    """The paper's intensity metric (mrad, mean over frames) of each half's extrinsic on the other
    half's frames: a judge without ground truth that does not use our covariances."""
    from ilcc_graph.evaluation import eval_frames, evaluate

    out = []
    for cal, other in ((halves[0], parts[1]), (halves[1], parts[0])):
        cfg = other.config
        ev = evaluate(eval_frames(other.frames), cfg.camera, cfg.board, np.asarray(cal.T_cam_lidar))
        out.append(f"{ev.intensity_mrad[0]:.3f}")
    return " / ".join(out)


def real_data(root: Path, jobs: int) -> list[str]:
    """Per recorded set and variant: frames used, dark offset, beams, the halves' agreement."""
    from ilcc_graph.datasets import open_source
    from ilcc_graph.run.observe import observe
    from ilcc_graph.run.pipeline import solve_observations
    from ilcc_graph.run.stages import StageOptions

    logging.getLogger("ilcc_graph").setLevel(logging.ERROR)
    lines: list[str] = []
    for name in REAL_SETS:
        folder = root / name
        if not (folder / "config.yaml").is_file():
            lines += [f"{name}: not present under the data folder, skipped", ""]
            continue
        obs = observe(open_source(folder), StageOptions(jobs=jobs))
        lines += [
            f"### {name}",
            "",
            "| variant | used | beams (left out) | dark mm | without the terms: deg, mm (sigma) | "
            "halves: extrinsic chi2 (6 dof) | halves: beam offsets chi2 (dof, p) | halves: dark mm "
            "| held out: intensity mrad, A on B / B on A | solve s "
            "| estimated: plane offset mm, tilt deg, beams mm (halves) |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        parts = [replace(obs, frames=obs.frames[0::2]), replace(obs, frames=obs.frames[1::2])]
        for vname, lo in VARIANTS.items():
            opts = RunOptions(lidar_errors=lo, second_pass=False)
            t0 = time.perf_counter()
            try:
                cal = solve_observations([obs], opts).calibration
                halves = [solve_observations([p], opts).calibration for p in parts]
            except (CalibrationImpossible, IndeterminateSystem) as err:
                lines.append(f"| {vname} | cannot calibrate: {err} |" + " |" * 8)
                continue
            dt = time.perf_counter() - t0
            le = cal.sensors.get("lidar_errors", {})
            names = le.get("names", [])
            beams = sum(n.startswith("offset[") for n in names)
            dark = "-"
            if "dark" in names:
                i = names.index("dark")
                dark = f"{1e3 * le['values'][i]:+.1f} +- {1e3 * le['sigmas'][i]:.1f}"
            eff = cal.sensors.get("effects", {}).get("lidar_errors")
            eff_s = (
                "-"
                if eff is None
                else (f"{eff['rotation_deg']:.3f}, {eff['translation_mm']:.1f} ({eff['mahalanobis']:.1f})")
            )
            m2, _, b2, dof, dnote = _halves_test(*halves)
            used = [sum(f.used for f in c.frames) for c in halves]
            beams_s = "-" if lo is None else f"{beams} ({len(le.get('left_out', []))})"
            bstr = "-" if dof == 0 else f"{b2:.1f} ({dof}, p = {chi2.sf(b2, dof):.3f})"
            lines.append(
                f"| {vname} | {sum(f.used for f in cal.frames)}/{len(cal.frames)} | {beams_s} | "
                f"{dark} | {eff_s} | "
                f"{m2:.1f} ({used[0]} + {used[1]} frames, p = {chi2.sf(m2, 6):.3f}) | {bstr} | "
                f"{dnote} | {_held_out(halves, parts)} | {dt:.1f} | {_plane_note(cal, halves)} |"
            )
            print(lines[-1], flush=True)
        lines.append("")
    return lines


# ----------------------------------------------------------------------------------------------
# Figure and document


def figure(results: Sequence[SetResult], path: Path) -> None:
    """NEES per set (off vs on), beam z-scores, corner RMS against distance, board-plane sensitivity."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    colours = {"hdl32": "tab:blue", "vlp16": "tab:orange"}
    for rig in RIGS:
        sets = [r for r in results if r.rig == rig and "on" in r.variants and "off" in r.variants]
        if not sets:
            continue
        c = colours[rig]
        off = [r.variants["off"].nees for r in sets]
        on = [r.variants["on"].nees for r in sets]
        ax[0, 0].scatter(off, on, s=14, color=c, label=f"{rig} ({len(sets)} sets)")
        z = np.concatenate([r.variants["on"].beam_z for r in sets])
        ax[0, 1].hist(z, bins=np.linspace(-5, 5, 41), density=True, histtype="step", color=c, label=rig)
        d = np.concatenate([r.variants["on"].distance_m for r in sets])
        e = np.concatenate([r.variants["on"].corner_rms_mm for r in sets])
        ax[1, 0].scatter(d, e, s=6, color=c, alpha=0.5, label=rig)
        target, dmax = CORNER_TARGET[rig]
        ax[1, 0].plot([0, dmax], [target, target], color=c, lw=1, ls="--")
        names = [n for n in VARIANTS if n != "off"]
        ax[1, 1].plot(
            range(len(names)),
            [np.mean([r.variants[n].nees for r in sets if n in r.variants]) for n in names],
            "o-", color=c, label=f"{rig} mean NEES",
        )  # fmt: skip
        ax[1, 1].plot(
            range(len(names)),
            [np.median([r.variants[n].trans_mm for r in sets if n in r.variants]) for n in names],
            "s--", color=c, label=f"{rig} median trans. error mm",
        )  # fmt: skip
        ax[1, 1].set_xticks(
            range(len(names)), [n.replace("on, ", "") for n in names], rotation=15, fontsize=8
        )
    lim = max(ax[0, 0].get_xlim()[1], ax[0, 0].get_ylim()[1])
    ax[0, 0].plot([0, lim], [0, lim], color="grey", lw=0.8)
    for v in (CHI2_6_95,):
        ax[0, 0].axhline(v, color="grey", ls=":", lw=0.8)
        ax[0, 0].axvline(v, color="grey", ls=":", lw=0.8)
    ax[0, 0].set(
        xlabel="NEES, terms off", ylabel="NEES, terms on", title="extrinsic NEES per set (95 % bound dotted)"
    )
    x = np.linspace(-5, 5, 200)
    ax[0, 1].plot(x, np.exp(-0.5 * x**2) / np.sqrt(2 * np.pi), color="grey", lw=0.8, label="N(0, 1)")
    ax[0, 1].set(xlabel="(estimated - true) / sigma", title="beam offsets, terms on")
    ax[1, 0].set(
        xlabel="board distance (m)",
        ylabel="corner RMS (mm)",
        title="boards after the joint solve (targets dashed)",
    )
    ax[1, 1].axhspan(4.5, 7.5, color="green", alpha=0.08)
    ax[1, 1].set(title="terms on: board-plane sigma (NEES target band shaded)")
    for a in ax.ravel():
        a.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


BEGIN, END = "<!-- bench:begin -->", "<!-- bench:end -->"


def write_doc(auto: list[str]) -> None:
    """Put ``auto`` between the markers of docs/bench_lidar_errors.md (the text around them stays)."""
    from ilcc_graph.io import atomic_write

    block = "\n".join([BEGIN, *auto, END])
    if DOC.is_file() and BEGIN in (text := DOC.read_text()) and END in text:
        text = text[: text.index(BEGIN)] + block + text[text.index(END) + len(END) :]
    else:
        text = "# The LiDAR's own error terms (issue 11)\n\n" + block + "\n"
    atomic_write(DOC, text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", type=int, default=0, help="simulated sets per rig")
    ap.add_argument("--first-seed", type=int, default=2000)
    ap.add_argument("--rigs", default=",".join(RIGS))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--sink", help="append every finished set to this pickle")
    ap.add_argument("--from-sink", help="tables from a sink written before")
    ap.add_argument("--obs-cache", help="folder of observed sets (read when there, written when not)")
    ap.add_argument("--observe-only", action="store_true", help="only fill --obs-cache, solve nothing")
    ap.add_argument("--timing", action="store_true", help="time the core on 20 and 400 frames")
    ap.add_argument("--timing-cache", help="pickle of the 400 observed frames (made when absent)")
    ap.add_argument("--real", action="store_true", help="the recorded sets' halves")
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--write", action="store_true", help=f"write {DOC.relative_to(ROOT)} and its figure")
    args = ap.parse_args()
    t_start = time.perf_counter()
    logging.basicConfig(level=logging.ERROR, format="%(levelname)s: %(message)s")
    results: list[SetResult] = []
    if args.from_sink:
        with open(args.from_sink, "rb") as fh:
            while True:
                try:
                    results.append(pickle.load(fh))
                except EOFError:
                    break
        for r in results:  # "on": the default as the code has it now
            if DEFAULT_ON in r.variants:
                r.variants["on"] = r.variants[DEFAULT_ON]
    jobs = [(rig, args.first_seed + k) for k in range(args.sets) for rig in args.rigs.split(",")]
    if jobs:
        sink = open(args.sink, "ab") if args.sink else None  # noqa: SIM115
        t0 = time.perf_counter()
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            futures = [
                pool.submit(run_set, rig, seed, args.obs_cache, args.observe_only) for rig, seed in jobs
            ]
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
        if args.observe_only:
            return
    auto = [
        f"Generated by `python scripts/bench_lidar_errors.py {' '.join(sys.argv[1:])}` on "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; load average at the start of the tables "
        f"{' / '.join(f'{v:.1f}' for v in os.getloadavg())} (2 cores, shared).",
        "",
    ]
    if results:
        auto += ["## Monte Carlo", "", *mc_tables(results)]
        print("\n".join(mc_tables(results)))
    if args.timing:
        cache = Path(args.timing_cache) if args.timing_cache else None
        t0 = time.perf_counter()
        obs400 = observe_many("hdl32", 9000, 400, args.jobs, cache)
        auto += [
            "## Timing",
            "",
            f"One simulated HDL-32E set of 400 frames (seed 9000; observed in "
            f"{time.perf_counter() - t0:.0f} s "
            "wall or read from the cache); the core (`estimation.batch.solve`: gate, variance components, "
            "the observability check, marginals) on its first 20 and on all frames, best of 3 at 20.",
            "",
            *timing(obs400),
            "",
        ]
    if args.real:
        auto += ["## Recorded data", "", *real_data(Path(args.data), args.jobs)]
    if args.write:
        if results:
            fig = DOC.with_name("bench_lidar_errors.png")
            figure(results, fig)
            auto += ["", f"![Monte Carlo]({fig.name})", ""]
        auto.append(f"Whole script: {(time.perf_counter() - t_start) / 60:.1f} min.")
        write_doc(auto)
        print(f"wrote {DOC}")


if __name__ == "__main__":
    sys.exit(main())
