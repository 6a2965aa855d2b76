"""Benchmark: the demo's data set with PNG or JPEG images: bytes on disk, the calibration's accuracy.

Usage: ``python3 scripts/bench_demo.py [--seeds 0 1 2] [--width 8000] [--work DIR] [--md FILE]``

Per seed the standard panoramic set (HDL-32E, 8000x4000 equirectangular, 20 frames) is simulated
with PNG images (lossless), and the same images are stored again as JPEG at quality 95 (OpenCV's
default, what ``ilcc-graph demo`` writes) and 98; the scans are shared. Each variant is calibrated
(the default run, 2 processes) and compared with the truth: rotation and translation error, NEES,
and how far the image corners moved from the PNG run's. For the first seed the time to write the
results with and without the report is measured beside the calibration's. ``--work`` keeps the
sets between runs (reused when there). Prints a markdown table and writes it to ``--md``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import cv2
import gtsam
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ilcc_graph.app.write import write_run  # noqa: E402
from ilcc_graph.datasets import open_source  # noqa: E402
from ilcc_graph.io import read_ground_truth  # noqa: E402
from ilcc_graph.next_pose import for_run as next_pose_for_run  # noqa: E402
from ilcc_graph.observe import StageOptions  # noqa: E402
from ilcc_graph.pipeline import RunOptions, run  # noqa: E402
from ilcc_graph.simulate import standard_spec  # noqa: E402
from ilcc_graph.simulate.export import simulate_dataset  # noqa: E402


def _megabytes(folder: Path) -> float:
    """Bytes under ``folder`` (links to folders followed: the variants share the PNG set's scans)."""
    walk = os.walk(folder, followlinks=True)
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, files in walk for f in files) / 1e6


def _simulate_times(seed: int, width: int) -> dict[str, tuple[float, float]]:
    """Seconds and MB to simulate the set afresh with PNG and with JPEG images (as the demo does)."""
    got = {}
    for fmt in ("png", "jpg"):
        tmp = Path(tempfile.mkdtemp(prefix="bench_demo_sim_"))
        spec = standard_spec("hdl32", "equirectangular", width, 20, seed)
        t = time.perf_counter()
        simulate_dataset(tmp / "data", spec, image_format=fmt)
        got[fmt] = (time.perf_counter() - t, _megabytes(tmp / "data"))
        shutil.rmtree(tmp, ignore_errors=True)
    return got


