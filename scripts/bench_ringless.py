"""Benchmark: the LiDAR stage on scanline-free (Livox-like) scans, and Open3D against numpy/scipy.

1. The stage (``lidar/ringless.py`` then the intensity fit) on simulated Mid-70 and Mid-40 scans,
   integration 0.1-1.0 s, the simulator's room (walls, floor, stand, a person beside the board
   60 % of the time), systematics off: boards found, corner RMS error, board-pose NEES (6 dof,
   mean; chi2(6) mean is 6) and the per-component z-score RMS, time per scan.
2. The search with Open3D's ``segment_plane`` (RANSAC) and/or ``cluster_dbscan`` plugged in instead
   of ours (``ransac_plane``, numpy; the range-scaled links, scipy cKDTree + csgraph), same scans:
   boards found, time; and plane segmentation alone (the largest plane of each scan).
3. Calibration (``pipeline.run``, the simulated config.yaml: ``lidar: model: livox-mid70``),
   Mid-70 0.5 s, 6 frames of a 640 x 400 pinhole, several seeds: extrinsic NEES with systematics
   off, and with the simulator's default systematics (one laser: its 3 mm range bias is common to
   every return) without and with the LiDAR's own error terms (``--lidar-errors``).

Only scans are simulated in 1 and 2 (no images). Prints markdown tables and writes
docs/lidar_ringless.md (the readers' comparison is in scripts/bench_io.py, docs/io_benchmark.md).

    nice python3 scripts/bench_ringless.py            # full (~10 min on the shared 2-core machine)
    nice python3 scripts/bench_ringless.py --quick    # smoke run
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import gtsam
import numpy as np
import yaml

from ilcc_graph.errors import BoardNotFound
from ilcc_graph.lidar import estimate_board
from ilcc_graph.lidar import pattern as P
from ilcc_graph.lidar import ringless as R
from ilcc_graph.lidar.detection import ransac_plane
from ilcc_graph.simulate import SimulationSpec, Systematics, default_camera, frame_scene, simulate_scan
from ilcc_graph.simulate.placements import board_placements

DOCS = Path(__file__).resolve().parents[1] / "docs"
CHI2_6_99 = 16.81


def _spec(name: str, T: float, frames: int, seed: int, **kw) -> SimulationSpec:
    return SimulationSpec(lidar=name, camera=default_camera("pinhole", 640), n_frames=frames, seed=seed,
                          integration_time_s=T, **kw)  # fmt: skip


def _scans(spec: SimulationSpec) -> list[tuple]:
    return [
        (simulate_scan(spec, frame_scene(spec, T, i), i), T) for i, T in enumerate(board_placements(spec))
    ]


def _board_error(fit, T: np.ndarray, spec: SimulationSpec) -> tuple[float, float, np.ndarray]:
    """(corner RMS m, NEES, z-scores (6,)) against the truth or its half-turn twin, whichever is nearer."""
    board = spec.board
    best = None
    for Tt in (T, T @ board.T_half_turn()):
        xi = gtsam.Pose3.Logmap(gtsam.Pose3(fit.T_lidar_board).between(gtsam.Pose3(Tt)))
        nees = float(xi @ np.linalg.solve(fit.covariance, xi))
        if best is None or nees < best[1]:
            truth = board.corners_board() @ Tt[:3, :3].T + Tt[:3, 3]
            rms = float(np.sqrt(((fit.corners_lidar - truth) ** 2).sum(axis=1).mean()))
            best = (rms, nees, xi / np.sqrt(np.diag(fit.covariance)))
    return best


def stage_table(frames: int, times: tuple[float, ...]) -> str:
    out = ("| lidar | integration s | returns | found | corner RMS mm (median / max) | board NEES mean | "
           "z-score RMS rx ry rz tx ty tz | board returns (median) | s per scan (median) |\n"
           "|---|---:|---:|---|---|---:|---|---:|---:|\n")  # fmt: skip
    for name in ("livox-mid70", "livox-mid40"):
        for T in times:
            spec = _spec(name, T, frames, 0, systematics=Systematics.off())
            rows, secs, n_ret, n_board = [], [], [], []
            for scan, Tb in _scans(spec):
                n_ret.append(len(scan))
                t0 = time.perf_counter()
                try:
                    fit = estimate_board(scan, spec.board, spec.lidar_model)
                except BoardNotFound:
                    continue
                finally:
                    secs.append(time.perf_counter() - t0)
                rows.append(_board_error(fit, Tb, spec))
                n_board.append(fit.diagnostics["n_points"])
            if rows:
                rms = np.array([r[0] for r in rows]) * 1e3
                nees = np.array([r[1] for r in rows])
                z = np.sqrt((np.array([r[2] for r in rows]) ** 2).mean(axis=0))
                cells = (f"{np.median(rms):.2f} / {rms.max():.2f} | {nees.mean():.1f} | "
                         f"{' '.join(f'{v:.2f}' for v in z)} | {np.median(n_board):.0f}")  # fmt: skip
            else:
                cells = "- | - | - | -"
            out += (f"| {name} | {T:.1f} | {np.median(n_ret):.0f} | {len(rows)}/{frames} | {cells} | "
                    f"{np.median(secs):.2f} |\n")  # fmt: skip
            print(out.splitlines()[-1], flush=True)
    return out


def checks_table(frames: int) -> str:
    """Two design checks on the same scans as table 1: elevation bands against one band for the
    fit's covariance, and the ray projection against the orthogonal one at a dense Mid-40."""
    import ilcc_graph.lidar as lidar_pkg
    from ilcc_graph.lidar import LidarOptions

    out = ("| variant | lidar, integration | found | board NEES mean | z-score RMS rx ry rz tx ty tz |\n"
           "|---|---|---|---:|---|\n")  # fmt: skip
    one_band = lambda p: np.zeros(len(p), np.int64)  # noqa: E731
    cases = [
        ("elevation bands (the stage)", "livox-mid70", 0.5, P.pseudo_rings, LidarOptions()),
        ("one band for every return", "livox-mid70", 0.5, one_band, LidarOptions()),
        ("ray projection (the stage)", "livox-mid40", 1.0, P.pseudo_rings, LidarOptions()),
        ("orthogonal projection", "livox-mid40", 1.0, P.pseudo_rings, LidarOptions(projection="normal")),
    ]
    for label, name, T, rings, opts in cases:
        spec = _spec(name, T, frames, 0, systematics=Systematics.off())
        lidar_pkg.pseudo_rings = rings
        rows = []
        for scan, Tb in _scans(spec):
            try:
                fit = estimate_board(scan, spec.board, spec.lidar_model, options=opts)
                rows.append(_board_error(fit, Tb, spec))
            except BoardNotFound:
                pass
        lidar_pkg.pseudo_rings = P.pseudo_rings
        z = np.sqrt((np.array([r[2] for r in rows]) ** 2).mean(axis=0))
        nees = np.mean([r[1] for r in rows])
        out += (f"| {label} | {name}, {T:.1f} s | {len(rows)}/{frames} | {nees:.1f} | "
                f"{' '.join(f'{v:.2f}' for v in z)} |\n")  # fmt: skip
        print(out.splitlines()[-1], flush=True)
    return out


