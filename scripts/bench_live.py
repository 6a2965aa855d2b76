"""Latency of ``ilcc-graph check --watch``: from a frame's arrival to its verdict (issue 13).

A simulated set's frames are copied one by one into an empty data-set folder (its config.yaml
first; per frame the scan, then the image, each with ``shutil.copyfile``, like a recorder writing
files) every ``--interval`` seconds, while ``ilcc-graph check DEST --watch --until N --out OUT``
runs as a separate process (the real command line). A frame's latency is the time from the end of
the write of its last file (the file's modification time) to the verdict, as ``check.yaml``
records it; it includes waiting until the files stop growing (0.3 s) and the polling (0.1 s).

Sets: a small one (pinhole 800 x 500, 8 frames), the 2000 x 1000 panoramic set (10 frames) and,
with ``--standard DIR`` (e.g. the folder ``ilcc-graph demo`` simulates, 8000 x 4000), its frames.
Run: ``python scripts/bench_live.py --write [--standard ~/.cache/ilcc_graph/demo-hdl32-equirect8000-seed0]``.

``--agree`` (issue 21): ``check`` fed the frames of each recorded set in ../shared/data (and a
simulated VLP-16 + pinhole set whose LiDAR reads 20 mm long) in order, in process, against
``calibrate`` (``pipeline.run``) on the same folder: the frames each uses, every verdict against
calibrate's fate of that frame, the final sigmas' ratio, and the running sigmas after 3, 5 and 8
boards against the final ones.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from _shared import write_between

from ilcc_graph.io import read_yaml
from ilcc_graph.simulate import SceneOptions, simulate_dataset, standard_spec

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bench_live.md"


def fill_and_check(src: Path, work: Path, n: int, interval: float) -> tuple[list[dict], float]:
    """Copy ``n`` frames of ``src`` into a new folder under ``work`` while ``check --watch`` runs."""
    dst, out = work / "live", work / "out"
    shutil.rmtree(dst, ignore_errors=True)
    (dst / "pcd").mkdir(parents=True)
    (dst / "img").mkdir()
    shutil.copyfile(src / "config.yaml", dst / "config.yaml")
    stems = sorted(p.stem for p in (src / "pcd").iterdir())[:n]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "ilcc_graph.app", "check", str(dst), "--watch", "--until", str(len(stems)),
           "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    time.sleep(3.0)  # the command's start (imports) is not part of a frame's latency
    t0 = time.perf_counter()
    for stem in stems:
        scan = next((src / "pcd").glob(f"{stem}.*"))
        image = next((src / "img").glob(f"{stem}.*"))
        shutil.copyfile(scan, dst / "pcd" / scan.name)
        shutil.copyfile(image, dst / "img" / image.name)
        time.sleep(interval)
    text, _ = proc.communicate(timeout=600)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"check failed ({proc.returncode}):\n{text}")
    print(text)
    return read_yaml(out / "check.yaml")["frames"], wall


def summary(name: str, frames: list[dict], interval: float) -> list[str]:
    lat = np.array([f["latency_s"] for f in frames])
    sec = np.array([f["seconds"] for f in frames])
    calibrated = [f for f in frames if "sigma" in f]
    return [
        name,
        str(len(frames)),
        f"{interval:.1f}",
        f"{np.median(sec):.2f} / {sec.max():.2f}",
        f"{np.median(lat):.2f}",
        f"{lat.max():.2f}",
        f"{np.mean(lat <= 2.0):.0%}",
        str(len(calibrated)),
    ]


RECORDED = ("acfr-vlp16-fisheye", "acfr-os1-fisheye", "acfr-os1-pinhole")


def agreement(name: str, data: Path) -> list[str]:
    """One table row: ``check`` against ``calibrate`` on ``data`` (module docstring)."""
    import logging

    from ilcc_graph.datasets import open_source
    from ilcc_graph.errors import CalibrationImpossible
    from ilcc_graph.live import CheckOptions, run_check
    from ilcc_graph.observe import StageOptions
    from ilcc_graph.pipeline import RunOptions, run
    from ilcc_graph.types import sigmas_deg_mm

    logging.getLogger("ilcc_graph").setLevel(logging.ERROR)
    t0 = time.perf_counter()
    result = run_check(open_source(data), CheckOptions(stages=StageOptions(jobs=1)))
    t_check = time.perf_counter() - t0
    try:
        cal = run([open_source(data)], RunOptions(stages=StageOptions(jobs=1))).calibration
    except CalibrationImpossible as err:
        final = "none" if result.final is None else f"{result.final.n_frames} frames"
        return [name, f"calibrate: exit 3 ({str(err)[:60]}...)", f"check: {final}", "-", "-", "-", "-", "-"]
    used = {f.name for f in cal.frames if f.used}
    if result.final is None:
        return [name, f"{len(used)}/{len(cal.frames)}", "check: not calibrated", "-", "-", "-", "-", "-"]
    final = set(result.final.solution.per_frame)
    judged = [v for v in result.verdicts if v.found and not v.repeat_of and v.sigmas is not None]
    same = sum((v.accepted and v.name in used) or (not v.accepted and v.name not in used) for v in judged)
    s_check, s_cal = sigmas_deg_mm(result.final.covariance), sigmas_deg_mm(cal.covariance)
    ratio = s_check / s_cal
    running = []
    for n in (3, 5, 8):
        v = next((v for v in result.verdicts if v.sigmas is not None and v.n_frames >= n), None)
        if v is not None:
            r = v.sigmas / s_cal
            running.append(f"{n}: {r[:3].max():.1f} / {r[3:].max():.1f}")
    model = result.final.solution.selection.chosen if result.final.solution.selection else "-"
    return [
        name,
        f"{len(used)}/{len(cal.frames)}",
        f"{len(final)}/{len(result.verdicts)}"
        + ("" if final == used else f" (differ: {sorted(final ^ used)})"),
        f"{same}/{len(judged)}",
        f"{ratio.min():.3f} .. {ratio.max():.3f}",
        f"{s_cal[:3].max():.4f} deg, {s_cal[3:].max():.2f} mm ({model})",
        "; ".join(running) or "-",
        f"{t_check:.0f}",
    ]


def agreement_table(work: Path, data_root: Path) -> str:
    header = [
        "set", "calibrate uses", "check's final uses", "verdicts as calibrate's",
        "final sigmas check / calibrate", "calibrate's largest sigmas (model)",
        "running sigmas / final after n boards (rot / trans, max)", "check s",
    ]  # fmt: skip
    rows = []
    for name in RECORDED:
        if (data_root / name / "config.yaml").is_file():
            rows.append(agreement(name, data_root / name))
            print(rows[-1], flush=True)
    scene = SceneOptions(room=(-9.0, 9.0, -9.0, 9.0), ceiling_height_m=4.0, board_distance_m=(2.9, 5.0))
    spec = standard_spec("vlp16", "pinhole", width=960, frames=12, seed=21, scene=scene)
    spec = spec.with_(systematics=replace(spec.systematics, range_offset_m=0.02))
    sim = simulate_dataset(work / "vlp16-offset", spec)
    rows.append(agreement("simulated VLP-16 + pinhole 960 px, 12 frames, 20 mm range offset", sim))
    print(rows[-1], flush=True)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--interval", type=float, default=3.0, help="seconds between frames")
    ap.add_argument(
        "--standard", type=Path, default=None, help="the 8000 x 4000 standard set (demo's folder)"
    )
    ap.add_argument("--frames", type=int, default=10, help="frames of the standard set to copy")
    ap.add_argument("--write", action="store_true")
    ap.add_argument("--agree", action="store_true", help="only check against calibrate (issue 21)")
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data", help="the recorded sets")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="bench_live_"))
    if args.agree:
        t0 = time.perf_counter()
        table = agreement_table(work, args.data)
        print(table)
        if args.write:
            when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
            load = os.getloadavg()[0]
            text = (
                f"`python scripts/bench_live.py --agree --write` ({when}, "
                f"{(time.perf_counter() - t0) / 60:.1f} min, "
                f"load average {load:.1f} at the end; 2 cores, shared).\n\n" + table
            )
            write_between(DOC, "<!-- agree:begin -->", "<!-- agree:end -->", text)
            print(f"wrote {DOC}")
        shutil.rmtree(work, ignore_errors=True)
        return 0
    sets = [
        ("pinhole 800 x 500, HDL-32E", standard_spec(camera="pinhole", width=800, frames=8, seed=5), 8),
        ("panorama 2000 x 1000, HDL-32E", standard_spec(width=2000, frames=10, seed=1), 10),
    ]
    rows = []
    for name, spec, n in sets:
        src = simulate_dataset(work / name.split()[0], spec)
        frames, _ = fill_and_check(src, work, n, args.interval)
        rows.append(summary(name, frames, args.interval))
    if args.standard is not None:
        frames, _ = fill_and_check(args.standard, work, args.frames, args.interval)
        rows.append(summary("standard panorama 8000 x 4000, HDL-32E", frames, args.interval))
    header = ["set", "frames", "every (s)", "work per frame median / max (s)", "latency median (s)",
              "latency max (s)", "within 2 s", "frames with sigmas"]  # fmt: skip
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    table = "\n".join(lines)
    print(table)
    if args.write:
        load = os.getloadavg()[0]
        text = (
            "`scripts/bench_live.py` (issue 13; target: within 2 s). Frames of simulated sets are copied "
            f"one by one into an empty folder every {args.interval:g} s while `check --watch` runs as its "
            "own "
            "process; latency: from the end of the write of the frame's last file to its verdict (includes "
            "the 0.3 s the files must stay unchanged and the 0.1 s polling). The work per frame is both "
            "stages (reading the files included), the repeat test and the solve of the frames so far as "
            "`calibrate` solves them (issue 21: gate, variance components, the sensor model's choice).\n\n"
            + table
            + f"\n\nMachine: {os.cpu_count()} cores, load average {load:.1f} when it finished."
        )
        write_between(DOC, "<!-- latency:begin -->", "<!-- latency:end -->", text)
        print(f"wrote {DOC}")
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
