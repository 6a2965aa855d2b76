"""The per-frame stages' worker processes: started safely, stopped with the run.

``map_processes(fn, items, jobs, progress)`` computes ``fn(*item)`` for every item, in order, on
``jobs`` processes (in this process when ``jobs <= 1``); ``imap_processes`` gives them one at a time
as the caller asks, the workers a few items ahead.

- Workers come from a ``forkserver``: a clean process that imports the stages once and forks each
  worker from itself, never from the main process. The main process has threads by then (OpenBLAS's,
  OpenCV's, the pool's own, a progress bar's); a fork copies the locks they hold and not the threads,
  so a child can wait forever on a lock nobody will release (a ``--jobs 2`` run hung at the start of
  its pool, issue 14). The server is started early (``prestart``) so that its imports overlap the
  main process's work; docs/faults.md has the measured cost.
- Workers ignore SIGINT (a terminal's Ctrl-C reaches the whole process group: the main process
  decides, and ends them; the fork server too, from its first import) and end with the main
  process (a thread waits on it) or their parent (Linux ``PR_SET_PDEATHSIG``), so even a run
  killed with SIGKILL leaves none behind: the server ends when the last of them has.
- When the main process leaves the map by an exception (a signal's ``Stopped``, an input error, a
  bug) the queued work is cancelled and the workers are terminated at once instead of being waited for.
- Every worker of a pool starts when the pool does, with a stop held over the spawns (``_started``):
  a stop in the middle of one broke the fork server's and the new child's pipes, and they printed
  tracebacks after the stop's line.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import logging
import multiprocessing
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Generator, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any

from ilcc_graph import signals

log = logging.getLogger(__name__)

__all__ = ["START_METHOD", "imap_processes", "map_processes", "pool", "prestart", "processes_where"]

#: how worker processes are started (see the module docstring)
START_METHOD = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
#: what the fork server imports once, so that a worker starts with the stages loaded
PRELOAD = ["ilcc_graph._forkserver_preload", "ilcc_graph.run.observe"]

Progress = Callable[[int, int], None]

_PR_SET_PDEATHSIG = 1


#: the resource tracker's warnings (a process of its own, started with this process's -W options):
#: after a stop it warns that it cannot unlink a semaphore the stop has already removed, a line
#: after the run's one line; leaks are measured instead (scripts/soak.py counts the semaphores)
QUIET_TRACKER = "ignore::UserWarning:multiprocessing.resource_tracker"


def _context() -> multiprocessing.context.BaseContext:
    if QUIET_TRACKER not in sys.warnoptions:  # before the tracker starts (with the first pool)
        sys.warnoptions.append(QUIET_TRACKER)
    ctx = multiprocessing.get_context(START_METHOD)
    if START_METHOD == "forkserver":
        ctx.set_forkserver_preload(PRELOAD)
    return ctx


def prestart() -> None:
    """Start the fork server now (it imports the stages while the caller goes on); cheap when running.

    The server ignores SIGINT from its first import on (``_forkserver_preload``).
    """
    if START_METHOD != "forkserver":
        return
    _context()
    from multiprocessing import forkserver

    forkserver.ensure_running()
    signals.at_stop(_stop_server)


def processes_where(field: int, value: int, live: bool = True) -> list[int]:
    """PIDs of the processes whose /proc/<pid>/stat field ``field`` (after the command name: 0 state,
    1 parent, 2 process group) equals ``value``; ``live``: zombies left out. Linux /proc; elsewhere
    none."""
    out = []
    with contextlib.suppress(OSError):
        for entry in os.scandir("/proc"):
            if not entry.name.isdigit():
                continue
            try:
                with open(f"/proc/{entry.name}/stat", "rb") as f:
                    fields = f.read().rsplit(b")", 1)[1].split()
            except OSError:
                continue
            if int(fields[field]) == value and not (live and fields[0] == b"Z"):
                out.append(int(entry.name))
    return out


def _stop_server() -> None:
    """End the fork server and every worker it forked, now (a stop). The server would end by itself
    once this process has, but only after its imports (seconds); a worker still starting is in no
    pool's list yet, and would fail on the pool's semaphores once they are released."""
    from multiprocessing import forkserver

    pid = getattr(getattr(forkserver, "_forkserver", None), "_forkserver_pid", None)  # no public accessor
    if not pid:
        return
    with contextlib.suppress(OSError):
        os.kill(pid, signal.SIGSTOP)  # no new worker from now on
        for child in processes_where(1, pid, live=False):
            with contextlib.suppress(OSError):
                os.kill(child, signal.SIGKILL)
        os.kill(pid, signal.SIGKILL)


def _die_with_parent() -> None:
    """Ask the kernel to kill this process when its parent ends (Linux; elsewhere nothing)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):  # no libc symbol: the pool's own checks remain
        return


