"""The recorded data sets (../shared/data): what the tool makes of each, with the config as written.

For every set present and every variant (the default, which chooses the sensor model per run; no
sensor terms; one range offset; the camera's intrinsics refined; the LiDAR's own errors estimated;
both) it prints and writes to docs/bench_real.md:

- frames used of the frames given, and why the others were left out;
- the extrinsic (as the camera's position in the LiDAR frame, mm) with its 1-sigma;
- the LiDAR's own corners (its intensity fit, not the graph's refined boards) projected into the
  images with the estimate: RMS distance (px) to the nearest detected corner over the used frames
  (the "LiDAR points on the board's squares" check, as a number);
- two disjoint halves of the frames (odd / even positions), each calibrated on its own: the
  Mahalanobis distance squared of their difference under the sum of their covariances (chi-square
  with 6 dof when the covariances are honest: 95 % below 12.59);
- for the Ouster sets, the difference to ACFR's own result (``acfr_reference/``: the mean of their
  per-sample estimates after dropping |z| >= 2, as their assessment does).

    python scripts/bench_real.py [--data ../shared/data] [--out docs/bench_real.md]
"""

from __future__ import annotations

import argparse
import csv
import logging
import time
from dataclasses import replace
from pathlib import Path

import gtsam
import numpy as np
from scipy.stats import chi2

from ilcc_graph.datasets import open_source
from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.io import atomic_write
from ilcc_graph.run.observe import Observation, observe
from ilcc_graph.run.pipeline import solve_observations
from ilcc_graph.run.result import RunOptions
from ilcc_graph.run.stages import StageOptions
from ilcc_graph.types import Calibration

SETS = ("acfr-vlp16-fisheye", "acfr-os1-fisheye", "acfr-os1-pinhole")
VARIANTS = {
    "default (the model chosen per run)": RunOptions(),
    "none (`--sensor-model none`)": RunOptions(sensor_model="none"),
    "range (`--sensor-model range`)": RunOptions(sensor_model="range"),
    "refine intrinsics": RunOptions(sensor_model="none", intrinsics=IntrinsicsOptions(refine=True)),
    "LiDAR errors (`--lidar-errors`)": RunOptions(lidar_errors=LidarErrorOptions()),
    "both": RunOptions(lidar_errors=LidarErrorOptions(), intrinsics=IntrinsicsOptions(refine=True)),
}