def _variant(png: Path, dst: Path, quality: int) -> Path:
    """The PNG set's images as JPEG at ``quality`` (config, truth and scans shared)."""
    if (dst / "ground_truth.yaml").is_file():
        return dst
    tmp = dst.with_name(dst.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "img").mkdir(parents=True)
    for name in ("config.yaml", "ground_truth.yaml"):
        shutil.copy(png / name, tmp / name)
    (tmp / "pcd").symlink_to((png / "pcd").resolve())
    for p in sorted((png / "img").glob("*.png")):
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(tmp / "img" / f"{p.stem}.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    tmp.rename(dst)
    return dst


def _calibrate(data: Path, write: Path | None = None) -> dict:
    """Calibrate ``data``; errors against its truth; with ``write`` the results' writing timed."""
    options = RunOptions(stages=StageOptions(jobs=2))
    t0 = time.perf_counter()
    result = run([open_source(data)], options)
    t1 = time.perf_counter()
    cal = result.calibration
    truth = read_ground_truth(data).T_cam_lidar
    pose, cov = gtsam.Pose3(np.asarray(cal.T_cam_lidar)), np.asarray(cal.covariance)
    xi = gtsam.Pose3.Logmap(pose.between(gtsam.Pose3(truth)))
    row = {
        "rot_deg": float(np.degrees(np.linalg.norm(xi[:3]))),
        "trans_mm": 1e3 * float(np.linalg.norm(np.asarray(cal.T_cam_lidar)[:3, 3] - truth[:3, 3])),
        "nees": float(xi @ np.linalg.solve(cov, xi)),
        "sigma": np.sqrt(np.diag(cov)) * np.r_[np.degrees([1, 1, 1]), 1e3, 1e3, 1e3],
        "uv": {f.name: np.asarray(f.corners.uv) for f in cal.frames if f.corners is not None},
        "calibrate_s": t1 - t0,
    }
    if write is not None:  # as ``calibrate`` writes: the next pose worked out while the report is drawn
        for report in (False, True):
            t = time.perf_counter()
            propose = partial(next_pose_for_run, result, None)
            write_run(
                write / ("report" if report else "bare"),
                result,
                report=report,
                truth=truth,
                next_pose=propose,
            )
            row["write_report_s" if report else "write_bare_s"] = time.perf_counter() - t
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--width", type=int, default=8000)
    ap.add_argument("--work", type=Path, default=None, help="keep the data sets here (default: a temp dir)")
    ap.add_argument("--md", type=Path, default=ROOT / "docs" / "bench_demo.md")
    ap.add_argument("--no-simulate", action="store_true", help="skip timing the simulation in both formats")
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="bench_demo_"))
    work.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()[0]
    rows, timing = [], {}
    sim = {} if args.no_simulate else _simulate_times(args.seeds[0], args.width)
    for seed in args.seeds:
        png = work / f"s{seed}-png"
        if not (png / "ground_truth.yaml").is_file():
            simulate_dataset(png, standard_spec("hdl32", "equirectangular", args.width, 20, seed))
        base = None
        for what, quality in (("PNG", None), ("JPEG q95", 95), ("JPEG q98", 98)):
            data = png if quality is None else _variant(png, work / f"s{seed}-jpg{quality}", quality)
            timed = seed == args.seeds[0] and quality in (None, 95)
            out = Path(tempfile.mkdtemp(prefix="bench_demo_out_")) if timed else None
            r = _calibrate(data, out)
            if out is not None:
                timing[what] = r
                shutil.rmtree(out, ignore_errors=True)
            base = base or r["uv"]
            shift = np.concatenate(
                [np.linalg.norm(r["uv"][k] - base[k], axis=1) for k in base if k in r["uv"]]
            )
            rows.append((seed, what, _megabytes(data / "img"), _megabytes(data), r, shift))
            print(
                rows[-1][:3],
                f"{r['rot_deg']:.4f} deg {r['trans_mm']:.3f} mm NEES {r['nees']:.2f}",
                flush=True,
            )

    lines = [
        "# The demo's data set: PNG or JPEG images",
        "",
        f"`python3 scripts/bench_demo.py --seeds {' '.join(map(str, args.seeds))}`, "
        f"{time.strftime('%Y-%m-%d')}, load average {load0:.1f} at the start on {os.cpu_count()} cores "
        "(shared: the seconds are upper bounds of a quiet machine's). The standard panoramic set "
        f"(HDL-32E, {args.width}x{args.width // 2} equirectangular, 20 frames) simulated with PNG images, "
        "the same images stored again as JPEG (4:2:0); the scans are the same files. "
        "Sizes in MB (images / the whole set); errors against the truth; NEES of the 6-dof error with "
        "the run's covariance (chi-square, 6 dof: 95 % below 12.6); corner shift: how far the image "
        "stage's corners moved from the PNG run's, px (rms / max).",
        "",
        "| seed | images | MB images | MB set | rot error deg | trans error mm | NEES | sigma rot deg (max) "
        "| sigma trans mm (max) | corner shift px |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for seed, what, mb_img, mb_set, r, shift in rows:
        lines.append(
            f"| {seed} | {what} | {mb_img:.0f} | {mb_set:.0f} | {r['rot_deg']:.4f} | {r['trans_mm']:.3f} | "
            f"{r['nees']:.2f} | {r['sigma'][:3].max():.4f} | {r['sigma'][3:].max():.3f} | "
            + ("-" if what == "PNG" else f"{np.sqrt(np.mean(shift**2)):.4f} / {shift.max():.4f}")
            + " |"
        )
    if sim:
        lines += [
            "",
            f"Simulating the set afresh (seed {args.seeds[0]}, `simulate_dataset`, one process): "
            + "; ".join(f"{k.upper()} images {s:.0f} s, {mb:.0f} MB" for k, (s, mb) in sim.items()),
        ]
    if timing:
        lines += [
            "",
            f"Seed {args.seeds[0]}: seconds to calibrate (the per-frame stages on 2 processes, the graph) "
            "and to write the results without and with the report (`outputs.write_run`; the report draws "
            "every frame's pictures and the next-pose figure):",
            "",
            "| images | calibrate s | write, no report s | write with report s |",
            "|---|---:|---:|---:|",
        ]
        for what, r in timing.items():
            lines.append(
                f"| {what} | {r['calibrate_s']:.1f} | {r['write_bare_s']:.1f} | {r['write_report_s']:.1f} |"
            )
    text = "\n".join(lines) + "\n"
    print(text)
    args.md.write_text(text)
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