def _exit_with(pid: int) -> None:
    """End this worker when process ``pid`` (the run's main process) ends, from a watching thread.

    A fork server's worker is the server's child, not the main process's, and holds the server's
    keep-alive pipe: without this a killed run's workers and server would wait for each other forever.
    """

    def wait() -> None:
        try:
            fd = os.pidfd_open(pid)  # Linux 5.3+: readable when the process ends
        except (AttributeError, OSError):
            fd = None
        if fd is not None:
            select.select([fd], [], [])
        else:
            while True:
                time.sleep(0.5)
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                except PermissionError:
                    continue
        os._exit(1)

    threading.Thread(target=wait, name="ilcc-graph-parent", daemon=True).start()


def _init_worker(main_pid: int) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _die_with_parent()
    _exit_with(main_pid)


def _started() -> None:
    """A worker's first task. ``pool`` starts every worker at once with these, a stop held: a worker
    spawned on demand is started by the main thread, and a stop in the middle of that broke the
    pipes of the fork server and the new child, which printed tracebacks (1 SIGTERM in 30 under load)."""


def _terminate(pool: ProcessPoolExecutor) -> None:
    """Cancel what is queued and end the workers now (not after their current frame)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())  # no public accessor before 3.14
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(timeout=1.0)
            if p.is_alive():
                p.kill()
                p.join(timeout=1.0)


@contextlib.contextmanager
def pool(jobs: int) -> Iterator[ProcessPoolExecutor]:
    """A pool of ``jobs`` worker processes (module docstring) for work submitted as it comes
    (``submit``); on leaving by an exception, or on a stop, its work is cancelled and the workers
    end at once. Functions and arguments must be picklable."""
    prestart()
    executor = ProcessPoolExecutor(
        max_workers=jobs, mp_context=_context(), initializer=_init_worker, initargs=(os.getpid(),)
    )
    with signals.on_stop(lambda: _terminate(executor)):
        try:
            with signals.held():  # every worker started now, where a stop waits for the spawns
                for _ in range(jobs):
                    executor.submit(_started)
            yield executor
        except BaseException:
            _terminate(executor)
            raise
    executor.shutdown(wait=True)


def map_processes(
    fn: Callable[..., Any], items: Sequence[tuple], jobs: int, progress: Progress | None = None
) -> list[Any]:
    """``[fn(*item) for item in items]`` on ``jobs`` processes, in order; ``progress(done, total)``.

    ``fn`` and the items must be picklable (``fn`` a module-level function). An exception ``fn``
    raises in a worker is raised here, after the other workers have been terminated.
    """
    out: list[Any] = []
    if jobs <= 1 or len(items) <= 1:
        for i, it in enumerate(items):
            signals.check()
            out.append(fn(*it))
            if progress:
                progress(i + 1, len(items))
        return out
    with pool(min(jobs, len(items))) as executor:
        futures = [executor.submit(fn, *it) for it in items]
        for i, fut in enumerate(futures):
            out.append(fut.result())
            signals.check()
            if progress:
                progress(i + 1, len(items))
    log.debug("%d items on %d %s workers (pid %d)", len(items), jobs, START_METHOD, os.getpid())
    return out


def imap_processes(
    fn: Callable[..., Any], items: Sequence[tuple], jobs: int, ahead: int | None = None
) -> Generator[Any, None, None]:
    """``fn(*item)`` for each item, in order, one at a time as the caller asks: on ``jobs`` processes
    working at most ``ahead`` items (default ``jobs``) beyond the last one taken, so that every worker
    is busy while the caller works on a result (in this process when ``jobs <= 1``). Closing the
    iterator before its end (a caller that has what it needs) ends the workers at once: the items
    ahead are dropped. ``fn`` and the items must be picklable, as for ``map_processes``."""
    if jobs <= 1 or len(items) <= 1:
        for it in items:
            signals.check()
            yield fn(*it)
        return
    todo = iter(items)
    with pool(min(jobs, len(items))) as executor:
        running: collections.deque[Future] = collections.deque(
            executor.submit(fn, *it) for it in itertools.islice(todo, max(1, ahead or jobs))
        )
        while running:
            out = running.popleft().result()
            signals.check()
            if (following := next(todo, None)) is not None:
                running.append(executor.submit(fn, *following))
            yield out
