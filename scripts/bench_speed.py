"""``ilcc-graph calibrate`` of the standard set, report included: time, size, results, today's code
against this tree, in one run (issue 13: at most 20 s on 2 cores, report at most 5 MB, coloured
clouds at most 10 MB or on request; issue 23: at most twice the time of decoding the set's PNGs
alone, measured just before each run).

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
import threading
import time
from pathlib import Path

import numpy as np
import yaml
from _shared import baseline_tree  # (scripts/ is the running script's folder)

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "bench_speed.md"
SHOT = ROOT / "docs" / "bench_speed_report.jpg"


def replace_section(heading: str, text: str) -> None:
    """docs/bench_speed.md with its section under ``heading`` (``"\\n## ...\\n"``) replaced by ``text``
    (appended when missing); the other sections kept."""
    old = DOC.read_text() if DOC.is_file() else ""
    if heading not in old:
        DOC.write_text(old.rstrip("\n") + "\n" + text)
        return
    head, tail = old.split(heading, 1)
    rest = tail[tail.index("\n## ") :] if "\n## " in tail else ""
    DOC.write_text(head.rstrip("\n") + "\n" + text.rstrip("\n") + "\n" + rest)


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


def _tree_rss(root: int) -> int:
    """Resident bytes of process ``root`` and all its descendants now (/proc)."""
    parent, rss = {}, {}
    page = os.sysconf("SC_PAGE_SIZE")
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            parent[int(d.name)] = int(stat.rsplit(")", 1)[1].split()[1])
            rss[int(d.name)] = int((d / "statm").read_text().split()[1]) * page
        except (OSError, ValueError, IndexError):
            continue
    tree, grew = {root}, True
    while grew:
        new = {p for p, pp in parent.items() if pp in tree and p not in tree}
        tree |= new
        grew = bool(new)
    return sum(rss.get(p, 0) for p in tree)


def run_measured(
    cmd: list[str], cwd: Path, env: dict
) -> tuple[subprocess.CompletedProcess, float, float, float]:
    """(process, wall s, machine CPU s, peak resident MB of the command and all its processes,
    sampled every 0.2 s)."""
    c0, t0 = _cpu_machine(), time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peak, out = 0, []
    reader = threading.Thread(target=lambda: out.extend(proc.communicate()))
    reader.start()
    while reader.is_alive():
        peak = max(peak, _tree_rss(proc.pid))
        reader.join(0.2)
    wall, cpu = time.perf_counter() - t0, _cpu_machine() - c0
    return subprocess.CompletedProcess(cmd, proc.returncode, *out), wall, cpu, peak / 1e6


def calibrate(src: Path, data: Path, out: Path, extra: list[str]) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, PYTHONPATH=str(src))
    link = out.parent / "DATA"  # run beside it with relative names: the report (and its screenshot)
    if not link.exists():  # shows "DATA" and "OUT", not this machine's folders
        link.symlink_to(Path(data).resolve())
    cmd = [sys.executable, "-m", "ilcc_graph.app", "calibrate", "DATA", "--out", out.name, "--jobs", "2"]
    cmd += extra
    p, wall, cpu, peak = run_measured(cmd, out.parent, env)
    if p.returncode != 0:
        raise RuntimeError(f"{cmd} failed:\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}")
    m = re.search(r"calibrated in ([0-9.]+) s, outputs written in ([0-9.]+) s", p.stdout)
    return {
        "wall": wall,
        "cpu": cpu,
        "peak_mb": peak,
        "calibrate": float(m.group(1)) if m else float("nan"),
        "write": float(m.group(2)) if m else float("nan"),
        "report_mb": _size(out / "report") / 1e6,
        "clouds_mb": _size(out / "coloured") / 1e6,
        "files": sum(1 for p in (out / "report").rglob("*") if p.is_file()),
        "cal": yaml.safe_load((out / "calibration.yaml").read_text()),
    }


DECODE = """
import sys, time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from ilcc_graph.io import read_image

def size(path):
    return read_image(path).shape

if __name__ == "__main__":
    files = sorted(p for p in Path(sys.argv[1]).iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    t0 = time.perf_counter()
    with ProcessPoolExecutor(2) as pool:
        shapes = list(pool.map(size, files))
    print(len(shapes), time.perf_counter() - t0)
"""


def decode(src: Path, data: Path) -> float:
    """Wall seconds to decode the set's PNGs alone, 2 processes (``io.read_image``, OpenCV), from
    starting Python to the end: what the run's image reading costs at the least."""
    env = dict(os.environ, PYTHONPATH=str(src))
    t0 = time.perf_counter()
    p = subprocess.run(
        [sys.executable, "-c", DECODE, str(Path(data) / "img")], env=env, capture_output=True, text=True
    )
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"decoding failed:\n{p.stderr[-3000:]}")
    return wall


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


def png_twin(data: Path) -> Path:
    """The set beside ``data`` with its images as PNG (the same pixels: each JPEG decoded and
    written losslessly), scans and files shared; made once."""
    twin = data.with_name(data.name + "-png")
    if (twin / "ground_truth.yaml").is_file():
        return twin
    import cv2

    tmp = twin.with_name(twin.name + ".part")
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "img").mkdir(parents=True)
    for f in data.iterdir():
        if f.is_file():
            shutil.copy2(f, tmp / f.name)
    shutil.copytree(data / "pcd", tmp / "pcd")
    for f in sorted((data / "img").iterdir()):
        cv2.imwrite(str(tmp / "img" / (f.stem + ".png")), cv2.imread(str(f), cv2.IMREAD_UNCHANGED))
    tmp.rename(twin)
    return twin


