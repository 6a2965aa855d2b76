"""``workers.imap_processes``: results in order, one at a time as asked, the workers a few items
ahead; closed early, the work ahead is dropped and the workers end. ``observe.FrameStream`` (the
incremental mode's frames) observes on ``--jobs`` processes with it and gives what one process gives.
"""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path

import numpy as np

from ilcc_graph.workers import imap_processes


def test_the_results_come_in_order_on_one_process_or_two() -> None:
    items = [(k, 7) for k in range(25)]
    want = [divmod(k, 7) for k in range(25)]
    assert list(imap_processes(divmod, items, 1)) == want
    assert list(imap_processes(divmod, items, 2)) == want
    assert list(imap_processes(divmod, items, 2, ahead=5)) == want


def test_closed_early_the_work_ahead_is_dropped(tmp_path: Path) -> None:
    """Each item makes a folder: after three results taken, at most ``ahead`` (2) more were started."""
    items = [(str(tmp_path / f"{k:02d}"),) for k in range(40)]
    it = imap_processes(os.mkdir, items, 2)
    for _ in range(3):
        next(it)
    it.close()
    made = sorted(p.name for p in tmp_path.iterdir())
    assert made[:3] == ["00", "01", "02"] and len(made) <= 5, made


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (not gone, not a zombie)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except OSError:
        return False


def test_closed_early_its_workers_end() -> None:
    it = imap_processes(os.getpid, [()] * 40, 2)
    pids = {next(it) for _ in range(4)}
    assert os.getpid() not in pids and all(_alive(p) for p in pids)  # the work ran on other processes
    it.close()
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.05)
    assert not [p for p in pids if _alive(p)], "workers still running after the iterator was closed"


def test_the_incremental_modes_frames_on_two_processes_are_those_of_one(simulated) -> None:  # noqa: ANN001
    from ilcc_graph.datasets import open_source
    from ilcc_graph.run.observe import FrameStream
    from ilcc_graph.run.result import RunOptions

    data = simulated("fisheye", frames=4, seed=3)
    stages = RunOptions().stages
    streams = [FrameStream(open_source(str(data)), dataclasses.replace(stages, jobs=j)) for j in (1, 2)]
    one, two = (list(s) for s in streams)
    assert len(one) == 4 and sum(f.used for f in one) >= 3
    _same(one, two, "frames")


def _same(a: object, b: object, where: str) -> None:
    """``a`` and ``b`` hold the same values to the bit (dataclasses, containers, arrays, floats), but
    for the stages' own timings (``time_...`` and ``cpu_...`` in a dict)."""
    assert type(a) is type(b), f"{where}: {type(a).__name__} against {type(b).__name__}"
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        for f in dataclasses.fields(a):
            _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            if not str(k).startswith(("time_", "cpu_")):
                _same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{k}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype, where
        assert np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"), where
    elif isinstance(a, float):
        assert a == b or (np.isnan(a) and np.isnan(b)), f"{where}: {a!r} against {b!r}"
    else:
        assert a == b, f"{where}: {a!r} against {b!r}"