def _o3d_plane(p: np.ndarray, threshold: float, rng: np.random.Generator):  # noqa: ANN202
    """Open3D's RANSAC plane with our hypothesis count (96), as (normal, offset, inliers)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    (a, b, c, d), inl = pc.segment_plane(threshold, 3, 96)
    n = np.array([a, b, c]) / np.linalg.norm([a, b, c])
    mask = np.zeros(p.shape[0], bool)
    mask[np.asarray(inl, np.int64)] = True
    return n, float(-d / np.linalg.norm([a, b, c])), mask


def _o3d_dbscan(p: np.ndarray, u: np.ndarray, delta: np.ndarray, jump: float, allow: float) -> np.ndarray:
    """Open3D's DBSCAN with one radius: the link limit at the returns' median range and spacing."""
    import open3d as o3d

    eps = jump * float(np.median(np.linalg.norm(p, axis=1))) * float(np.median(delta)) + allow
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    return np.asarray(pc.cluster_dbscan(eps, 3, print_progress=False))


def backends_table(frames: int) -> str:
    import open3d as o3d

    o3d.utility.random.seed(0)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    cases = {
        "numpy RANSAC + scipy links (ours)": (ransac_plane, P.link_components),
        "Open3D segment_plane + scipy links": (_o3d_plane, P.link_components),
        "numpy RANSAC + Open3D cluster_dbscan": (ransac_plane, _o3d_dbscan),
        "Open3D segment_plane + cluster_dbscan": (_o3d_plane, _o3d_dbscan),
    }
    out = ("| search | lidar, integration | found | corner RMS mm (median) | s per scan (median) |\n"
           "|---|---|---|---:|---:|\n")  # fmt: skip
    sets = [("livox-mid70", 0.5), ("livox-mid40", 0.5), ("livox-mid70", 0.2)]
    scans = {k: _scans(_spec(*k, frames, 1, systematics=Systematics.off())) for k in sets}
    import ilcc_graph.lidar as lidar_pkg

    for label, (plane_fn, cluster_fn) in cases.items():

        def find(*a, plane_fn=plane_fn, cluster_fn=cluster_fn, **k):  # noqa: ANN002, ANN003, ANN202
            return R.find_ringless_candidates(*a, plane_fn=plane_fn, cluster_fn=cluster_fn, **k)

        lidar_pkg.find_ringless_candidates = find
        for (name, T), items in scans.items():
            spec = _spec(name, T, frames, 1)
            found, rms, secs = 0, [], []
            for scan, Tb in items:
                t0 = time.perf_counter()
                try:
                    fit = estimate_board(scan, spec.board, spec.lidar_model)
                    found += 1
                    rms.append(_board_error(fit, Tb, spec)[0] * 1e3)
                except BoardNotFound:
                    pass
                secs.append(time.perf_counter() - t0)
            med = f"{np.median(rms):.2f}" if rms else "-"
            out += f"| {label} | {name}, {T:.1f} s | {found}/{len(items)} | {med} | {np.median(secs):.2f} |\n"
            print(out.splitlines()[-1], flush=True)
    lidar_pkg.find_ringless_candidates = R.find_ringless_candidates
    return out


def planes_table(frames: int) -> str:
    """The largest plane of whole scans: numpy RANSAC against Open3D's, time and agreement."""
    import open3d as o3d

    o3d.utility.random.seed(0)
    out = ("| scan | returns | numpy ms | Open3D ms | numpy inliers | Open3D inliers | "
           "angle between planes deg |\n|---|---:|---:|---:|---:|---:|---:|\n")  # fmt: skip
    rng = np.random.default_rng(0)
    for name, T in (("livox-mid70", 0.5), ("livox-mid70", 1.0), ("livox-mid40", 0.5)):
        items = _scans(_spec(name, T, min(frames, 5), 2, systematics=Systematics.off()))
        t_np, t_o3, n_np, n_o3, ang = [], [], [], [], []
        for scan, _ in items:
            p = scan.points
            t0 = time.perf_counter()
            a = ransac_plane(p, 0.03, rng)
            t1 = time.perf_counter()
            b = _o3d_plane(p, 0.03, rng)
            t2 = time.perf_counter()
            t_np.append(t1 - t0)
            t_o3.append(t2 - t1)
            n_np.append(a[2].sum())
            n_o3.append(b[2].sum())
            ang.append(np.degrees(np.arccos(min(1.0, abs(float(a[0] @ b[0]))))))
        out += (f"| {name} {T:.1f} s | {len(items[0][0])} | {1e3 * np.median(t_np):.0f} | "
                f"{1e3 * np.median(t_o3):.0f} | {np.median(n_np):.0f} | {np.median(n_o3):.0f} | "
                f"{np.median(ang):.2f} |\n")  # fmt: skip
        print(out.splitlines()[-1], flush=True)
    return out


