"""How fast a signal stops a run, per phase, and what the worker pool's start method costs.

Part 1: ``ilcc-graph calibrate`` on a small simulated set is signalled ``--repeats`` times in each
phase (starting, the worker pool, estimating, writing); per case the exit code, the seconds from the
signal to the main process's exit and to the whole process tree's, and whether stderr held exactly
one line from the stop and no traceback. Part 2: a pool of 2 workers started with 'fork',
'forkserver' (what ``workers.py`` uses) and 'spawn' from a process that holds the stages, timed to
its first results (a fresh process each time). Prints tables and writes them between the stop
markers of docs/faults.md. Linux only (/proc).

Usage: python3 scripts/bench_stop.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _shared import processes_where, write_between  # noqa: E402

from ilcc_graph.app import main  # noqa: E402

MARK_BEGIN, MARK_END = "<!-- stop:begin -->", "<!-- stop:end -->"
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _group(pgid: int) -> list[int]:
    return processes_where(2, pgid)


def one(data: Path, work: Path, phase: str, sig: int, group: bool) -> dict:
    out = work / "run"
    cmd = [
        sys.executable,
        "-m",
        "ilcc_graph.app",
        "-v",
        "calibrate",
        str(data),
        "--out",
        str(out),
        "--jobs",
        "2",
    ]
    if phase != "writing":
        cmd.append("--no-report")
    p = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=ENV, start_new_session=True
    )
    lines: list[str] = []
    reader = threading.Thread(
        target=lambda: lines.extend(ln.decode().rstrip() for ln in p.stderr), daemon=True
    )
    reader.start()
    ready = {
        "starting": lambda: True,
        "worker pool": lambda: len(_group(p.pid)) >= 4,
        "estimating": lambda: any("estimating the extrinsic" in ln for ln in lines),
        "writing": lambda: any(".partial-" in q.name for q in work.iterdir()),
    }[phase]
    if phase == "starting":
        time.sleep(0.3)
    t0 = time.monotonic()
    while not ready() and p.poll() is None and time.monotonic() - t0 < 120:
        time.sleep(0.005)
    t0 = time.monotonic()
    (os.killpg if group else os.kill)(p.pid, sig)
    rc = p.wait()
    t_main = time.monotonic() - t0
    while _group(p.pid) and time.monotonic() - t0 < 10:
        time.sleep(0.005)
    t_tree = time.monotonic() - t0
    left = _group(p.pid)
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    reader.join(5)
    said = [ln for ln in lines if ln.startswith("ilcc-graph: ")]
    clean = len(said) == 1 and lines and lines[-1] == said[0] and not any("Traceback" in ln for ln in lines)
    partial = out.exists() or any(".partial-" in q.name for q in work.iterdir())
    with contextlib.suppress(OSError):
        subprocess.run(["rm", "-rf", str(out)], check=False)
    return {"rc": rc, "main": t_main, "tree": t_tree, "left": len(left), "clean": clean, "partial": partial}


_POOL = """
import math, sys, time, multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor
def go():
    import ilcc_graph.observe
    from ilcc_graph import workers
    m = sys.argv[1]
    ctx = mp.get_context(m)
    if m == "forkserver":
        ctx.set_forkserver_preload(workers.PRELOAD)
    t = time.perf_counter()
    with ProcessPoolExecutor(2, mp_context=ctx) as pool:
        list(pool.map(ilcc_graph.observe.warn_damaged, [[], [], [], []]))
    print(time.perf_counter() - t)
if __name__ == "__main__":
    go()
"""


def pool_cost(method: str) -> float:
    r = subprocess.run(
        [sys.executable, "-c", _POOL, method], env=ENV, capture_output=True, text=True, check=True
    )
    return float(r.stdout.strip().splitlines()[-1])


def run(args: argparse.Namespace) -> str:
    lines = [
        f"`python3 scripts/bench_stop.py --repeats {args.repeats}`, {time.strftime('%Y-%m-%d')}, load "
        f"average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (shared with other work: the seconds "
        "are upper bounds of a quiet machine's).",
        "",
        "| phase | signal | exit codes | to main exit, s (median / max) "
        "| to no process left, s (median / max) | one line, no traceback | partial output |",
        "|---|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory(prefix="ilcc-stop-") as tmp:
        data = Path(tmp) / "data"
        with contextlib.redirect_stdout(io.StringIO()):
            assert main(["simulate", str(data), "--frames", "4", "--seed", "2", "--width", "2000"]) == 0
        cases = [
            ("starting", signal.SIGTERM, False, "SIGTERM"),
            ("worker pool", signal.SIGTERM, False, "SIGTERM"),
            ("worker pool", signal.SIGINT, True, "Ctrl-C (group)"),
            ("estimating", signal.SIGINT, True, "Ctrl-C (group)"),
            ("writing", signal.SIGTERM, False, "SIGTERM"),
        ]
        for phase, sig, group, name in cases:
            work = Path(tmp) / f"w-{phase}-{name}".replace(" ", "")
            work.mkdir()
            rs = [one(data, work, phase, sig, group) for _ in range(args.repeats)]
            codes = ", ".join(sorted({str(r["rc"]) for r in rs}))
            m, t = [r["main"] for r in rs], [r["tree"] for r in rs]
            lines.append(
                f"| {phase} | {name} | {codes} | {statistics.median(m):.2f} / {max(m):.2f} | "
                f"{statistics.median(t):.2f} / {max(t):.2f} | {sum(r['clean'] for r in rs)} of {len(rs)} | "
                f"{sum(r['partial'] for r in rs)} of {len(rs)} |"
            )
            print(lines[-1], flush=True)
    lines += [
        "",
        "Start-up of a 2-worker pool to its first results, from a process that holds the stages (fresh "
        f"process each time, {args.repeats} times; seconds, median / max):",
        "",
        "| start method | seconds |",
        "|---|---|",
    ]
    for method in ("fork", "forkserver", "spawn"):
        ts = [pool_cost(method) for _ in range(args.repeats)]
        lines.append(f"| {method} | {statistics.median(ts):.2f} / {max(ts):.2f} |")
        print(lines[-1], flush=True)
    return "\n".join(lines)


def write_docs(text: str) -> None:
    write_between(ROOT / "docs" / "faults.md", MARK_BEGIN, MARK_END, text)


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--no-docs", action="store_true", help="print only")
    a = p.parse_args()
    text = run(a)
    print(text)
    if not a.no_docs:
        write_docs(text)
