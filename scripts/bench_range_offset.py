"""Benchmark of the LiDAR range offset (factors/range_offset.py, ilcc_graph.estimation.sessions).

1. The model against the simulator: the same scene scanned by the ray-casting LiDAR simulator with
   ``Systematics(range_offset_m=0.03)`` and without (no noise, no other systematics), both fitted by
   the LiDAR stage (``lidar.estimate_board``); the change of the fitted board pose is compared with
   the model's ``T * Expmap(b g)`` (up to the half turn of a symmetric board).
2. Graph-level Monte Carlo (tests/synthetic_graph.py; set-up in docs/bench_joint.md): board priors
   drawn around the pose a LiDAR reading ``b`` long would fit (an exact rigid fit of the board's
   face pushed along its rays, not the first-order model). Is ``b`` recovered within 3 sigma, and what
   does ignoring it do to the extrinsic?

Run: ``nice python3 scripts/bench_range_offset.py [--runs 100] [--sim-frames 8] [--write]``.
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
from synthetic_graph import session_frames  # noqa: E402
from test_joint import pinhole  # noqa: E402

from factors.range_offset import shifted_board_pose  # noqa: E402
from ilcc_graph.board import Board  # noqa: E402
from ilcc_graph.cameras import Equirectangular  # noqa: E402
from ilcc_graph.errors import CalibrationError  # noqa: E402
from ilcc_graph.estimation import NoiseOptions  # noqa: E402
from ilcc_graph.estimation.graphs import board_face_samples  # noqa: E402
from ilcc_graph.estimation.sessions import JointOptions, Session, solve_sessions  # noqa: E402

BOARD = Board(6, 8, 0.075)
DOC = ROOT / "docs" / "bench_joint.md"
T_PANO = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.03, -0.05, 0.07), np.array([0.05, -0.03, -0.25]))
R_CV = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
T_PIN = gtsam.Pose3(gtsam.Rot3(R_CV), -R_CV @ np.array([0.05, -0.03, 0.2]))


def simulator_check(n_frames: int, offset: float = 0.03) -> str:
    from ilcc_graph.lidar import estimate_board
    from ilcc_graph.simulate import Systematics, board_placements, frame_scene, simulate_scan, standard_spec

    rows = [
        f"Range offset {1e3 * offset:.0f} mm; noise-free scans of the simulator's default board placements "
        "(standard_spec, seed 4); columns: the board pose change the LiDAR stage reports, and its part "
        "the model does not explain (rotation mrad, translation mm; rx ry rz / tx ty tz in the board frame, "
        "z the normal).",
        "",
        "| LiDAR | frame | fitted change rot (mrad) | fitted change trans (mm) | model error rot (mrad) "
        "| model error trans (mm) | stage sigma rot (mrad) | stage sigma trans (mm) |",
        "|---|---:|---|---|---|---|---|---|",
    ]
    for lidar in ("hdl32", "vlp16"):
        spec0 = standard_spec(
            lidar=lidar, frames=n_frames, seed=4, noise_scale=0.0, systematics=Systematics.off()
        )
        spec1 = spec0.with_(systematics=Systematics(0.0, 0.0, 0.0, 0.0, offset))
        S = board_face_samples(spec0.board)
        H = gtsam.Pose3(spec0.board.T_half_turn())
        for i, T in enumerate(board_placements(spec0)):
            scene = frame_scene(spec0, T, i)
            try:
                f0 = estimate_board(simulate_scan(spec0, scene, i), spec0.board, spec0.lidar_model)
                f1 = estimate_board(simulate_scan(spec1, scene, i), spec0.board, spec0.lidar_model)
            except CalibrationError as err:
                rows.append(f"| {lidar} | {i + 1} | board not found: {err} | | | | | |")
                continue
            T0, T1 = gtsam.Pose3(f0.T_lidar_board), gtsam.Pose3(f1.T_lidar_board)
            obs = min(
                (T0.localCoordinates(c) for c in (T1, T1.compose(H), T1.compose(H.inverse()))),
                key=lambda x: float(np.linalg.norm(x)),
            )
            err = obs - T0.localCoordinates(shifted_board_pose(T0, offset, S))
            sig = np.sqrt(np.diag(f1.covariance))

            def fmt(v: np.ndarray) -> str:
                return " ".join(f"{1e3 * x:+.2f}" for x in v)

            rows.append(
                f"| {lidar} | {i + 1} | {fmt(obs[:3])} | {fmt(obs[3:])} | {fmt(err[:3])} | {fmt(err[3:])} "
                f"| {fmt(sig[:3]).replace('+', '')} | {fmt(sig[3:]).replace('+', '')} |"
            )
            print(rows[-1], flush=True)
    return "\n".join(rows)


def monte_carlo(runs: int, n_frames: int) -> str:
    rng = np.random.default_rng(6)
    pano = Equirectangular(8000, 4000)
    cases = [
        ("equirectangular, all around", pano, T_PANO, None, 0.03),
        ("equirectangular, all around", pano, T_PANO, None, 0.0),
        ("pinhole 110 deg, in front", pinhole(), T_PIN, np.array([1.0, 0.0, 0.0]), 0.03),
    ]
    rows = [
        f"{runs} runs per row, {n_frames} frames each; b true offset; z = (b_est - b) / sigma_b. 'inside' is "
        "the fraction with |z| < 3 (target >= 95 %). NEES of T_cam_lidar (6 expected) with the offset "
        "estimated and with it ignored (plain graph, no chi-square gate).",
        "",
        "| camera, boards | b (mm) | mean b_est (mm) | mean sigma_b (mm) | mean z | std z | inside 3 sigma "
        "| NEES, offset estimated | NEES, offset ignored |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for label, cam, T, towards, b in cases:
        z, est, sig, n_with, n_without = [], [], [], [], []
        for _ in range(runs):
            frames, _ = session_frames(rng, n_frames, cam, T, BOARD, range_offset_m=b, towards=towards)
            sess = [Session("S", frames, cam, board=BOARD)]
            sol = solve_sessions(sess, JointOptions(range_offset=True))
            ro = sol.range_offsets["lidar"]
            z.append((ro.value_m - b) / ro.sigma_m)
            est.append(ro.value_m)
            sig.append(ro.sigma_m)
            xi = sol.joint.pose.localCoordinates(T)
            n_with.append(xi @ np.linalg.solve(sol.joint.covariance, xi))
            plain = solve_sessions(sess, JointOptions(noise=NoiseOptions(chi2_gate_prob=None)))
            xi = plain.joint.pose.localCoordinates(T)
            n_without.append(xi @ np.linalg.solve(plain.joint.covariance, xi))
        z = np.array(z)
        rows.append(
            f"| {label} | {1e3 * b:.0f} | {1e3 * np.mean(est):.2f} | {1e3 * np.mean(sig):.2f} "
            f"| {z.mean():+.2f} | {z.std():.2f} | {100 * np.mean(np.abs(z) < 3):.0f} % "
            f"| {np.mean(n_with):.1f} | {np.mean(n_without):.1f} |"
        )
        print(rows[-1], flush=True)
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--sim-frames", type=int, default=8)
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    t2 = monte_carlo(args.runs, args.frames)
    t1 = simulator_check(args.sim_frames) if args.sim_frames > 0 else ""
    table = t1 + "\n\n" + t2 if t1 else t2
    print(table)
    if args.write:
        write_section(DOC, "range-offset", table)
        print(f"wrote {DOC}")


if __name__ == "__main__":
    main()