def calibration_table(seeds: int) -> str:
    from ilcc_graph.datasets import FolderSource
    from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
    from ilcc_graph.run.observe import observe
    from ilcc_graph.run.pipeline import solve_observations
    from ilcc_graph.run.result import RunOptions
    from ilcc_graph.simulate import simulate_dataset

    rows: dict[str, list[tuple[float, int]]] = {"systematics off": [], "systematics on": [],
                                                "systematics on, --lidar-errors": []}  # fmt: skip
    t_run = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(seeds):
            for syst in ("off", "on"):
                kw = {"systematics": Systematics.off()} if syst == "off" else {}
                data = simulate_dataset(Path(tmp) / f"{syst}{seed}", _spec("livox-mid70", 0.5, 6, seed, **kw))
                truth = np.array(yaml.safe_load((data / "ground_truth.yaml").read_text())["T_cam_lidar"])
                t0 = time.perf_counter()
                obs = observe(FolderSource(data))
                variants = [("", RunOptions())]
                if syst == "on":
                    variants.append((", --lidar-errors", RunOptions(lidar_errors=LidarErrorOptions())))
                for suffix, opts in variants:
                    cal = solve_observations([obs], opts).calibration
                    xi = gtsam.Pose3.Logmap(gtsam.Pose3(cal.T_cam_lidar).between(gtsam.Pose3(truth)))
                    rows[f"systematics {syst}{suffix}"].append(
                        (float(xi @ np.linalg.solve(cal.covariance, xi)), sum(f.used for f in cal.frames))
                    )
                t_run.append(time.perf_counter() - t0)
    out = ("| case | seeds | frames used (of 6) | NEES mean | NEES median | NEES max | above chi2(6) 99 % |\n"
           "|---|---:|---|---:|---:|---:|---:|\n")  # fmt: skip
    for case, vals in rows.items():
        n = np.array([v[0] for v in vals])
        used = sorted({v[1] for v in vals})
        out += (f"| {case} | {len(vals)} | {', '.join(map(str, used))} | {n.mean():.1f} | "
                f"{np.median(n):.1f} | {n.max():.1f} | {(n > CHI2_6_99).sum()} |\n")  # fmt: skip
    out += f"\nObserve + solve per set: {np.median(t_run):.1f} s (median).\n"
    print(out, flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="few frames and seeds (smoke run)")
    args = ap.parse_args()
    frames, seeds = (4, 2) if args.quick else (20, 10)
    times = (0.5,) if args.quick else (0.1, 0.2, 0.3, 0.5, 1.0)
    t0 = time.time()
    stage = stage_table(frames, times)
    checks = checks_table(frames)
    backends = backends_table(frames)
    planes = planes_table(frames)
    calib = calibration_table(seeds)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    text = (
        "# Scanline-free LiDARs (Livox-like): the stage, Open3D against numpy/scipy, calibration\n\n"
        f"`python3 scripts/bench_ringless.py{' --quick' if args.quick else ''}`, {time.time() - t0:.0f} s on "
        f"the shared 2-core machine (load average {load} at the end: wall times vary up to 2x between runs). "
        "Simulated with `ilcc_graph.simulate` (rosette of simulate/rosette.py, 100,000 returns/s, "
        "reflectivity 0-255, no ring field); pinhole camera 640 x 400 for the placements; "
        f"{frames} frames per row in 1 and 2. See docs/lidar_ringless.md's text above the tables for how "
        "to read them.\n\n"
        "## 1. The stage against the integration time (systematics off)\n\n"
        "z-scores: the board pose's error over its stated sigma, per Pose3 component (board frame: "
        "rx ry tz out of the plane, rz tx ty in it); 1 is honest.\n\n" + stage + "\n"
        "Two checks on the same scans: the fit's covariance grouping returns by elevation bands one "
        "spacing high against one band for all; the ray projection against the orthogonal one (the "
        "simulator puts the board's noise along its normal).\n\n" + checks + "\n"
        "## 2. Open3D plugged into the search (same scans, seed 1)\n\n" + backends + "\n"
        "Plane segmentation alone: the largest plane of whole scans (threshold 3 cm, 96 hypotheses "
        "each; numpy: ``detection.ransac_plane``, scored on at most 1500 returns and refined by least "
        "squares; Open3D: ``segment_plane``), medians.\n\n" + planes + "\n"
        f"## 3. Calibration, Mid-70 0.5 s, 6 frames, {seeds} seeds\n\n" + calib
    )
    start = "<!-- bench_ringless: generated below, do not edit -->"
    doc = DOCS / "lidar_ringless.md"
    head = doc.read_text().split(start)[0] if doc.exists() else ""
    doc.write_text(head + start + "\n\n" + text)
    print(f"wrote {doc}")


if __name__ == "__main__":
    main()