def standard_set(data: Path | None) -> Path:
    """The demo's standard set (JPEG, ``ilcc-graph demo``'s cache folder), simulated when missing."""
    data = data or Path.home() / ".cache" / "ilcc_graph" / "demo-hdl32-equirect8000-seed0"
    if not (data / "ground_truth.yaml").is_file():
        sys.path.insert(0, str(ROOT))
        from ilcc_graph.simulate.write_set import write_standard_set

        write_standard_set(
            data, width=8000, seed=0, lidar="hdl32", camera="equirectangular", frames=20, image_format="jpg"
        )
    return data


MODES = {"report": [], "--no-report": ["--no-report"]}
TARGETS = {
    ("jpg", "report"): 3.0,
    ("jpg", "--no-report"): 2.5,
    ("png", "report"): 2.0,
    ("png", "--no-report"): 1.5,
}


def measure(sets: dict[str, Path], codes: dict[str, Path], repeats: int, work: Path) -> list[dict]:
    """Every (format, code, mode) run ``repeats`` times, alternately, each after the decoding alone."""
    runs = []
    for k in range(repeats):
        for fmt, data in sets.items():
            for mode, extra in MODES.items():
                for name, src in codes.items():
                    t_decode = decode(ROOT, data)
                    r = calibrate(src, data, work / f"out_{fmt}_{name.replace(' ', '_')}", extra)
                    r.update(format=fmt, code=name, mode=mode, decode=t_decode, ratio=r["wall"] / t_decode)
                    runs.append(r)
                    print(fmt, mode, name, k, {x: round(v, 2) for x, v in r.items() if isinstance(v, float)},
                          flush=True)  # fmt: skip
    return runs


def table(runs: list[dict], labels: dict[str, str]) -> str:
    header = ["set", "code", "command", "wall s (each run)", "decoding alone s", "wall / decoding",
              "target", "CPU s", "calibration s", "writing s", "peak MB", "report MB"]  # fmt: skip
    rows = []
    for fmt in dict.fromkeys(r["format"] for r in runs):
        for mode in MODES:
            for code in labels:
                rs = [r for r in runs if (r["format"], r["mode"], r["code"]) == (fmt, mode, code)]
                target = TARGETS[(fmt, mode)]
                met = "met" if np.median([r["ratio"] for r in rs]) <= target else "missed"
                rows.append([
                    fmt.upper(), labels[code], f"`calibrate{'' if mode == 'report' else ' ' + mode}`",
                    ", ".join(f"{r['wall']:.1f}" for r in rs), ", ".join(f"{r['decode']:.1f}" for r in rs),
                    ", ".join(f"{r['ratio']:.2f}" for r in rs),
                    f"<= {target:g}x ({met})" if code != "today" else "",
                    f"{np.median([r['cpu'] for r in rs]):.1f}",
                    f"{np.median([r['calibrate'] for r in rs]):.1f}",
                    f"{np.median([r['write'] for r in rs]):.1f}", f"{max(r['peak_mb'] for r in rs):.0f}",
                    f"{rs[-1]['report_mb']:.1f}",
                ])  # fmt: skip
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=None, help="the standard set (default: the demo's cache)")
    ap.add_argument(
        "--baseline", default=None, help="git revision of today's code (default: merge-base with main)"
    )
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--no-png", action="store_true", help="the JPEG set only")
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args(argv)
    data = standard_set(args.data)
    sets = {"jpg": data} if args.no_png else {"jpg": data, "png": png_twin(data)}
    rev, head, work, base = baseline_tree(ROOT, args.baseline, "bench_speed_")
    runs = measure(sets, {"today": base, "this tree": ROOT}, args.repeats, work)
    labels = {"today": f"today ({rev[:7]})", "this tree": f"this tree ({head})"}
    same = {fmt: compare(*(next(r["cal"] for r in reversed(runs) if (r["format"], r["code"]) == (fmt, c))
                           for c in labels)) for fmt in sets}  # fmt: skip
    load = os.getloadavg()
    text = (
        "# `calibrate` of the standard set: time against decoding its images, today's code and this "
        "tree\n\n"
        "`nice python scripts/bench_speed.py --write` (issues 13, 23, 37). The standard set is the one "
        "`ilcc-graph demo` makes (HDL-32E, 8000 x 4000 panoramas as JPEG, 20 frames, seed 0) and its PNG "
        "twin (the same pixels written as PNG). `ilcc-graph calibrate DATA --out OUT --jobs 2`, with the "
        "report and with `--no-report`, each version in its own process, alternately, "
        f"{args.repeats} times each; just before each run, the set's 20 images decoded alone on 2 "
        "processes (`io.read_image`, from starting Python): on a shared machine their ratio moves less "
        "than either time. Wall time includes starting Python and writing everything; CPU is the "
        "machine's busy time during the run (/proc/stat, every process, whatever else ran too); peak MB "
        "the largest resident memory of the command and all its processes together (sampled every "
        "0.2 s). Targets (issue 37, for this tree): JPEG at most 3x with the report, 2.5x without; PNG "
        "at most 2x and 1.5x; met or missed by the median ratio.\n\n" + table(runs, labels) + "\n\n"
        "Results, today's against this tree's calibration.yaml (last runs):\n\n"
        + "\n".join(f"- {fmt.upper()}: {s}" for fmt, lines in same.items() for s in lines)
        + "\n\n"
        f"Machine: {os.cpu_count()} cores shared with other work; load average {load[0]:.1f} / "
        f"{load[1]:.1f} / {load[2]:.1f} (1 / 5 / 15 min) at the end.\n"
    )
    print(text)
    if args.write:  # the title and the standard set's table; the other scripts' sections kept
        old = DOC.read_text() if DOC.is_file() else ""
        DOC.write_text(text.rstrip("\n") + "\n" + (old[old.index("\n## ") :] if "\n## " in old else ""))
        print(f"wrote {DOC}")
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
