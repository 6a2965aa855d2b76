"""Soak: many calibrations of a small simulated set back to back; memory, open files, processes.

Runs ``ilcc-graph calibrate`` ``--runs`` times in this one process (``app.main``, ``--jobs 2``,
every ``--report-every``-th run with the report), then ``--subprocess-runs`` times as separate
command-line processes. Samples after each in-process run: resident memory, open file descriptors,
threads, child processes and POSIX semaphores in /dev/shm; after each subprocess run: processes
left in its process group. Prints a table and writes it between the soak markers of
docs/faults.md. Linux only (/proc).

Usage: python3 scripts/soak.py [--runs 200] [--subprocess-runs 20] [--frames 4] [--width 2000]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _shared import processes_where, write_between  # noqa: E402

from ilcc_graph.app import main  # noqa: E402

MARK_BEGIN, MARK_END = "<!-- soak:begin -->", "<!-- soak:end -->"


def _status(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return -1


def _children(pid: int) -> list[int]:
    return processes_where(1, pid)


def _group(pgid: int) -> list[int]:
    return processes_where(2, pgid)


def _semaphores() -> int:
    return (
        sum(1 for p in Path("/dev/shm").iterdir() if p.name.startswith("sem."))
        if Path("/dev/shm").is_dir()
        else -1
    )


def sample(i: int, seconds: float) -> dict:
    return {
        "run": i,
        "rss_mb": _status("VmRSS") / 1024,
        "fds": len(os.listdir("/proc/self/fd")),
        "threads": _status("Threads"),
        "children": len(_children(os.getpid())),
        "sem": _semaphores(),
        "seconds": seconds,
    }


def soak(args: argparse.Namespace, work: Path) -> tuple[list[dict], list[tuple[int, int, float, float]]]:
    data = work / "data"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["simulate", str(data), "--frames", str(args.frames), "--width", str(args.width)]) == 0
    rows = []
    for i in range(1, args.runs + 1):
        out = work / "out"
        argv = ["calibrate", str(data), "--out", str(out), "--jobs", "2"]
        if args.report_every <= 0 or i % args.report_every:
            argv.append("--no-report")
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            code = main(argv)
        dt = time.perf_counter() - t0
        assert code == 0, f"run {i} exited {code}"
        shutil.rmtree(out)
        rows.append(sample(i, dt))
        if i == 1 or i % 10 == 0:
            r = rows[-1]
            print(f"run {i:4d}: {r['rss_mb']:7.1f} MB  {r['fds']} fds  {r['threads']} threads  "
                  f"{r['children']} children  {r['sem']} sem  {dt:.2f} s", flush=True)  # fmt: skip
    sub = []
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for i in range(1, args.subprocess_runs + 1):
        out = work / "sub"
        t0 = time.perf_counter()
        cmd = [
            sys.executable,
            "-m",
            "ilcc_graph.app",
            "calibrate",
            str(data),
            "--out",
            str(out),
            "--no-report",
        ]
        p = subprocess.Popen(
            cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, start_new_session=True
        )
        assert p.wait() == 0
        dt = time.perf_counter() - t0
        t_end = time.perf_counter()
        while _group(p.pid) and time.perf_counter() - t_end < 10:  # the fork server ends after the run
            time.sleep(0.02)
        sub.append((i, len(_group(p.pid)), time.perf_counter() - t_end, dt))
        shutil.rmtree(out, ignore_errors=True)
    return rows, sub


def table(rows: list[dict], sub: list[tuple[int, int, float, float]], args: argparse.Namespace) -> str:
    pick = [r for r in rows if r["run"] in (1, 2, 5, 10) or r["run"] % max(1, len(rows) // 8) == 0]
    lines = [
        f"Soak: {len(rows)} calibrations in one process (simulated set, {args.frames} frames, {args.width} "
        f"px, `--jobs 2`, every {args.report_every}th with the report), then {len(sub)} as separate "
        f"processes; `python3 scripts/soak.py --runs {args.runs} --subprocess-runs {args.subprocess_runs} "
        f"--frames {args.frames} --width {args.width}`, {time.strftime('%Y-%m-%d')}, load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (shared).",
        "",
        "| run | resident MB | open files | threads | child processes | /dev/shm semaphores | seconds |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in pick:
        cells = [r["run"], f"{r['rss_mb']:.1f}", r["fds"], r["threads"], r["children"], r["sem"]]
        lines.append("| " + " | ".join(map(str, cells)) + f" | {r['seconds']:.2f} |")
    if len(rows) >= 20:
        a, b = rows[9], rows[-1]
        per = (b["rss_mb"] - a["rss_mb"]) / (b["run"] - a["run"])
        peak = max(r["rss_mb"] for r in rows)
        lines += [
            "",
            f"From run {a['run']} to run {b['run']}: resident memory {a['rss_mb']:.1f} -> {b['rss_mb']:.1f} "
            f"MB ({per * 1024:+.0f} kB per run, peak {peak:.1f} MB), open files {a['fds']} -> {b['fds']}, "
            f"threads {a['threads']} -> {b['threads']}, child processes {a['children']} -> {b['children']} "
            f"(the fork server and its resource tracker), /dev/shm semaphores {a['sem']} -> {b['sem']} "
            "(system-wide).",
        ]
    if sub:
        left = sum(n for _, n, _, _ in sub)
        gone = max(t for _, _, t, _ in sub)
        lines.append(
            f"Separate processes: {len(sub)} runs; {left} processes of their trees left 10 s after they "
            f"ended (the fork server and resource tracker were gone {gone:.2f} s after the run at most); "
            f"{sum(t for *_, t in sub) / len(sub):.1f} s per run, start-up included."
        )
    return "\n".join(lines)


def write_docs(text: str) -> None:
    write_between(ROOT / "docs" / "faults.md", MARK_BEGIN, MARK_END, text)


def parse() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=200)
    p.add_argument("--subprocess-runs", type=int, default=20)
    p.add_argument("--report-every", type=int, default=20)
    p.add_argument("--frames", type=int, default=4)
    p.add_argument("--width", type=int, default=2000)
    p.add_argument("--no-docs", action="store_true", help="print only")
    return p.parse_args()


if __name__ == "__main__":
    args = parse()
    with tempfile.TemporaryDirectory(prefix="ilcc-soak-") as tmp:
        rows, sub = soak(args, Path(tmp))
    text = table(rows, sub, args)
    print(text)
    if not args.no_docs:
        write_docs(text)
