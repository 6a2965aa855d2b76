"""Benchmark of ilcc_graph.estimation.rig.solve_rig: four pinhole cameras around a LiDAR (Monte Carlo).

Graph-level synthetic frames (tests/synthetic_graph.py): four 1280x960 pinhole cameras with a
110 deg horizontal field, looking out every 90 deg, 10 cm off the LiDAR axis and 20 cm up (the rig of
tests/test_joint.py); boards 1.5-4 m all around; a board fully inside two images is one variable
seen by both. 0.5 px corner noise, board priors as in docs/bench_joint.md.

Per camera: error of ``T_cam_lidar`` and NEES. Per camera pair: error and NEES of ``T_ca_cb``
with the covariance from the joint marginal (``relative_pose``), and, for contrast, NEES with the
cross-covariance ignored (sum of the two marginals pushed through the same Jacobians).

Run: ``nice python3 scripts/bench_rig.py [--runs 50] [--frames 40] [--write]``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gtsam
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "scripts"))

from bench_customfactor import write_section  # noqa: E402
from synthetic_graph import rig_frames  # noqa: E402
from test_joint import rig  # noqa: E402

from ilcc_graph.board import Board  # noqa: E402
from ilcc_graph.estimation.rig import relative_pose, solve_rig  # noqa: E402

BOARD = Board(6, 8, 0.075)
DOC = ROOT / "docs" / "bench_joint.md"


def nees(T_est: np.ndarray, cov: np.ndarray, T: gtsam.Pose3) -> float:
    xi = gtsam.Pose3(T_est).localCoordinates(T)
    return float(xi @ np.linalg.solve(cov, xi))


def errors(T_est: np.ndarray, T: gtsam.Pose3) -> tuple[float, float]:
    xi = gtsam.Pose3(T_est).localCoordinates(T)
    return float(np.degrees(np.linalg.norm(xi[:3]))), float(
        1e3 * np.linalg.norm(T_est[:3, 3] - T.translation())
    )


def run(runs: int, n_frames: int) -> str:
    rng = np.random.default_rng(3)
    cams, truth = rig(4)
    names = list(cams)
    per_cam: dict[str, list[tuple[float, float, float, float, float]]] = {n: [] for n in names}
    per_pair: dict[tuple[str, str], list[tuple[float, float, float, float]]] = {}
    shared, views = [], []
    for _ in range(runs):
        frames = rig_frames(rng, n_frames, cams, truth, BOARD)
        shared.append(sum(len(f.views) > 1 for f in frames))
        views.append(sum(len(f.views) for f in frames))
        sol = solve_rig(frames, cams)
        for n in names:
            e = sol.extrinsics[n]
            r, t = errors(e.T, truth[n])
            per_cam[n].append(
                (
                    r,
                    t,
                    nees(e.T, e.covariance, truth[n]),
                    np.degrees(e.sigmas[:3]).max(),
                    1e3 * e.sigmas[3:].max(),
                )
            )
        for (a, b), est in sol.relative.items():
            T_ab = truth[a] * truth[b].inverse()
            r, t = errors(est.T, T_ab)
            ia, ib = names.index(a), names.index(b)
            C = np.zeros((12, 12))
            C[:6, :6] = sol.joint_covariance[6 * ia : 6 * ia + 6, 6 * ia : 6 * ia + 6]
            C[6:, 6:] = sol.joint_covariance[6 * ib : 6 * ib + 6, 6 * ib : 6 * ib + 6]
            naive = relative_pose(sol.extrinsics[a].T, sol.extrinsics[b].T, C)
            per_pair.setdefault((a, b), []).append(
                (r, t, nees(est.T, est.covariance, T_ab), nees(est.T, naive.covariance, T_ab))
            )
    rows = [
        f"{runs} runs of {n_frames} boards; {np.mean(views):.1f} camera views per run, {np.mean(shared):.1f} "
        "boards seen by two cameras. NEES: mean over runs (6 expected; 95 % band for the mean of "
        f"{runs} runs about 6 +- {1.96 * np.sqrt(12 / runs):.1f}).",
        "",
        "| camera | rotation error mean / max (deg) | translation error mean / max (mm) "
        "| max sigma rot (deg) | max sigma trans (mm) | mean NEES |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for n in names:
        d = np.array(per_cam[n])
        rows.append(
            f"| {n} | {d[:, 0].mean():.4f} / {d[:, 0].max():.4f} "
            f"| {d[:, 1].mean():.2f} / {d[:, 1].max():.2f} "
            f"| {d[:, 3].mean():.4f} | {d[:, 4].mean():.2f} | {d[:, 2].mean():.2f} |"
        )
    rows += [
        "",
        "| camera pair (T_ca_cb) | rotation error mean (deg) | translation error mean (mm) "
        "| mean NEES, joint covariance | mean NEES, cross-covariance ignored |",
        "|---|---:|---:|---:|---:|",
    ]
    for (a, b), vals in per_pair.items():
        d = np.array(vals)
        rows.append(
            f"| {a} - {b} | {d[:, 0].mean():.4f} | {d[:, 1].mean():.2f} "
            f"| {d[:, 2].mean():.2f} | {d[:, 3].mean():.2f} |"
        )
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    table = run(args.runs, args.frames)
    print(table)
    if args.write:
        write_section(DOC, "rig", table)
        print(f"wrote {DOC}")


if __name__ == "__main__":
    main()
