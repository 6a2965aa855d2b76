"""Benchmark of the batch solve (estimation.batch): time vs frames, factor design, Monte Carlo NEES.

Synthetic problems as in tests/test_graph.py: an 8000x4000 equirectangular camera, a 6x8 board
(35 corners) 1.5-5 m around the LiDAR, pixel noise 0.5 px (random anisotropic covariance per
corner), board-pose priors with sigmas ~(2, 2, 1) mrad and (3, 3, 2) mm drawn from their covariances.

Run: ``nice python3 scripts/bench_graph.py [--runs 50] [--write]`` (``--write`` puts the tables into
docs/bench_graph.md between markers).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, X
from scipy.stats import chi2

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "scripts"))

from bench_customfactor import write_section  # noqa: E402
from test_graph import CAMERA, T_TRUE, perturbed, synthetic_problem  # noqa: E402

import ilcc_graph.estimation.noise as noise_policy  # noqa: E402
from factors import bearing_factor, tangent_bases  # noqa: E402
from ilcc_graph.estimation import NoiseOptions, solve  # noqa: E402
from ilcc_graph.estimation.paper import refine_paper  # noqa: E402

#: the noise as stated: one LM solve, no gate, no variance components (the per-corner graph's model)
AS_STATED = NoiseOptions(chi2_gate_prob=None, variance_components=False)

# Each Levenberg-Marquardt solve of the noise policy (the gate's re-solves, the variance components'
# iterations) is counted: ``solve`` reports only the sum of their iterations.
_LM_RUNS: list[int] = []
_optimize = noise_policy.optimize


def _counted_optimize(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
    result, iterations = _optimize(*args, **kwargs)
    _LM_RUNS.append(iterations)
    return result, iterations


noise_policy.optimize = _counted_optimize


def _solve_counted(frames, T0, options: NoiseOptions = NoiseOptions()):  # noqa: ANN001, ANN202
    """``solve`` and the iterations of each LM solve it ran."""
    _LM_RUNS.clear()
    sol = solve(frames, CAMERA, T0, options)
    return sol, list(_LM_RUNS)


def _errors(T_est: np.ndarray, T_true: gtsam.Pose3 = T_TRUE) -> tuple[float, float]:
    """Rotation error (deg) and translation error (mm) of T_est w.r.t. the truth."""
    xi = gtsam.Pose3(T_est).localCoordinates(T_true)
    return float(np.degrees(np.linalg.norm(xi[:3]))), float(
        1e3 * np.linalg.norm(T_est[:3, 3] - T_true.translation())
    )


def timing_table(sizes: tuple[int, ...], repeats: int) -> str:
    rng = np.random.default_rng(100)
    rows = [
        "| frames | corners | solve + marginals, median (s) | build (s) | LM (s) | LM solves | "
        "LM iterations, first solve / all | marginals (s) | components' uncertainty (s) | "
        "rest of the noise policy (s) | s per frame |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n in sizes:
        times, parts = [], []
        for _ in range(repeats):
            frames, _ = synthetic_problem(rng, n)
            T0 = perturbed(T_TRUE, rng)
            t0 = time.perf_counter()
            sol, runs = _solve_counted(frames, T0)
            total = time.perf_counter() - t0
            times.append(total)
            t = sol.timings
            b, o, m, u = (
                t["build"],
                t["optimize"],
                t.get("marginals", 0.0),
                t.get("component_uncertainty", 0.0),
            )
            parts.append((b, o, len(runs), runs[0], sum(runs), m, u, total - b - o - m - u))
        med = float(np.median(times))
        b, o, k, first, its, m, u, rest = np.median(np.array(parts), axis=0)
        rows.append(
            f"| {n} | {35 * n} | {med:.3f} | {b:.3f} | {o:.3f} | {k:.0f} | {first:.0f} / {its:.0f} | "
            f"{m:.3f} | {u:.3f} | {rest:.3f} | {1e3 * med / n:.1f} ms |"
        )
    return "\n".join(rows)


def _per_corner_solve(frames, T0: np.ndarray) -> tuple[float, np.ndarray]:
    """The same graph with one single-corner CustomFactor per corner (the design we avoid)."""
    t0 = time.perf_counter()
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(X(0), gtsam.Pose3(T0))
    for i, f in enumerate(frames):
        values.insert(B(i), gtsam.Pose3(f.T_lidar_board))
        graph.add(
            gtsam.PriorFactorPose3(
                B(i), gtsam.Pose3(f.T_lidar_board), gtsam.noiseModel.Gaussian.Covariance(f.board_cov, False)
            )
        )
        cov_t = CAMERA.bearing_tangent_cov(f.bearings, f.cov_px, tangent_bases(f.bearings))
        for k in range(len(f.bearings)):
            noise = gtsam.noiseModel.Gaussian.Covariance(cov_t[k], False)
            graph.add(bearing_factor(X(0), B(i), f.points_board[k], f.bearings[k], noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    cov = gtsam.Marginals(graph, result).marginalCovariance(X(0))
    return time.perf_counter() - t0, np.asarray(cov)


def design_table(sizes: tuple[int, ...]) -> str:
    rng = np.random.default_rng(200)
    rows = [
        "| frames | grouped: 1 CustomFactor per frame (s) | per corner: 1 CustomFactor per corner (s) | "
        "max rel. difference of the covariances |",
        "|---:|---:|---:|---:|",
    ]
    for n in sizes:
        frames, _ = synthetic_problem(rng, n)
        T0 = perturbed(T_TRUE, rng)
        t0 = time.perf_counter()
        sol = solve(frames, CAMERA, T0, AS_STATED)  # the per-corner graph's noise model: nothing rescaled
        t_grouped = time.perf_counter() - t0
        t_single, cov = _per_corner_solve(frames, T0)
        diff = np.abs(cov - sol.covariance).max() / np.abs(sol.covariance).max()
        rows.append(f"| {n} | {t_grouped:.3f} | {t_single:.2f} | {diff:.1e} |")
    return "\n".join(rows)


def monte_carlo_table(runs: int, n_frames: int) -> str:
    rng = np.random.default_rng(300)
    methods = {
        "graph (default noise policy)": NoiseOptions(),
        "graph, noise as stated (no gate, no variance components)": AS_STATED,
        "graph, huber": NoiseOptions(robust="huber"),
    }
    err: dict[str, list[tuple[float, float]]] = {"start": [], "paper": [], **{m: [] for m in methods}}
    nees: dict[str, list[float]] = {m: [] for m in methods}
    times: dict[str, list[float]] = {"paper": [], **{m: [] for m in methods}}
    lm: dict[str, list[tuple[int, int]]] = {m: [] for m in methods}
    for _ in range(runs):
        frames, _ = synthetic_problem(rng, n_frames)
        T0 = perturbed(T_TRUE, rng, rot=0.01, trans=0.02)
        err["start"].append(_errors(T0))
        t0 = time.perf_counter()
        T_paper = refine_paper(frames, T0)
        times["paper"].append(time.perf_counter() - t0)
        err["paper"].append(_errors(T_paper))
        for name, opts in methods.items():
            t0 = time.perf_counter()
            sol, solves = _solve_counted(frames, T0, opts)
            times[name].append(time.perf_counter() - t0)
            err[name].append(_errors(sol.T_cam_lidar))
            lm[name].append((len(solves), solves[0]))
            xi = gtsam.Pose3(sol.T_cam_lidar).localCoordinates(T_TRUE)
            nees[name].append(float(xi @ np.linalg.solve(sol.covariance, xi)))
    bound = chi2.ppf(0.95, 6)
    rows = [
        f"{runs} runs x {n_frames} frames (35 corners each); start = truth perturbed by 0.01 rad / 0.02 m "
        "per axis (1 sigma).",
        "",
        "| method | rot. err. median (deg) | rot. err. p90 (deg) | trans. err. median (mm) | "
        "trans. err. p90 (mm) | mean NEES | inside chi2(6) 95 % | LM solves, median | iterations of the "
        "first, median | time median (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, e in err.items():
        a = np.array(e)
        r = f"| {name} | {np.median(a[:, 0]):.4f} | {np.percentile(a[:, 0], 90):.4f} | "
        r += f"{np.median(a[:, 1]):.2f} | {np.percentile(a[:, 1], 90):.2f} | "
        if name in nees:
            v = np.array(nees[name])
            k = np.array(lm[name])
            r += f"{v.mean():.2f} | {100 * np.mean(v < bound):.0f} % | "
            r += f"{np.median(k[:, 0]):.0f} | {np.median(k[:, 1]):.0f} | "
        else:
            r += "- | - | - | - | "
        r += f"{np.median(times[name]):.3f} |" if name in times else "- |"
        rows.append(r)
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50, help="Monte Carlo runs")
    parser.add_argument("--frames", type=int, default=20, help="frames per Monte Carlo run")
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats per size")
    parser.add_argument("--write", action="store_true", help="write the tables into docs/bench_graph.md")
    args = parser.parse_args()
    tables = {
        "graph-timing": timing_table((20, 50, 100, 200, 400), args.repeats),
        "graph-design": design_table((5, 20, 50)),
        "graph-montecarlo": monte_carlo_table(args.runs, args.frames),
    }
    for name, table in tables.items():
        print(f"## {name}\n{table}\n")
        if args.write:
            write_section(ROOT / "docs" / "bench_graph.md", name, table)


if __name__ == "__main__":
    main()
