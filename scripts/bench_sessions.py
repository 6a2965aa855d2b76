"""Benchmark of joint sessions (estimation.sessions): joint vs alone, detection of a moved mount.

Graph-level synthetic sessions (tests/synthetic_graph.py): an 8000x4000 equirectangular camera, a 6x8
board of 75 mm 1.5-5 m around the LiDAR, 0.5 px corner noise (random anisotropic covariance per
corner), board-pose priors with sigmas ~(2, 2, 1) mrad / (3, 3, 2) mm drawn from their covariances.
The three sessions of a run share the rig, not the board placements.

Run: ``nice python3 scripts/bench_sessions.py [--runs 100] [--write]`` (``--write``: tables into
docs/bench_joint.md between markers). ``--pipeline DIR`` instead runs one end-to-end example: three
simulated data sets (``ilcc_graph.simulate``, pinhole camera, C with a moved mount) written to DIR and
calibrated from disk with ``run.observe.observe`` and ``run.pipeline.solve_observations`` (real stages).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import gtsam
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "scripts"))

from bench_customfactor import write_section  # noqa: E402
from synthetic_graph import session_frames  # noqa: E402

from ilcc_graph.board import Board  # noqa: E402
from ilcc_graph.cameras import Equirectangular  # noqa: E402
from ilcc_graph.estimation import NoiseOptions  # noqa: E402
from ilcc_graph.estimation.sessions import JointOptions, Session, solve_sessions  # noqa: E402

CAMERA = Equirectangular(8000, 4000)
BOARD = Board(6, 8, 0.075)
T_TRUE = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.03, -0.05, 0.07), np.array([0.05, -0.03, -0.25]))
DOC = ROOT / "docs" / "bench_joint.md"


def sessions(rng: np.random.Generator, n_frames: int, poses: tuple[gtsam.Pose3, ...]) -> list[Session]:
    out = []
    for k, T in enumerate(poses):
        frames, _ = session_frames(rng, n_frames, CAMERA, T, BOARD, prefix=f"s{k}_")
        out.append(Session("ABC"[k], frames, CAMERA, board=BOARD))
    return out


def moved(T: gtsam.Pose3, deg: float, mm: float, rng: np.random.Generator) -> gtsam.Pose3:
    a, t = rng.normal(size=3), rng.normal(size=3)
    xi = np.concatenate([np.radians(deg) * a / np.linalg.norm(a), 1e-3 * mm * t / np.linalg.norm(t)])
    return T.compose(gtsam.Pose3.Expmap(xi))


def nees(T_est: gtsam.Pose3, cov: np.ndarray, T: gtsam.Pose3) -> float:
    xi = T_est.localCoordinates(T)
    return float(xi @ np.linalg.solve(cov, xi))


def joint_vs_alone(runs: int, n_frames: int) -> str:
    rng = np.random.default_rng(1)
    ratio, nees_joint, nees_alone, inside_joint = [], [], [], []
    rot_err, tr_err, sig_j, sig_a = [], [], [], []
    for _ in range(runs):
        sol = solve_sessions(sessions(rng, n_frames, (T_TRUE,) * 3), JointOptions(noise=NoiseOptions()))
        j = sol.joint
        ratio.append(np.mean([a.sigmas / j.sigmas for a in sol.alone.values()], axis=0))
        nees_joint.append(nees(j.pose, j.covariance, T_TRUE))
        nees_alone += [nees(a.pose, a.covariance, T_TRUE) for a in sol.alone.values()]
        xi = j.pose.localCoordinates(T_TRUE)
        inside_joint.append(np.abs(xi) < 3 * j.sigmas)
        rot_err.append(np.degrees(np.linalg.norm(xi[:3])))
        tr_err.append(1e3 * np.linalg.norm(xi[3:]))
        sig_j.append(j.sigmas)
        sig_a.append(np.mean([a.sigmas for a in sol.alone.values()], axis=0))
    ratio, inside = np.array(ratio), np.array(inside_joint)
    sj, sa = np.mean(sig_j, axis=0), np.mean(sig_a, axis=0)
    axes = ("rx", "ry", "rz", "tx", "ty", "tz")
    rows = [
        f"{runs} runs, 3 sessions x {n_frames} frames, rigid mode.",
        "",
        "| axis | mean sigma alone | mean sigma joint | mean sigma alone / joint (sqrt(3) = 1.73) "
        "| joint error within 3 sigma |",
        "|---|---:|---:|---:|---:|",
    ]
    for i, a in enumerate(axes):
        unit, scale = ("deg", np.degrees(1.0)) if i < 3 else ("mm", 1e3)
        rows.append(
            f"| {a} | {scale * sa[i]:.4f} {unit} | {scale * sj[i]:.4f} {unit} | {ratio[:, i].mean():.3f} "
            f"| {100 * inside[:, i].mean():.0f} % |"
        )
    rows += [
        "",
        f"Joint error: rotation {np.mean(rot_err):.4f} deg mean ({np.max(rot_err):.4f} max), translation "
        f"{np.mean(tr_err):.2f} mm mean ({np.max(tr_err):.2f} max). Mean NEES (6 expected): joint "
        f"{np.mean(nees_joint):.2f}, sessions alone {np.mean(nees_alone):.2f}.",
    ]
    return "\n".join(rows)


def detection(runs: int, frame_counts: tuple[int, ...], alpha: float) -> str:
    rng = np.random.default_rng(2)
    cases = [
        ("nothing moved", 0.0, 0.0),
        ("0.5 deg and 10 mm", 0.5, 10.0),
        ("0.5 deg only", 0.5, 0.0),
        ("10 mm only", 0.0, 10.0),
        ("0.1 deg and 2 mm", 0.1, 2.0),
    ]
    rows = [
        f"Global test at alpha = {alpha} (6 (S-1) = 12 dof); the mount moves between sessions B and C "
        "(C differs). 'located' = the session named as moved is C. "
        f"{2 * runs} runs for 'nothing moved', {runs} per other cell.",
        "",
        "| frames per session | case | alarms (global test) | located C | pair test B -> C fires "
        "| pair A -> B fires | median p-value | s per run |",
        "|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for n in frame_counts:
        for label, deg, mm in cases:
            alarms = located = bc = ab = 0
            pvals, t_run = [], []
            n_runs = 2 * runs if deg == 0 and mm == 0 else runs
            for _ in range(n_runs):
                T_c = T_TRUE if deg == 0 and mm == 0 else moved(T_TRUE, deg, mm, rng)
                ss = sessions(rng, n, (T_TRUE, T_TRUE, T_c))
                t0 = time.perf_counter()
                sol = solve_sessions(ss, JointOptions(alpha=alpha))
                t_run.append(time.perf_counter() - t0)
                alarms += sol.global_test.moved
                located += sol.moved == "C"
                ab += sol.pair_tests[0].moved
                bc += sol.pair_tests[1].moved
                pvals.append(sol.global_test.p_value)
            rows.append(
                f"| {n} | {label} | {100 * alarms / n_runs:.1f} % | {100 * located / n_runs:.1f} % "
                f"| {100 * bc / n_runs:.1f} % | {100 * ab / n_runs:.1f} % | {np.median(pvals):.2g} "
                f"| {np.median(t_run):.2f} |"
            )
            print(rows[-1], flush=True)
    return "\n".join(rows)


def pipeline_example(out_dir: Path, n_frames: int) -> str:
    """Three simulated data sets through the whole pipeline; one run, not a Monte Carlo."""
    from scipy.spatial.transform import Rotation

    from ilcc_graph.datasets import FolderSource
    from ilcc_graph.report.text import format_joint
    from ilcc_graph.run.observe import observe
    from ilcc_graph.run.pipeline import solve_observations
    from ilcc_graph.run.result import RunOptions
    from ilcc_graph.simulate import simulate_dataset, standard_spec
    from ilcc_graph.simulate.spec import default_T_cam_lidar

    T0 = default_T_cam_lidar("pinhole")
    D = np.eye(4)
    D[:3, :3] = Rotation.from_rotvec(np.radians([0.3, -0.3, 0.2])).as_matrix()
    D[:3, 3] = [0.006, -0.005, 0.005]
    truth = {"A": T0, "B": T0, "C": D @ T0}
    dirs = []
    for seed, (name, T) in enumerate(truth.items(), start=1):
        d = out_dir / name
        if not (d / "config.yaml").exists():
            simulate_dataset(d, standard_spec(camera="pinhole", frames=n_frames, seed=seed, T_cam_lidar=T))
        dirs.append(d)
    t0 = time.perf_counter()
    observations = [observe(FolderSource(d)) for d in dirs]
    res = solve_observations(observations, names=list(truth))
    seconds = time.perf_counter() - t0
    jump = gtsam.Pose3(T0).localCoordinates(gtsam.Pose3(truth["C"]))
    lines = [
        f"One run: three simulated pinhole data sets of {n_frames} frames (standard_spec, seeds 1-3); "
        f"the mount of C is moved by {np.degrees(np.linalg.norm(jump[:3])):.3f} deg and "
        f"{1e3 * np.linalg.norm(jump[3:]):.1f} mm. Observation + joint solve from disk: {seconds:.0f} s.",
        "",
        "| session | frames used | error (deg) | error (mm) | NEES of its own estimate (6 expected) |",
        "|---|---:|---:|---:|---:|",
    ]
    for s in res.sessions:
        name = s.name
        e = res.documents["joint.yaml"]["alone"][name]
        xi = gtsam.Pose3(e["T_cam_lidar"]).localCoordinates(gtsam.Pose3(truth[name]))
        used = sum(f.used for f in s.calibration.frames)
        lines.append(
            f"| {name} | {used} | {np.degrees(np.linalg.norm(xi[:3])):.3f} "
            f"| {1e3 * np.linalg.norm(xi[3:]):.2f} "
            f"| {xi @ np.linalg.solve(e['covariance'], xi):.1f} |"
        )
    for rep in ((0.0, 0.0), (0.02, 1.0)):
        joint = JointOptions(repeatability_deg=rep[0], repeatability_mm=rep[1])
        opts = RunOptions(joint=joint)
        again = res if rep == (0.0, 0.0) else solve_observations(observations, opts, list(truth))
        sol = again.documents["joint.yaml"]
        lines += [
            "",
            f"`format_joint` with repeatability {rep[0]} deg / {rep[1]} mm:",
            "",
            "```",
            format_joint(sol),
            "```",
        ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--alpha", type=float, default=0.01)
    parser.add_argument("--write", action="store_true")
    parser.add_argument("--pipeline", type=Path, default=None, help="folder for the end-to-end example")
    parser.add_argument("--pipeline-frames", type=int, default=10)
    args = parser.parse_args()
    if args.pipeline is not None:
        text = pipeline_example(args.pipeline, args.pipeline_frames)
        print(text)
        if args.write:
            write_section(DOC, "sessions-pipeline", text)
        return
    t1 = joint_vs_alone(args.runs, args.frames)
    print(t1, flush=True)
    t2 = detection(args.runs, (5, args.frames), args.alpha)
    print(t2)
    if args.write:
        write_section(DOC, "sessions-joint", t1)
        write_section(DOC, "sessions-detection", t2)
        print(f"wrote {DOC}")


if __name__ == "__main__":
    main()
