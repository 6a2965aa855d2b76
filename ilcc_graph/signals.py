"""Stopping a run on SIGINT (Ctrl-C), SIGTERM or SIGHUP: at once, the workers ended, no partial output.

``stop_on_signals()`` is the command line's context. Inside it the first of these signals raises
``Stopped`` (a ``KeyboardInterrupt``) in the main thread, so the clean-ups on the way out run: the
worker pool terminates its processes (``workers.py``), a staged output folder is removed
(``folders.staged``). Two things make the stop certain:

- a watcher thread learns of the signal at once (``signal.set_wakeup_fd``), also while the main
  thread sits in a long C call where no Python handler runs (OpenCV's chessboard search on a
  large image runs for seconds); when the process still lives ``grace_s`` later it prints the
  stop's line, runs the clean-ups registered with ``on_stop`` / ``at_stop`` and ends the process
  with 128 + the signal number (``exit_now``; the command line ends that way after a stop too);
- the stop is remembered: a ``Stopped`` swallowed on its way (raised inside a finaliser, where
  Python only prints it) is raised again by ``check()``, which loops and phases call.

Further signals during a stop are ignored. ``held()`` defers a stop over a few renames that make
an output folder complete. SIGINT is handled even when the process started with it ignored (a
background job of a script ignores it; a ``kill -INT`` was then silently swallowed and the run
completed, issue 14): a calibration leaves nothing half-done, so stopping is always safe. SIGHUP is
left alone when ignored (``nohup``).
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from types import FrameType

__all__ = [
    "Stopped",
    "announce",
    "at_stop",
    "check",
    "exit_now",
    "held",
    "on_stop",
    "stop_on_signals",
    "stop_requested",
]

_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))
_WHAT = {"SIGINT": "interrupted", "SIGTERM": "terminated", "SIGHUP": "hung up"}


class Stopped(KeyboardInterrupt):
    """The run was stopped by a signal; ``exit_code`` is 128 + its number (130 SIGINT, 143 SIGTERM)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = int(signum)

    @property
    def exit_code(self) -> int:
        return 128 + self.signum

    def __str__(self) -> str:
        name = signal.Signals(self.signum).name
        return (
            f"{_WHAT.get(name, 'stopped')} ({name}): the run stopped; workers ended, no partial output left"
        )


class _State:
    """Process-wide stop state (signals are process-wide). Written by the handler without locks."""

    def __init__(self) -> None:
        self.signum: int | None = None  # the stop asked for (by the handler or the watcher)
        self.raised = False  # the handler has raised it once
        self.held = 0
        self.cleanups: dict[int, Callable[[], None]] = {}
        self.announced = threading.Lock()
        self.said = False


_state = _State()


def stop_requested() -> int | None:
    """The signal number of a stop asked for, or None."""
    return _state.signum


def check() -> None:
    """Raise ``Stopped`` when a stop was asked for (outside ``held``); cheap, call it between steps."""
    if _state.signum is not None and not _state.held:
        raise Stopped(_state.signum)


def announce(err: Stopped) -> None:
    """Print the stop's one line on stderr, once per process (the watcher and the CLI both may try)."""
    with _state.announced:
        if _state.said:
            return
        _state.said = True
    print(f"ilcc-graph: {err}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def on_stop(fn: Callable[[], None]) -> Iterator[None]:
    """While the block runs, ``fn`` is a clean-up that ``exit_now`` runs (the block's own error
    handling is the first to clean up; ``fn`` is for when the process ends without unwinding)."""
    key = id(fn)
    _state.cleanups[key] = fn
    try:
        yield
    finally:
        _state.cleanups.pop(key, None)


def at_stop(fn: Callable[[], None]) -> None:
    """``fn`` is a clean-up ``exit_now`` runs, for the rest of the process (e.g. a fork server)."""
    _state.cleanups[id(fn)] = fn


def exit_now(code: int) -> None:
    """End the process at once after a stop: run the clean-ups left, flush, ``os._exit(code)``.

    Skips the interpreter's teardown (modules, atexit joins), which took 0.5-1.5 s on a loaded
    machine and during which no thread of ours can run.
    """
    for fn in list(_state.cleanups.values()):
        with contextlib.suppress(Exception):
            fn()
    _release_semaphores()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def _release_semaphores(timeout_s: float = 0.5) -> None:
    """Run multiprocessing's exit finalisers (they unlink the worker pool's named semaphores, which
    its resource tracker would otherwise clean up with a warning), for at most ``timeout_s``."""
    util = sys.modules.get("multiprocessing.util")
    run = getattr(util, "_run_finalizers", None)  # what multiprocessing runs at a normal exit
    if run is None:
        return
    t = threading.Thread(target=lambda: run(0), daemon=True)
    t.start()
    t.join(timeout_s)


@contextlib.contextmanager
def held() -> Iterator[None]:
    """A stop asked for inside the block is raised at its end (the watcher waits for it too)."""
    _state.held += 1
    try:
        yield
    finally:
        _state.held -= 1
    check()


def _importing(frame: FrameType | None) -> bool:
    """Is the main thread inside Python's import machinery? (An exception raised there, e.g. in its
    module-lock callback, is printed as "Exception ignored" with a traceback, not propagated.)"""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _handler(signum: int, frame: FrameType | None) -> None:
    if _state.raised:
        return  # a second Ctrl-C while stopping: the stop is under way (the watcher ends it)
    if _state.signum is None:
        _state.signum = signum
    if _state.held or _importing(frame):
        return  # raised by the next check() or the end of ``held``; the watcher ends it otherwise
    _state.raised = True
    raise Stopped(_state.signum)


def _force(signum: int) -> None:
    """End the process now (the main thread did not get out in time): the line, the clean-ups, exit."""
    announce(Stopped(signum))
    exit_now(128 + signum)


def _watch(sock: socket.socket, grace_s: float) -> None:
    while True:
        try:
            data = sock.recv(64)
        except InterruptedError:
            continue
        except OSError:
            return
        if not data:
            return  # the context ended without a stop
        signum = next((b for b in data if b in _SIGNALS), None)
        if signum is not None:
            break
    if _state.signum is None:
        _state.signum = signum  # the Python handler has not run yet (the main thread is in C code)
    deadline = time.monotonic() + grace_s
    hold_deadline = deadline + 5.0
    while time.monotonic() < deadline or (_state.held and time.monotonic() < hold_deadline):
        time.sleep(0.02)
    _force(_state.signum or signum)


@contextlib.contextmanager
def stop_on_signals(grace_s: float = 0.5) -> Iterator[None]:
    """Within the block SIGINT, SIGTERM and SIGHUP stop the run (module docstring).

    Outside the main thread (where Python allows no handlers) the block runs unguarded. After a
    stop the watcher stays armed: the process ends ``grace_s`` after the signal at the latest.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    r, w = socket.socketpair()
    w.setblocking(False)
    old: dict[int, object] = {}
    for s in _SIGNALS:
        if s == getattr(signal, "SIGHUP", None) and signal.getsignal(s) == signal.SIG_IGN:
            continue  # nohup
        old[s] = signal.signal(s, _handler)
    old_fd = signal.set_wakeup_fd(w.fileno(), warn_on_full_buffer=False)
    watcher = threading.Thread(target=_watch, args=(r, grace_s), name="ilcc-graph-stop", daemon=True)
    watcher.start()
    try:
        yield
    finally:
        if _state.signum is None:
            signal.set_wakeup_fd(old_fd)
            for s, h in old.items():
                signal.signal(s, h)  # type: ignore[arg-type]
            w.close()  # the watcher reads EOF and returns
            watcher.join(timeout=1.0)
            r.close()
