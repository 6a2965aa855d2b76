"""``ilcc-graph calibrate`` of the standard set, report included: time, size, results, today's code
against this tree, in one run (issue 13: at most 20 s on 2 cores, report at most 5 MB, coloured
clouds at most 10 MB or on request).

The standard set is the one ``ilcc-graph demo`` simulates (HDL-32E, 8000 x 4000 equirectangular,
20 frames, seed 0; ``--data`` or simulated into the demo's cache folder). The baseline is the code
of ``--baseline`` (a git revision, default: the commit this branch started from, ``git merge-base
HEAD main``) extracted with ``git archive`` into a temporary folder; both run as
``python -m ilcc_graph.app calibrate DATA --out OUT --jobs 2`` in their own process, alternately
(``--repeats`` each), so that the machine's load falls on both alike. Wall time, the machine's busy CPU
time during the run (/proc/stat), the two phases the command prints (calibration, writing), the
report's and the clouds' sizes; and the calibration.yaml numbers of both (they must agree).
With a headless Chromium on the machine, the new report is opened in it and a screenshot written
(docs/bench_speed_report.jpg) to look at.

Run: ``nice python scripts/bench_speed.py --write``.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bench_speed.md"
SHOT = ROOT / "docs" / "bench_speed_report.jpg"


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.exists() else 0


def _cpu_machine() -> float:
    """Busy CPU seconds of the whole machine so far (/proc/stat: all cores, every process).

    The run's own count (``getrusage`` of the children) misses the workers of a fork server, which
    are not the command's waited-for children; the machine's count has them, and whatever else
    runs at the time (the table says the load)."""
    fields = [float(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0.0)  # idle + iowait
    return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def calibrate(src: Path, data: Path, out: Path, extra: list[str]) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, PYTHONPATH=str(src))
    link = out.parent / "DATA"  # run beside it with relative names: the report (and its screenshot)
    if not link.exists():  # shows "DATA" and "OUT", not this machine's folders
        link.symlink_to(Path(data).resolve())
    cmd = [sys.executable, "-m", "ilcc_graph.app", "calibrate", "DATA", "--out", out.name, "--jobs", "2"]
    cmd += extra
    c0, t0 = _cpu_machine(), time.perf_counter()
    p = subprocess.run(cmd, cwd=out.parent, env=env, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _cpu_machine() - c0
    if p.returncode != 0:
        raise RuntimeError(f"{cmd} failed:\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}")
    m = re.search(r"calibrated in ([0-9.]+) s; wrote .* \(([0-9.]+) s\)", p.stdout)
    return {
        "wall": wall,
        "cpu": cpu,
        "calibrate": float(m.group(1)) if m else float("nan"),
        "write": float(m.group(2)) if m else float("nan"),
        "report_mb": _size(out / "report") / 1e6,
        "clouds_mb": _size(out / "coloured") / 1e6,
        "files": sum(1 for p in (out / "report").rglob("*") if p.is_file()),
        "cal": yaml.safe_load((out / "calibration.yaml").read_text()),
    }


def compare(a: dict, b: dict) -> list[str]:
    Ta, Tb = np.array(a["T_cam_lidar"]), np.array(b["T_cam_lidar"])
    sa = np.array(list(a["sigma"].values()))
    sb = np.array(list(b["sigma"].values()))
    used_a = [f["name"] for f in a["frames"] if f["used"]]
    used_b = [f["name"] for f in b["frames"] if f["used"]]
    return [
        f"largest difference of T_cam_lidar entries: {np.abs(Ta - Tb).max():.2e}",
        f"largest relative difference of the six sigmas: {np.max(np.abs(sa - sb) / sa):.2e}",
        f"frames used: {len(used_a)} and {len(used_b)}, the same: {used_a == used_b}",
    ]


def screenshot(report: Path) -> str:
    browser = next((b for b in ("chromium-headless-shell", "chromium") if shutil.which(b)), None)
    if browser is None:
        return "no headless Chromium here: the page was only checked with tests/test_report_views.py's parser"
    png = Path(tempfile.mkdtemp()) / "shot.png"
    cmd = [
        browser,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--hide-scrollbars",
        f"--screenshot={png}",
        "--window-size=1280,7000",
        "--virtual-time-budget=15000",
        (report / "index.html").as_uri(),
    ]
    subprocess.run(cmd, capture_output=True, timeout=180)
    from PIL import Image

    img = Image.open(png).convert("RGB")
    img = img.resize((img.width // 2, img.height // 2))
    img.save(SHOT, quality=80)
    return f"opened in {browser} (headless), screenshot: `{SHOT.name}` (1280 x 7000 px page, halved)"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=None)
    ap.add_argument(
        "--baseline", default=None, help="git revision of today's code (default: merge-base with main)"
    )
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args(argv)
    data = args.data or Path.home() / ".cache" / "ilcc_graph" / "demo-hdl32-equirect8000-seed0"
    if not (data / "ground_truth.yaml").is_file():
        sys.path.insert(0, str(ROOT))
        from ilcc_graph.simulate import simulate_dataset, standard_spec

        simulate_dataset(
            data, standard_spec(lidar="hdl32", camera="equirectangular", width=8000, frames=20, seed=0)
        )
    rev = (
        args.baseline
        or subprocess.run(
            ["git", "merge-base", "HEAD", "main"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
    )
    head = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
    ).stdout
    work = Path(tempfile.mkdtemp(prefix="bench_speed_"))
    base = work / "baseline"
    base.mkdir()
    arch = subprocess.run(["git", "archive", rev], cwd=ROOT, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(base)], input=arch, check=True)
    runs: dict[str, list[dict]] = {"today": [], "this tree": []}
    for k in range(args.repeats):
        for name, src in (("today", base), ("this tree", ROOT)):
            r = calibrate(src, data, work / f"out_{name.replace(' ', '_')}", [])
            runs[name].append(r)
            print(name, k, {x: round(v, 2) for x, v in r.items() if isinstance(v, float)}, flush=True)
    clouds = calibrate(ROOT, data, work / "out_clouds", ["--clouds"])
    shot = screenshot(work / "out_this_tree" / "report")
    header = [
        "code",
        "wall s (each run)",
        "CPU s",
        "calibration s",
        "writing s",
        "report MB",
        "report files",
        "clouds MB",
    ]
    rows = []
    for name, rs in runs.items():
        rows.append(
            [
                f"{name}" + (f" ({rev[:7]})" if name == "today" else f" ({head.strip()})"),
                ", ".join(f"{r['wall']:.1f}" for r in rs),
                f"{np.median([r['cpu'] for r in rs]):.1f}",
                f"{np.median([r['calibrate'] for r in rs]):.1f}",
                f"{np.median([r['write'] for r in rs]):.1f}",
                f"{rs[-1]['report_mb']:.1f}",
                str(rs[-1]["files"]),
                f"{rs[-1]['clouds_mb']:.1f}",
            ]
        )
    rows.append(
        [
            "this tree, `--clouds`",
            f"{clouds['wall']:.1f}",
            f"{clouds['cpu']:.1f}",
            f"{clouds['calibrate']:.1f}",
            f"{clouds['write']:.1f}",
            f"{clouds['report_mb']:.1f}",
            str(clouds["files"]),
            f"{clouds['clouds_mb']:.1f}",
        ]
    )
    table = "\n".join(
        ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        + ["| " + " | ".join(r) + " |" for r in rows]
    )
    same = compare(runs["today"][-1]["cal"], runs["this tree"][-1]["cal"])
    load = os.getloadavg()
    text = (
        "# `calibrate` of the standard set: time and size, today's code against this tree\n\n"
        "`scripts/bench_speed.py` (issue 13). The standard panoramic set (HDL-32E, 8000 x 4000, 20 frames), "
        "`ilcc-graph calibrate DATA --out OUT --jobs 2` with the report, each version in its own process, "
        f"alternately, {args.repeats} times each. Wall time includes starting Python and writing everything; "
        "CPU is the machine's busy time during the run (/proc/stat, every process: the run's workers, "
        "also a fork server's, and whatever else ran). Targets: at most 20 s wall on 2 cores, "
        "report at most 5 MB, coloured clouds at most 10 MB or on request.\n\n" + table + "\n\n"
        "Results, today's against this tree's calibration.yaml:\n\n"
        + "\n".join(f"- {s}" for s in same)
        + "\n\n"
        f"Browser: {shot}.\n\n"
        f"Machine: {os.cpu_count()} cores shared with other work; load average {load[0]:.1f} / "
        f"{load[1]:.1f} / {load[2]:.1f} (1 / 5 / 15 min) at the end.\n"
    )
    print(text)
    if args.write:
        DOC.write_text(text)
        print(f"wrote {DOC}")
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