def acfr_reference(folder: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """ACFR's T_lidar_cam (4, 4) (column means of their estimates after dropping |z| >= 2) and the
    standard deviation of their rows' translations (3,), or None."""
    files = sorted((folder / "acfr_reference").glob("calibration_*.csv"))
    if not files:
        return None
    with files[0].open() as fh:
        rows = np.array([[float(v) for v in r.values()] for r in csv.DictReader(fh)])
    mean = []
    for col in rows.T:
        z = (col - col.mean()) / col.std() if col.std() > 0 else np.zeros_like(col)
        mean.append(col[np.abs(z) < 2].mean())
    roll, pitch, yaw, x, y, z = mean
    T = np.eye(4)
    T[:3, :3] = gtsam.Rot3.Ypr(yaw, pitch, roll).matrix()  # R = Rz(yaw) Ry(pitch) Rx(roll)
    T[:3, 3] = [x, y, z]
    return T, rows[:, 3:].std(axis=0, ddof=1)


def corner_rms_px(cal: Calibration, obs: Observation) -> float:
    """RMS pixel distance from the LiDAR's corners, projected with the estimate, to the nearest
    detected image corner, over the used frames (order-free)."""
    cam = obs.config.camera
    intr = cal.sensors.get("camera_intrinsics")
    if intr is not None:
        cam = cam.with_intrinsics(np.asarray(intr["values"], dtype=np.float64))
    R, t = cal.T_cam_lidar[:3, :3], cal.T_cam_lidar[:3, 3]
    d2 = []
    for f in cal.frames:
        if not f.used or f.board is None or f.corners is None:
            continue
        uv = cam.project(f.board.corners_lidar @ R.T + t)
        dist = np.linalg.norm(uv[:, None, :] - f.corners.uv[None, :, :], axis=2).min(axis=1)
        d2.append(dist**2)
    return float(np.sqrt(np.mean(np.concatenate(d2)))) if d2 else float("nan")


def halves(obs: Observation, options: RunOptions) -> tuple[float, str]:
    """Mahalanobis distance squared of the odd and even halves' estimates, and a note."""
    parts = [replace(obs, frames=obs.frames[0::2]), replace(obs, frames=obs.frames[1::2])]
    est = []
    for p in parts:
        try:
            est.append(solve_observations([p], replace(options, second_pass=False)).calibration)
        except (CalibrationImpossible, IndeterminateSystem) as e:
            return float("nan"), f"a half cannot calibrate: {e}"
    a, b = est
    D = gtsam.Pose3(a.T_cam_lidar).between(gtsam.Pose3(b.T_cam_lidar))
    d = np.asarray(gtsam.Pose3.Logmap(D))
    Ad = D.inverse().AdjointMap()  # b's covariance carried into a's tangent
    C = a.covariance + Ad @ b.covariance @ Ad.T
    m2 = float(d @ np.linalg.solve(C, d))
    used = [sum(f.used for f in c.frames) for c in est]
    return m2, f"{used[0]} + {used[1]} frames, p = {chi2.sf(m2, 6):.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "bench_real.md"))
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR, format="%(levelname)s: %(message)s")
    root = Path(args.data)
    lines = [
        "# The recorded data sets",
        "",
        f"`python scripts/bench_real.py` ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}); "
        "configs as the sets ship them. Camera position = translation of T_lidar_cam (mm). "
        "Corner RMS: the LiDAR's own corners projected with the estimate against the image corners. "
        "Halves: Mahalanobis distance squared of two disjoint halves (chi-square 6 dof; 95 % below "
        "12.59).",
        "",
    ]
    for name in SETS:
        folder = root / name
        if not (folder / "config.yaml").is_file():
            print(f"{name}: not present under {root}, skipped")
            continue
        t0 = time.perf_counter()
        obs = observe(open_source(folder), StageOptions(jobs=args.jobs))
        t_obs = time.perf_counter() - t0
        acfr = acfr_reference(folder)
        ref = None if acfr is None else acfr[0]
        lines += [f"## {name}", "", f"Observation (LiDAR and image stages): {t_obs:.1f} s.", ""]
        if acfr is not None:
            lines += [
                "ACFR's result (camera in LiDAR frame, mm): "
                + ", ".join(f"{1e3 * v:.1f}" for v in ref[:3, 3])  # type: ignore[index]
                + "; the spread (std) of their own estimates: "
                + ", ".join(f"{1e3 * v:.1f}" for v in acfr[1])
                + ".",
                "",
            ]
        head = (
            "| variant | used | camera in LiDAR frame x, y, z mm (1-sigma) | rot. sigma deg "
            "| corner RMS px | halves | solve s |"
        )
        if ref is not None:
            head += " vs ACFR: rot deg, trans mm |"
        lines += [head, "|" + "---|" * (head.count("|") - 1)]
        notes: list[str] = []
        for vname, options in VARIANTS.items():
            t1 = time.perf_counter()
            try:
                cal = solve_observations([obs], options).calibration
            except (CalibrationImpossible, IndeterminateSystem) as e:
                lines.append(
                    f"| {vname} | - | cannot calibrate (exit 3, below) |" + " |" * (head.count("|") - 4)
                )
                if f"- {e}" not in notes:
                    notes.append(f"- {e}")
                continue
            t_solve = time.perf_counter() - t1
            T_lc = np.linalg.inv(cal.T_cam_lidar)
            # the camera's position in the LiDAR frame and its sigma (first order through the inverse)
            J = -gtsam.Pose3(cal.T_cam_lidar).inverse().AdjointMap()
            C_lc = J @ cal.covariance @ J.T
            s_pos = np.sqrt(np.diag(T_lc[:3, :3] @ C_lc[3:, 3:] @ T_lc[:3, :3].T))
            s_rot = np.degrees(np.sqrt(np.diag(cal.covariance[:3, :3])))
            used = sum(f.used for f in cal.frames)
            m2, hnote = halves(obs, options)
            model = cal.sensors.get("model", {})
            if model and not model.get("forced"):
                cam = model.get("camera") or {}
                vname_shown = f"{vname}: {model['chosen']}" + (
                    ", intrinsics refined" if cam.get("refined") else ""
                )
            else:
                vname_shown = vname
            row = (
                f"| {vname_shown} | {used}/{len(cal.frames)} | "
                + ", ".join(f"{1e3 * v:.1f} ({1e3 * s:.1f})" for v, s in zip(T_lc[:3, 3], s_pos))
                + f" | {', '.join(f'{v:.3f}' for v in s_rot)} | {corner_rms_px(cal, obs):.2f} | "
                f"{m2:.1f} ({hnote}) | {t_solve:.1f} |"
            )
            if ref is not None:
                D = gtsam.Pose3(ref).between(gtsam.Pose3(T_lc))
                rot = np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(D.rotation())))
                row += f" {rot:.3f}, {1e3 * np.linalg.norm(T_lc[:3, 3] - ref[:3, 3]):.1f} |"
            lines.append(row)
            print(row, flush=True)
            for f in cal.frames:
                if not f.used:
                    notes.append(f"- {vname}: {f.name}: {f.reason}")
        lines += ["", "Frames left out, or why the set cannot calibrate:", "", *(notes or ["- none"]), ""]
    text = "\n".join(lines) + "\n"
    print(text)
    atomic_write(Path(args.out), text)


if __name__ == "__main__":
    main()
