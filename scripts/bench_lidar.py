"""Benchmark of the LiDAR stage on the project's simulator: the paper's Figure 12 re-done.

Conditions: noise multiplier 1-3 at 1 m, and distance 1-6 m at baseline noise (HDL-32E, the
paper's 6 x 8 board of 75 mm, the simulator's clutter: room walls, stand, a person beside the
board half of the time, systematics on). Each seed draws a board pose like the simulator's
placements (diamond, +-15 deg pitch, +-25 deg yaw, any azimuth). Metrics per condition:
detection rate, the paper's error ``sqrt(sum_k |e_k|^2) / n`` as % of the square side, per-corner
RMS (mm), board-pose NEES against the truth (6 dof), and timings. Only LiDAR scans are simulated
(no image rendering). Writes docs/bench_lidar.md and docs/bench_lidar_*.png.

    nice python3 scripts/bench_lidar.py --seeds 100        # full
    nice python3 scripts/bench_lidar.py --seeds 10 --quick # smoke run
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import gtsam
import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.errors import BoardNotFound
from ilcc_graph.lidar import LidarOptions, estimate_board
from ilcc_graph.simulate import SceneOptions, frame_scene, simulate_scan, standard_spec

SPEC_EXTRA: dict = {}
DOCS = Path(__file__).resolve().parents[1] / "docs"


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def board_pose(
    board: Board, distance: float, rng: np.random.Generator, vertical_deg: np.ndarray
) -> np.ndarray:
    """T_lidar_board: pattern centre at ``distance``, facing the LiDAR, diamond roll, random tilt."""
    x0, x1, y0, y1 = board.extent()
    radius = 0.5 * np.hypot(x1 - x0, y1 - y0)
    a = np.arcsin(min(1.0, radius / distance))
    el_lo, el_hi = np.deg2rad(vertical_deg[0]) + a + 0.02, np.deg2rad(vertical_deg[-1]) - a - 0.02
    # above the floor (1.5 m below the LiDAR) and below the ceiling (2.5 m above), 0.3 m clear
    el_lo = max(el_lo, np.arcsin(np.clip((-1.5 + 0.3 + radius) / distance, -1, 1)))
    el_hi = min(el_hi, np.arcsin(np.clip((2.5 - 0.3 - radius) / distance, -1, 1)))
    el = 0.5 * (el_lo + el_hi) + (0.0 if el_hi < el_lo else rng.uniform(-0.3, 0.3) * (el_hi - el_lo))
    az = rng.uniform(-np.pi, np.pi)
    centre = distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    z0 = -centre / distance
    x0v = np.cross([0.0, 0.0, 1.0], z0)
    x0v /= np.linalg.norm(x0v)
    y0v = np.cross(z0, x0v)
    roll = np.deg2rad(45.0 + 90.0 * rng.integers(4) + rng.uniform(-8, 8))
    pitch, yaw = np.deg2rad(rng.uniform(-15, 15)), np.deg2rad(rng.uniform(-25, 25))
    R = np.column_stack([x0v, y0v, z0]) @ _rot(1, yaw) @ _rot(0, pitch) @ _rot(2, roll)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre - R @ board.pattern_centre
    return T


def simulate_one(lidar: str, distance: float, noise: float, seed: int):
    """(scan, T_lidar_board, spec) of one simulated frame with the board at ``distance``."""
    rng = np.random.default_rng(10_000 + seed)
    spec = standard_spec(lidar=lidar, seed=seed, noise_scale=noise, frames=1, **SPEC_EXTRA,
                         scene=SceneOptions(room=(-9.0, 9.0, -9.0, 9.0), ceiling_height_m=4.0))  # fmt: skip
    T = board_pose(spec.board, distance, rng, spec.lidar_model.vertical_angles_deg)
    spec = replace(spec, placements=(T,))
    scene = frame_scene(spec, T, 0)
    return simulate_scan(spec, scene, 0), T, spec


def pose_error(T_est: np.ndarray, T_true: np.ndarray, board: Board) -> np.ndarray:
    """xi with T_true = T_est * Expmap(xi); the half-turn twin of the truth when closer."""
    best = None
    for Tt in (T_true, T_true @ board.T_half_turn()) if board.half_turn_symmetric else (T_true,):
        xi = gtsam.Pose3.Logmap(gtsam.Pose3(T_est).between(gtsam.Pose3(Tt)))
        if best is None or np.linalg.norm(xi[3:]) < np.linalg.norm(best[3:]):
            best = xi
    return best


def run_condition(lidar: str, distance: float, noise: float, seeds: int, options: LidarOptions) -> dict:
    found, paper, rms, nees, t_det, t_fit, n_pts, reasons = 0, [], [], [], [], [], [], []
    c_det, c_fit = [], []
    for seed in range(seeds):
        scan, T, spec = simulate_one(lidar, distance, noise, seed)
        board = spec.board
        try:
            fit = estimate_board(scan, board, spec.lidar_model, None, options)
        except BoardNotFound as e:
            reasons.append(str(e)[:120])
            continue
        found += 1
        xi = pose_error(fit.T_lidar_board, T, board)
        T_true = fit.T_lidar_board @ np.asarray(gtsam.Pose3.Expmap(xi).matrix())
        truth = board.corners_board() @ T_true[:3, :3].T + T_true[:3, 3]
        e = fit.corners_lidar - truth
        n = len(e)
        paper.append(100.0 * np.sqrt((e**2).sum()) / n / board.square_size)
        rms.append(1e3 * np.sqrt((e**2).sum(axis=1).mean()))
        nees.append(float(xi @ np.linalg.solve(fit.covariance, xi)))
        t_det.append(fit.diagnostics["time_detect_s"])
        t_fit.append(fit.diagnostics["time_fit_s"])
        c_det.append(fit.diagnostics["cpu_detect_s"])
        c_fit.append(fit.diagnostics["cpu_fit_s"])
        n_pts.append(fit.diagnostics["n_points"])
    arr = lambda v: np.asarray(v, dtype=float)  # noqa: E731
    return {
        "distance": distance, "noise": noise, "seeds": seeds, "found": found,
        "paper_pct": arr(paper), "rms_mm": arr(rms), "nees": arr(nees),
        "t_detect": arr(t_det), "t_fit": arr(t_fit), "c_detect": arr(c_det), "c_fit": arr(c_fit),
        "n_points": arr(n_pts), "reasons": reasons,
    }  # fmt: skip


def _row(r: dict) -> str:
    def med(v: np.ndarray, f: str = ".2f") -> str:
        return format(float(np.median(v)), f) if v.size else "-"

    def ms(v: np.ndarray) -> str:
        return f"{1e3 * float(np.median(v)):.0f}" if v.size else "-"

    def mean(v: np.ndarray, f: str = ".2f") -> str:
        return format(float(np.mean(v)), f) if v.size else "-"

    return (
        f"| {r['distance']:.1f} | {r['noise']:.1f} "
        f"| {100 * r['found'] / r['seeds']:.0f} % ({r['found']}/{r['seeds']}) "
        f"| {mean(r['paper_pct'], '.3f')} | {mean(r['rms_mm'])} | {med(r['rms_mm'])} "
        f"| {mean(r['nees'])} | {med(r['nees'])} | {med(r['n_points'], '.0f')} "
        f"| {ms(r['t_detect'])} / {ms(r['c_detect'])} | {ms(r['t_fit'])} / {ms(r['c_fit'])} |"
    )


HEADER = (
    "| distance (m) | noise x | detected | paper error (% of square) | corner RMS mean (mm) "
    "| RMS median (mm) "
    "| NEES mean | NEES median | board points | detect ms wall / CPU | fit ms wall / CPU |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|"
)


def plot(results_noise: list[dict], results_dist: list[dict], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    for key, label, res, name in (
        ("noise", "noise multiplier (at 1 m)", results_noise, "noise"),
        ("distance", "distance (m), baseline noise", results_dist, "distance"),
    ):
        if not res:
            continue
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
        x = [r[key] for r in res]
        for ax, metric, ylab in (
            (axes[0], "paper_pct", "paper error, % of square side"),
            (axes[1], "rms_mm", "per-corner RMS (mm)"),
            (axes[2], "nees", "NEES (6 dof)"),
        ):
            data = [r[metric] if r[metric].size else np.array([np.nan]) for r in res]
            ax.boxplot(data, positions=x, widths=0.25 if key == "noise" else 0.4, showfliers=False)
            ax.plot(x, [np.mean(d) for d in data], "o-", label="mean")
            if metric == "nees":
                ax.axhspan(4.5, 7.5, color="g", alpha=0.15, label="aim 4.5-7.5")
                ax.set_yscale("log")
            ax.set_xlabel(label)
            ax.set_ylabel(ylab)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
        fig.suptitle(f"LiDAR stage on the simulator (HDL-32E, 6x8 board of 75 mm): error vs {name}")
        fig.tight_layout()
        path = out / f"bench_lidar_{name}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(path)
    return files


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--lidar", default="hdl32")
    ap.add_argument("--quick", action="store_true", help="fewer conditions (smoke run)")
    ap.add_argument("--out", type=Path, default=DOCS)
    args = ap.parse_args()
    opts = LidarOptions()
    noises = [1.0, 3.0] if args.quick else [1.0, 1.5, 2.0, 2.5, 3.0]
    dists = [1.0, 3.0, 6.0] if args.quick else [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    t0 = time.time()
    res_noise = [run_condition(args.lidar, 1.0, s, args.seeds, opts) for s in noises]
    for r in res_noise:
        print(_row(r), flush=True)
    res_dist = [run_condition(args.lidar, d, 1.0, args.seeds, opts) for d in dists]
    for r in res_dist:
        print(_row(r), flush=True)
    files = plot(res_noise, res_dist, args.out)
    lines = [
        "# LiDAR stage benchmark (simulated, the paper's Figure 12 re-done)",
        "",
        f"`scripts/bench_lidar.py --seeds {args.seeds}{' --quick' if args.quick else ''}`, "
        f"LiDAR {args.lidar}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
        f"{time.time() - t0:.0f} s wall time on the shared machine.",
        "Board: the paper's 6 x 8 squares of 75 mm, no margin. Scene: the simulator's room (18 x 18 m),",
        "stand, person beside the board in 60 % of the frames, systematics on (per-beam range bias 3 mm,",
        "+4 mm on black print, dropouts). Board pose per seed: diamond (45 deg + k 90 deg + up to 8 deg),",
        "pitch +-15 deg, yaw +-25 deg, random azimuth, kept above the floor. Errors against the simulator's",
        "true pose; the half-turn twin of a symmetric board counts as right. Paper error:",
        "sqrt(sum_k |e_k|^2) / n as % of the square side (n = 35 corners). Times: medians, wall clock and",
        "this process's CPU time (the machine's 2 cores were shared with other jobs: wall ~2-3x CPU).",
        "",
        "## Error against the noise multiplier (board at 1 m)",
        "",
        HEADER,
        *[_row(r) for r in res_noise],
        "",
        "## Error against distance (baseline noise)",
        "",
        HEADER,
        *[_row(r) for r in res_dist],
        "",
        *[f"![{f.stem}]({f.name})" for f in files],
        "",
    ]
    misses = [(r["distance"], r["noise"], m) for r in res_noise + res_dist for m in r["reasons"]]
    if misses:
        lines += ["## Frames where the board was not found", ""]
        lines += [f"- {d:.1f} m, noise x{s:.1f}: {m}" for d, s, m in misses[:30]]
        lines.append("")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_lidar.md").write_text("\n".join(lines))
    print(f"wrote {args.out / 'bench_lidar.md'}")


if __name__ == "__main__":
    main()
