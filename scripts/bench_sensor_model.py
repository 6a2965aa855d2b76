"""The sensor-error model chosen by default (issue 21): Monte Carlo on simulated sets.

Sets (``rig_spec``): **hdl32**, HDL-32E + equirectangular panorama 3000 x 1500 px, 20 boards
1.2-2.6 m; **vlp16**, VLP-16 + pinhole 1920 x 1200 px, 20 boards 2.9-5 m. Each set is rendered
once; its images go through the image stage once, and its scans are simulated and put through the
LiDAR stage three times, with three LiDARs (``LIDARS``):

- ``full``: the simulator's default systematics (per-beam range bias 3 mm sigma, black print 4 mm
  long scaled by the footprint's darkness, dropouts) plus a global range offset of 20 mm;
- ``offset``: the global 20 mm offset alone (no per-beam bias, no dark offset);
- ``off``: no systematic error at all (``Systematics.off()``).

``--observe-only`` fills the cache (``--obs-cache DIR``, one pickle per set): the slow part (the
rendering, the ray casting, the two per-frame stages). Every solve then reads the cache.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # see bench_lidar_errors.py: small dense products

import argparse
import logging
import pickle
import sys
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import gtsam
import numpy as np
from _shared import write_between
from scipy.stats import chi2

from ilcc_graph.config import Config
from ilcc_graph.errors import CalibrationImpossible, FrameError, IndeterminateSystem
from ilcc_graph.estimation.batch import solve as solve_batch
from ilcc_graph.estimation.held_out import HeldOut, held_out
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.model_solves import decide
from ilcc_graph.estimation.noise import solve_problem
from ilcc_graph.estimation.problem import frames_problem
from ilcc_graph.estimation.selection import (
    AUTO,
    MODELS,
    Selection,
    candidates,
    mixture,
    range_terms,
)
from ilcc_graph.image import detect_corners
from ilcc_graph.lidar import LidarOptions, estimate_board
from ilcc_graph.lidar.stretch import correction_of, significant
from ilcc_graph.run.prepare import prepare
from ilcc_graph.run.range_refit import refit_frames
from ilcc_graph.simulate import (
    ImageRenderer,
    SceneOptions,
    Systematics,
    beam_biases,
    board_placements,
    frame_scene,
    simulate_scan,
    standard_spec,
)
from ilcc_graph.simulate.intrinsics_error import IntrinsicsError, stated_camera
from ilcc_graph.types import ExpectedBoard, FrameResult

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bench_sensor_model.md"
RIGS = ("hdl32", "vlp16")
#: the global range offset every "with offset" LiDAR reads (metres)
OFFSET_M = 0.020
LIDARS: dict[str, Systematics] = {
    "full": Systematics(range_offset_m=OFFSET_M),
    "offset": Systematics(beam_bias_sigma_m=0.0, dark_range_offset_m=0.0, range_offset_m=OFFSET_M),
    "off": Systematics.off(),
}


def rig_spec(rig: str, seed: int, frames: int = 20):  # noqa: ANN201 - SimulationSpec
    """The simulated set of ``rig`` (module docstring) with the ``full`` LiDAR."""
    if rig == "hdl32":
        spec = standard_spec("hdl32", "equirectangular", width=3000, frames=frames, seed=seed)
    elif rig == "vlp16":
        scene = SceneOptions(room=(-9.0, 9.0, -9.0, 9.0), ceiling_height_m=4.0, board_distance_m=(2.9, 5.0))
        spec = standard_spec("vlp16", "pinhole", frames=frames, seed=seed, scene=scene)
    else:
        raise ValueError(f"unknown rig {rig!r}")
    return spec.with_(systematics=LIDARS["full"])


@dataclass
class ObservedSet:
    """One simulated set observed with each LiDAR of ``LIDARS`` (picklable).

    frames: per LiDAR the frames (the same image corners, that LiDAR's board fits). biases: the
    per-beam biases of ``full`` (m; the others have none). T_cam_lidar, T_lidar_board: the truth.
    """

    rig: str
    seed: int
    config: Config
    frames: dict[str, list[FrameResult]]
    T_cam_lidar: np.ndarray
    T_lidar_board: dict[str, np.ndarray]
    biases: np.ndarray
    seconds: float = 0.0


def observe_set(rig: str, seed: int) -> ObservedSet:
    """Render set ``seed`` of ``rig`` once and run the stages: the image once, the LiDAR per LiDAR."""
    t0 = time.perf_counter()
    spec = rig_spec(rig, seed)
    placements = board_placements(spec)
    renderer = ImageRenderer(spec)
    specs = {name: spec.with_(systematics=s) for name, s in LIDARS.items()}
    biases = {name: beam_biases(s) for name, s in specs.items()}
    config = Config(board=spec.board, lidar=spec.lidar_model, camera=spec.camera, source=f"sim {rig} {seed}")
    frames: dict[str, list[FrameResult]] = {name: [] for name in LIDARS}
    truth = {}
    for i, T in enumerate(placements):
        name = f"{i + 1:04d}"
        truth[name] = T
        scene = frame_scene(spec, T, i)
        corners, image_why = None, None
        try:
            corners = detect_corners(renderer.render(scene, i), spec.camera, spec.board)
        except FrameError as err:
            image_why = f"image: {err}"
        for lidar, s in specs.items():
            reasons = [image_why] if image_why else []
            fit = None
            try:
                fit = estimate_board(simulate_scan(s, scene, i, biases[lidar]), s.board, s.lidar_model)
            except FrameError as err:
                reasons.append(f"LiDAR: {err}")
            frames[lidar].append(
                FrameResult(name, not reasons, "; ".join(reasons) or None, board=fit, corners=corners)
            )
    return ObservedSet(
        rig, seed, config, frames, np.asarray(spec.T_cam_lidar), truth, biases["full"],
        time.perf_counter() - t0,
    )  # fmt: skip


def cached_set(rig: str, seed: int, cache: Path | None) -> ObservedSet:
    """Set ``seed`` of ``rig`` observed, read from ``cache/<rig>-<seed>.pkl`` when there (else written)."""
    path = cache / f"{rig}-{seed}.pkl" if cache else None
    if path is not None and path.is_file():
        with path.open("rb") as fh:
            return pickle.load(fh)
    obs = observe_set(rig, seed)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        with tmp.open("wb") as fh:
            pickle.dump(obs, fh)
        tmp.replace(path)
    return obs


# ----------------------------------------------------------------------------------------------
# Solving from the cache

#: the board subsets solved: all frames, and every 4th (5 of 20, spread over the directions)
SUBSETS = {"all": 1, "few": 4}
#: the key suffix of the solves after the boards were fitted again on corrected ranges
REFIT = "/refit"
#: every model solved per LiDAR and subset; the choice among any of them is made from these solves
SOLVED = ("none", "offset", "range", "beams")


@dataclass
class ModelSolve:
    """One model's solve of a set: its extrinsic and covariance, the used boards' refined poses and
    their images held out (name: ``HeldOut``), or why it failed."""

    T: np.ndarray | None = None
    C: np.ndarray | None = None
    boards: dict[str, np.ndarray] = field(default_factory=dict)
    held_out: dict[str, HeldOut] = field(default_factory=dict)
    seconds: float = 0.0
    failure: str | None = None
    lidar: dict[str, list] | None = None  # the LiDAR's errors: names, values (m)
    terms: tuple[float, int] = (0.0, 0)  # their Wald chi-square against zero, dof (selection.range_terms)


@dataclass
class Solved:
    """One variant (a model forced, or the choice among several) against the truth."""

    nees: float = float("nan")
    rot_deg: float = float("nan")
    trans_mm: float = float("nan")
    used: int = 0
    corner_rms_mm: list[float] = field(default_factory=list)
    chosen: str = ""
    weights: dict[str, float] = field(default_factory=dict)
    factor: float = 1.0
    seconds: float = 0.0
    failure: str | None = None


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """xi (6,) with ``T_true = T_est Expmap(xi)``."""
    return np.asarray(gtsam.Pose3(T_est).localCoordinates(gtsam.Pose3(T_true)), dtype=np.float64)


def corner_rms_mm(T_est: np.ndarray, T_true: np.ndarray, board) -> float:  # noqa: ANN001 - Board
    """RMS distance (mm) of the board's inner corners at ``T_est`` from the true ones (closer half turn)."""
    K = board.corners_board()
    c = K @ T_est[:3, :3].T + T_est[:3, 3]
    cands = [T_true] + ([T_true @ board.T_half_turn()] if board.half_turn_symmetric else [])
    return min(
        1e3 * float(np.sqrt(np.mean(np.sum((c - (K @ T[:3, :3].T + T[:3, 3])) ** 2, axis=1)))) for T in cands
    )


def _solve_all(frames: list[FrameResult], config: Config) -> dict[str, ModelSolve]:
    """Every model of ``SOLVED`` on the frames: its solve and held-out scores."""
    try:
        prep = prepare(frames, config)
    except CalibrationImpossible as err:
        return {m: ModelSolve(failure=str(err)) for m in SOLVED}
    base = frames_problem(prep.frames, config.camera, prep.T_init)
    names = [b.name for b in base.boards]
    out = {}
    for m in SOLVED:
        t0 = time.perf_counter()
        try:
            sol = solve_problem(MODELS[m].problem(base))
            est = sol.extrinsic()
            ho = {names[k]: h for k, h in held_out(sol).items()}
        except (CalibrationImpossible, IndeterminateSystem, np.linalg.LinAlgError) as err:
            out[m] = ModelSolve(failure=str(err))
            continue
        boards = {names[i]: sol.board_pose(i) for i in sol.boards}
        lid = sol.lidar(0)
        le = None if lid is None else {"names": list(lid[0]), "values": [float(v) for v in lid[1]]}
        dt = time.perf_counter() - t0
        out[m] = ModelSolve(est.T, est.covariance, boards, ho, dt, lidar=le, terms=range_terms(sol))
    return out


def _choose(ok: dict[str, ModelSolve], names: tuple[str, ...]) -> Selection:
    """The choice ``select_model`` makes (``model_solves.decide``), from the cached solves ``ok``."""
    held = {n: s.held_out for n, s in ok.items()}
    used = {n: len(s.boards) for n, s in ok.items()}
    return decide(held, used, names, None, {n: s.terms for n, s in ok.items()}, [MODELS[n] for n in ok])


def _refit(
    obs: ObservedSet, lidar: str, frames: list[FrameResult], solves: dict[str, ModelSolve]
) -> list[FrameResult] | None:
    """The frames with their boards fitted again as ``run.range_refit`` does it (the scans simulated
    again, corrected by the default's chosen model's estimate of the LiDAR's range errors), or None
    when that correction is not significant."""
    ok = {n: solves[n] for n in AUTO if solves[n].failure is None}
    if not ok:
        return None
    sel = _choose(ok, AUTO)
    le = ok[sel.chosen].lidar
    correction = None if le is None else correction_of({"lidar_errors": le})
    if not significant(frames, correction, obs.config.board):
        return None
    spec = rig_spec(obs.rig, obs.seed).with_(systematics=LIDARS[lidar])
    biases = beam_biases(spec)
    index = {name: i for i, name in enumerate(obs.T_lidar_board)}
    fits: dict[str, object] = {}
    for f in frames:
        if f.board is None:
            continue
        i = index[f.name]
        scan = simulate_scan(spec, frame_scene(spec, obs.T_lidar_board[f.name], i), i, biases)
        try:
            expected = ExpectedBoard(f.board.T_lidar_board)
            fits[f.name] = estimate_board(
                scan, spec.board, spec.lidar_model, None, LidarOptions(), expected, correction
            )
        except FrameError as err:
            fits[f.name] = err
    return refit_frames(frames, fits)


def solve_models(obs: ObservedSet) -> dict[tuple[str, str, str], ModelSolve]:
    """Per (LiDAR, subset, model of ``SOLVED``) its solve and held-out scores; and per
    (LiDAR, subset + ``REFIT``, model) the same after the boards were fitted again on the ranges
    corrected by the default's estimate (``run.range_refit``), where that correction is significant."""
    logging.getLogger("ilcc_graph").setLevel(logging.ERROR)
    out: dict[tuple[str, str, str], ModelSolve] = {}
    for lidar, frames in obs.frames.items():
        for subset, stride in SUBSETS.items():
            part = frames[::stride]
            first = _solve_all(part, obs.config)
            out.update({(lidar, subset, m): s for m, s in first.items()})
            again = _refit(obs, lidar, part, first)
            if again is not None:
                out.update({(lidar, subset + REFIT, m): s for m, s in _solve_all(again, obs.config).items()})
    return out


def variant(obs: ObservedSet, solves: dict[str, ModelSolve], names: tuple[str, ...]) -> Solved:
    """The variant choosing among ``names`` (one name: that model forced) against the truth."""
    ok = {n: solves[n] for n in names if solves[n].failure is None}
    if not ok:
        return Solved(failure=next(solves[n].failure for n in names))
    if len(names) == 1:
        sel, C = None, ok[names[0]].C
        chosen = names[0]
    else:
        sel = _choose(ok, names)
        chosen = sel.chosen
        C = mixture({n: (s.T, s.C) for n, s in ok.items()}, sel)
    s = ok[chosen]
    xi = pose_error(s.T, obs.T_cam_lidar)
    r = Solved(
        nees=float(xi @ np.linalg.solve(C, xi)),
        rot_deg=float(np.degrees(np.linalg.norm(xi[:3]))),
        trans_mm=float(1e3 * np.linalg.norm(s.T[:3, 3] - obs.T_cam_lidar[:3, 3])),
        used=len(s.boards),
        corner_rms_mm=[
            corner_rms_mm(Tb, obs.T_lidar_board[n], obs.config.board) for n, Tb in s.boards.items()
        ],
        chosen=chosen,
        seconds=sum(solves[n].seconds for n in names),
    )
    if sel is not None:
        r.weights = {c.name: c.weight for c in sel.candidates}
        r.factor = next(c.factor for c in sel.candidates if c.name == chosen)
    return r


# ----------------------------------------------------------------------------------------------
# The camera: intrinsics stated with a typical error (vlp16 + pinhole, the ``full`` LiDAR)


def with_camera(frames: list[FrameResult], camera) -> list[FrameResult]:  # noqa: ANN001 - CameraModel
    """The frames' image corners as seen through ``camera`` (bearings from the same pixels)."""
    return [
        f
        if f.corners is None
        else replace(f, corners=replace(f.corners, bearings=camera.bearing(f.corners.uv)))
        for f in frames
    ]


def solve_camera(obs: ObservedSet) -> dict[tuple[str, str], Solved]:
    """Per (intrinsics stated: ``right`` or ``typical error``, variant): the default's choice of the
    camera (``auto``) and the intrinsics forced ``stated`` or ``refined``, the LiDAR model chosen
    as the default chooses it, on all boards of the ``full`` LiDAR."""
    logging.getLogger("ilcc_graph").setLevel(logging.ERROR)
    out: dict[tuple[str, str], Solved] = {}
    for stated, err in (("right", IntrinsicsError()), ("typical error", IntrinsicsError.typical(1.0))):
        cam = stated_camera(obs.config.camera, err, obs.seed)
        config = replace(obs.config, camera=cam)
        for v, how in (("auto", "auto"), ("stated", "stated"), ("refined", "stated")):
            t0 = time.perf_counter()
            try:
                prep = prepare(with_camera(obs.frames["full"], cam), config)
                intr = IntrinsicsOptions(refine=v == "refined")
                sol = solve_batch(
                    prep.frames, cam, prep.T_init, models=AUTO, intrinsics=intr, intrinsics_choice=how
                )
            except (CalibrationImpossible, IndeterminateSystem) as err2:
                out[(stated, v)] = Solved(failure=str(err2))
                continue
            xi = pose_error(sol.T_cam_lidar, obs.T_cam_lidar)
            cc = sol.selection.camera if sol.selection is not None else None
            out[(stated, v)] = Solved(
                nees=float(xi @ np.linalg.solve(sol.covariance, xi)),
                rot_deg=float(np.degrees(np.linalg.norm(xi[:3]))),
                trans_mm=float(1e3 * np.linalg.norm(sol.T_cam_lidar[:3, 3] - obs.T_cam_lidar[:3, 3])),
                used=len(sol.per_frame),
                chosen=("refined" if cc.refined else "stated") if cc is not None else v,
                seconds=time.perf_counter() - t0,
            )
    return out


# ----------------------------------------------------------------------------------------------
# Tables

#: the default and the variants the tables show: name -> the models chosen among, and whether the
#: boards fitted again on corrected ranges are used where the default fitted them again
SHOWN: dict[str, tuple[tuple[str, ...], bool]] = {
    "default (auto)": (AUTO, True),
    "default, first fits only": (AUTO, False),
    **{f"{m} forced (first fits)": ((m,), False) for m in SOLVED},
}
CORNER_TARGET = {"hdl32": 0.5, "vlp16": 0.75}
CHI2_6_95 = 12.59


def _row(name: str, rs: list[Solved], fails: int, target: float) -> str:
    ne = np.array([r.nees for r in rs])
    rot, tr = np.array([r.rot_deg for r in rs]), np.array([r.trans_mm for r in rs])
    cr = np.concatenate([r.corner_rms_mm for r in rs])
    chosen = Counter(r.chosen for r in rs)
    ch = ", ".join(f"{k} {v}" for k, v in chosen.most_common()) if len(rs[0].weights) > 1 else "-"
    return (
        f"| {name} | {len(rs)}" + (f" ({fails} failed)" if fails else "") + f" | {ne.mean():.2f} | "
        f"{100 * np.mean(ne <= CHI2_6_95):.0f} % | {np.median(rot):.4f} / {np.percentile(rot, 90):.4f} | "
        f"{np.median(tr):.2f} / {np.percentile(tr, 90):.2f} | "
        f"{np.median(cr):.2f} ({100 * np.mean(cr <= target):.0f} %) "
        f"| {np.mean([r.used for r in rs]):.1f} | {ch} |"
    )


def variants_of(
    results: dict, rig: str, lidar: str, subset: str, names: tuple[str, ...], refit: bool = True
) -> tuple[list, int]:
    """The sets' ``variant`` of ``names`` (with ``refit``: on the boards fitted again where the default
    fitted them again) and the number that failed."""
    rs, fails = [], 0
    for (r, _), res in sorted(results.items()):
        if r != rig:
            continue
        obs_like = res["truth"]
        key = subset + REFIT if refit and (lidar, subset + REFIT, names[0]) in res["models"] else subset
        chosen_among = tuple(m.name for m in candidates([MODELS[n] for n in names], key != subset))
        v = variant(obs_like, {m: res["models"][(lidar, key, m)] for m in SOLVED}, chosen_among)
        if v.failure is None:
            rs.append(v)
        else:
            fails += 1
    return rs, fails


@dataclass
class Truth:
    """What ``variant`` needs of a set: the truth (kept in the sink instead of the whole set)."""

    T_cam_lidar: np.ndarray
    T_lidar_board: dict[str, np.ndarray]
    config: Config


def tables(results: dict) -> list[str]:
    lines: list[str] = []
    head = (
        "| variant | sets | mean NEES | coverage 95 % | rot. median / p90 deg | trans. median / p90 mm | "
        "corner RMS mm, median (boards within target) | boards used | model chosen |"
    )
    for rig in RIGS:
        seeds = sorted(s for r, s in results if r == rig)
        if not seeds:
            continue
        for lidar in LIDARS:
            for subset in SUBSETS:
                lines += [
                    f"### {rig}, LiDAR `{lidar}`, "
                    + ("all boards" if subset == "all" else "every 4th board (5)"),
                    "",
                    head,
                    "|" + "---|" * (head.count("|") - 1),
                ]
                for name, (names, refit) in SHOWN.items():
                    rs, fails = variants_of(results, rig, lidar, subset, names, refit)
                    if rs:
                        lines.append(_row(name, rs, fails, CORNER_TARGET[rig]))
                key = (lidar, subset + REFIT, "none")
                n_refit = sum(key in res["models"] for (r, _), res in results.items() if r == rig)
                lines += ["", f"Boards fitted again on corrected ranges in {n_refit} of {len(seeds)} sets."]
                lines.append("")
    return lines


def camera_table(results: dict) -> list[str]:
    rows = [
        (s, res["camera"]) for (r, s), res in sorted(results.items()) if r == "vlp16" and res.get("camera")
    ]
    if not rows:
        return []
    lines = [
        f"### vlp16 + pinhole, LiDAR `full`, all boards: intrinsics stated right or with a typical error "
        f"({len(rows)} sets)",
        "",
        "| intrinsics stated | variant | mean NEES | coverage 95 % | trans. median / p90 mm | refined in |",
        "|---|---|---|---|---|---|",
    ]
    for stated in ("right", "typical error"):
        for v in ("auto", "stated", "refined"):
            rs = [c[(stated, v)] for _, c in rows if c[(stated, v)].failure is None]
            if not rs:
                continue
            ne, tr = np.array([r.nees for r in rs]), np.array([r.trans_mm for r in rs])
            lines.append(
                f"| {stated} | {'default (auto)' if v == 'auto' else v + ' forced'} | {ne.mean():.2f} | "
                f"{100 * np.mean(ne <= CHI2_6_95):.0f} % | "
                f"{np.median(tr):.2f} / {np.percentile(tr, 90):.2f} | "
                f"{sum(r.chosen == 'refined' for r in rs)}/{len(rs)} |"
            )
    return lines + [""]


def figure(results: dict, path: Path) -> None:
    """NEES histograms of the default against ``none`` forced, per rig, LiDAR ``full``, all / few boards."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True)
    bins = np.linspace(0, 30, 31)
    for i, rig in enumerate(RIGS):
        for j, subset in enumerate(SUBSETS):
            ax = axes[i, j]
            for name, names, colour in (("default (auto)", AUTO, "C0"), ("none forced", ("none",), "C3")):
                rs, _ = variants_of(results, rig, "full", subset, names, name == "default (auto)")
                ne = np.clip([r.nees for r in rs], 0, 30)
                if len(ne):
                    ax.hist(
                        ne,
                        bins,
                        alpha=0.5,
                        color=colour,
                        label=f"{name}: mean {np.mean([r.nees for r in rs]):.1f}",
                    )
            x = np.linspace(0.01, 30, 300)
            rs, _ = variants_of(results, rig, "full", subset, AUTO)
            ax.plot(x, len(rs) * chi2.pdf(x, 6), "k--", lw=1, label="chi-square 6 dof")
            ax.axvline(CHI2_6_95, color="grey", lw=0.8)
            ax.set_title(
                f"{rig}, LiDAR full (20 mm offset), {'all boards' if subset == 'all' else '5 boards'}"
            )
            ax.legend(fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("NEES of T_cam_lidar (clipped at 30)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", type=int, default=50)
    ap.add_argument("--first-seed", type=int, default=3000)
    ap.add_argument("--rigs", default=",".join(RIGS))
    ap.add_argument("--obs-cache", type=Path, required=True)
    ap.add_argument("--observe-only", action="store_true")
    ap.add_argument("--sink", type=Path, help="results pickle: solved sets are kept and skipped on a re-run")
    ap.add_argument("--camera-sets", type=int, default=25, help="vlp16 sets with the camera experiment")
    ap.add_argument("--write", action="store_true", help="tables and figure to docs/ from the sink")
    args = ap.parse_args(argv)
    logging.getLogger("ilcc_graph").setLevel(logging.ERROR)
    rigs = args.rigs.split(",")
    results = {}
    if args.sink is not None and args.sink.is_file():
        with args.sink.open("rb") as fh:
            results = pickle.load(fh)
    t_start = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.sets):
        for rig in rigs:
            camera = rig == "vlp16" and seed < args.first_seed + args.camera_sets
            done = results.get((rig, seed), {})
            if "models" in done and ("camera" in done or not camera):
                continue
            t0 = time.perf_counter()
            obs = cached_set(rig, seed, args.obs_cache)
            msg = f"{rig} {seed}: {time.perf_counter() - t0:.1f} s ({obs.seconds:.1f} s observing)"
            if not args.observe_only:
                t1 = time.perf_counter()
                res = dict(done) or {"truth": Truth(obs.T_cam_lidar, obs.T_lidar_board, obs.config)}
                if "models" not in res:
                    res["models"] = solve_models(obs)
                if camera:
                    res["camera"] = solve_camera(obs)
                results[(rig, seed)] = res
                msg += f", solved in {time.perf_counter() - t1:.1f} s"
                if args.sink is not None:
                    tmp = args.sink.with_suffix(".tmp")
                    with tmp.open("wb") as fh:
                        pickle.dump(results, fh)
                    tmp.replace(args.sink)
            print(msg, flush=True)
    if args.write:
        lines = tables(results) + camera_table(results)
        figure(results, DOC.with_suffix(".png"))
        when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
        head = (
            f"Generated by `python scripts/bench_sensor_model.py {' '.join(argv or sys.argv[1:])}` on {when} "
            f"({(time.perf_counter() - t_start) / 60:.1f} min; load average {os.getloadavg()[0]:.1f}, "
            "2 cores, shared)."
        )
        write_between(DOC, "<!-- bench:begin -->", "<!-- bench:end -->", "\n".join([head, "", *lines]))
        print(f"wrote {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
