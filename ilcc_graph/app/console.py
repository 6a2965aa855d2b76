"""What the command line needs around a run: a progress bar, argument value types, the log of a bug.

- ``Progress(desc)``: the one progress-bar helper, a ``(done, total)`` callback drawing on stderr.
- value types for argparse (``COUNT``, ``PIXELS``, ``SEED``, ``NON_NEGATIVE``, ``POSITIVE``, ``RATE``,
  ``DEG_MM``):
  a wrong value is argparse's usage error (exit 2) naming the flag, e.g. ``simulate --frames 0``.
- ``run_command(fn, out, debug)``: a command under ``signals.stop_on_signals`` with its
  outcome as the exit code (interface.md): 0; 2 and one line for an ``InputError``; 3 for a
  calibration the data cannot give; 130 / 143 / 129 and one line for SIGINT / SIGTERM / SIGHUP;
  1 for an internal error (``report_bug``: one line, the traceback in a log file beside the output
  folder, ``<out>.error.log``, since the output folder itself is complete or absent; or in the
  temporary folder when a file not ours has that name; and on stderr with ``--debug``).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import sys
import tempfile
import textwrap
import traceback
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ilcc_graph import signals
from ilcc_graph.errors import (
    EXIT_BUG,
    EXIT_IMPOSSIBLE,
    EXIT_INPUT,
    CalibrationImpossible,
    IndeterminateSystem,
    InputError,
)

if TYPE_CHECKING:  # imported when the first bar is drawn
    from tqdm import tqdm

__all__ = [
    "stdout_closed",
    "COUNT",
    "DEG_MM",
    "NON_NEGATIVE",
    "PIXELS",
    "POSITIVE",
    "RATE",
    "SEED",
    "lazy_choices",
    "Progress",
    "report_bug",
    "run_command",
    "setup_logging",
]


class Progress:
    """One progress-bar helper: a callback (done, total) drawing a tqdm bar on stderr."""

    def __init__(self, desc: str) -> None:
        self.desc = desc
        self.bar: tqdm | None = None

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(
                total=total, desc=self.desc, unit="frame", leave=False, file=sys.stderr, disable=None
            )
        self.bar.n = done
        self.bar.refresh()
        if done >= total:
            self.bar.close()


def _number(kind: type, lo: float, what: str, hi: float = math.inf) -> Callable[[str], float]:
    """An argparse type: a ``kind`` in [lo, hi]; argparse names the flag in its message (exit 2)."""

    def parse(text: str) -> float:
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not (math.isfinite(v) and lo <= v <= hi):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return v

    return parse


COUNT = _number(int, 1, "a whole number >= 1")
PIXELS = _number(int, 64, "a whole number of pixels >= 64")
SEED = _number(int, 0, "a whole number >= 0")
#: ``simulate --rig-seed`` and ``simulate-rig --rig-seed``
RIG_SEED_HELP = (
    "the seed of the sensors' own errors (each LiDAR beam's range bias and gain, the stated "
    "intrinsics' error; default: --seed); a calibration set's seed here and another --seed give a "
    "new capture of the same rig (for verify)"
)
NON_NEGATIVE = _number(float, 0.0, "a number >= 0")
POSITIVE = _number(float, 1e-12, "a number > 0")
RATE = _number(float, 1e-12, "a number between 0 and 1", 1 - 1e-12)


class Choices(Sequence[str]):
    """An argparse ``choices`` read from its registry when first needed (a value checked, the help
    shown), so that building the parser imports no registry: ``lazy_choices(sp.add_argument(...),
    lambda: FORMATS)``."""

    def __init__(self, table: Callable[[], Sequence[str]]) -> None:
        self._table = table
        self._got: tuple[str, ...] | None = None

    def _names(self) -> tuple[str, ...]:
        if self._got is None:
            self._got = tuple(self._table())
        return self._got

    def __getitem__(self, k: int) -> str:  # type: ignore[override]
        return self._names()[k]

    def __len__(self) -> int:
        return len(self._names())

    def __contains__(self, value: object) -> bool:
        return value in self._names()


def lazy_choices(action: argparse.Action, table: Callable[[], Sequence[str]]) -> argparse.Action:
    """``action`` with its choices read from ``table`` when first needed (``Choices``); set after
    ``add_argument``, whose own check of the help's format would read them at once (the registries
    import the solvers: about 1.3 s before the first worker could start)."""
    action.choices = Choices(table)
    return action


def DEG_MM(text: str) -> tuple[float, float]:  # noqa: N802 - an argparse type, named like the others
    """'DEG,MM' -> (deg, mm), both positive (an argparse type)."""
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected DEG,MM (e.g. 0.05,1.0), got {text!r}") from None
    if not (a > 0 and b > 0 and math.isfinite(a + b)):
        raise argparse.ArgumentTypeError(f"expected two positive numbers DEG,MM, got {text!r}")
    return a, b


def _not_estimation_notes(record: logging.LogRecord) -> bool:
    """False for the estimation core's notes below WARNING (each frame the gate drops on its way, the
    variance components): the closing summary says what came of them, once."""
    return record.levelno >= logging.WARNING or not record.name.startswith("ilcc_graph.estimation")


class SaidOnce(logging.Filter):
    """Lets a line through once per command: the same warning from each candidate model's solve (only
    3 usable frames, say) is said once."""

    def __init__(self) -> None:
        super().__init__()
        self.said: set[tuple[int, str]] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.levelno, record.getMessage())
        if key in self.said:
            return False
        self.said.add(key)
        return True


class Wrapped(logging.Formatter):
    """``LEVEL: message`` wrapped to ``WIDTH`` columns (the lines after the first indented), as the
    rest of a command's output is: for a terminal, where a long warning would break mid-word."""

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        return "\n".join(textwrap.fill(line, WIDTH, subsequent_indent="  ") for line in text.splitlines())


def setup_logging(verbose: bool) -> None:
    """INFO on stderr; DEBUG for our own loggers with ``verbose`` (not every library's). The estimation
    core's INFO notes only with ``verbose`` (a filter on the handlers: the loggers' levels stay theirs);
    each line once per command on the handler made here (``SaidOnce``, anew for each command; a
    handler of the caller's, pytest's say, is left to say every line); its lines wrapped to ``WIDTH``
    columns when stderr is a terminal (``Wrapped``; a file or a pipe gets each message on one line)."""
    ours = not logging.getLogger().handlers
    logging.basicConfig(level=logging.INFO, format="%(levelname)s: %(message)s")
    if ours and sys.stderr.isatty():
        for handler in logging.getLogger().handlers:
            handler.setFormatter(Wrapped("%(levelname)s: %(message)s"))
    logging.getLogger("ilcc_graph").setLevel(logging.DEBUG if verbose else logging.INFO)
    for handler in logging.getLogger().handlers:
        said = [f for f in handler.filters if isinstance(f, SaidOnce)]
        for old in said:
            handler.removeFilter(old)
        if ours or said:
            handler.addFilter(SaidOnce())
        if verbose:
            handler.removeFilter(_not_estimation_notes)
        elif _not_estimation_notes not in handler.filters:
            handler.addFilter(_not_estimation_notes)


def report_bug(err: BaseException, out: Path | None, debug: bool, argv: list[str] | None = None) -> int:
    """Say an internal error in one line, keep its traceback in a log file; returns exit code 1."""
    from ilcc_graph.io.output_folders import OURS, write_beside

    text = "".join(traceback.format_exception(type(err), err, err.__traceback__))
    command = "ilcc-graph " + " ".join(sys.argv[1:] if argv is None else argv)
    candidates = [Path(f"{out}.error.log")] if out is not None else []
    candidates.append(Path(tempfile.gettempdir()) / f"ilcc-graph-error-{os.getpid()}.log")
    log = f"{OURS}: an internal error's traceback\n{command}\n{text}"
    where = next((p for p in candidates if write_beside(p, log) is not None), None)
    if debug:
        print(text, file=sys.stderr, end="")
    note = f"; the traceback is in {where}" if where else ""
    print(f"internal error (a bug, please report it): {type(err).__name__}: {err}{note}", file=sys.stderr)
    return EXIT_BUG


def run_command(
    fn: Callable[[], int], out: Callable[[], Path | None], debug: Callable[[], bool] = lambda: False
) -> int:
    """``fn()`` with signals handled, its outcome as the exit code (module docstring).

    out: where the command's output folder is (once it has decided), for an internal error's log;
    debug: whether to show that error's traceback.
    """
    with signals.stop_on_signals(), _quiet_stdout() as stdout:
        try:
            code = fn()
            signals.check()  # a stop swallowed on its way (signals.py) still stops
            return code
        except BrokenPipeError:  # a closed stdout where our wrapper does not see it: the run stops
            stdout.closed_pipe()
            return EXIT_PIPE
        except signals.Stopped as err:
            signals.announce(err)
            return err.exit_code
        except Exception as err:
            if (signum := signals.stop_requested()) is None:
                return _failure(err, out, debug)
            stop = signals.Stopped(signum)  # what the stop broke on its way (the worker pool, say)
            signals.announce(stop)
            return stop.exit_code
        except KeyboardInterrupt:  # outside the main thread: no handler of ours
            print("interrupted", file=sys.stderr)
            return 130


#: the exit status of a run ended by a closed stdout before it finished (128 + SIGPIPE, as a shell's)
EXIT_PIPE = 141


class _QuietStdout:
    """sys.stdout while a command runs: when the reader goes away (``calibrate DATA | head``, a pager
    quit early: EPIPE), what is printed later is dropped and the run goes on to write its outputs
    (issue 36: it ended with exit 1 "internal error: BrokenPipeError" and an error log)."""

    def __init__(self, stream: Any) -> None:
        self.stream = stream
        self.pipe_closed = False

    def closed_pipe(self) -> None:
        """Drop the rest: file descriptor 1 onto /dev/null, so that no flush (ours or the
        interpreter's at exit) meets the closed pipe again."""
        self.pipe_closed = True
        try:
            fd = self.stream.fileno()
        except (AttributeError, OSError, ValueError):
            return  # not a real file (a test's capture)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, fd)
        os.close(devnull)

    def write(self, text: str) -> int:
        if not self.pipe_closed:
            try:
                return self.stream.write(text)
            except BrokenPipeError:
                self.closed_pipe()
        return len(text)

    def flush(self) -> None:
        if not self.pipe_closed:
            try:
                self.stream.flush()
            except BrokenPipeError:
                self.closed_pipe()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[_QuietStdout]:
    """``_QuietStdout`` as sys.stdout, and one as sys.stderr (``2>&1 | head``: the progress bar and the
    log meet the closed pipe too), for the block (the originals put back after it); yields stdout's."""
    originals = sys.stdout, sys.stderr
    quiet = _QuietStdout(sys.stdout), _QuietStdout(sys.stderr)
    sys.stdout, sys.stderr = quiet
    try:
        yield quiet[0]
    finally:
        if sys.stdout is quiet[0]:
            sys.stdout = originals[0]
        if sys.stderr is quiet[1]:
            sys.stderr = originals[1]
        for q in quiet:
            q.flush()


def stdout_closed() -> bool:
    """Whether the reader of standard output has gone (``_QuietStdout``): a command that would go on
    only to print (``check --watch``) ends then (``BrokenPipeError``: exit 141, quietly)."""
    return bool(getattr(sys.stdout, "pipe_closed", False))


#: the terminal width every printed line fits in (columns)
WIDTH = 80


def wrapped(text: str, indent: str = "", more: str = "  ") -> str:
    """``text`` wrapped to ``WIDTH`` columns, each of its lines on its own: the first line of each
    starts with ``indent``, the following ones with ``more``. A word longer than a line (a path) is
    kept whole."""
    out: list[str] = []
    for para in text.splitlines() or [""]:
        out += textwrap.wrap(
            para,
            WIDTH,
            initial_indent=indent,
            subsequent_indent=more,
            break_long_words=False,
            break_on_hyphens=False,
        ) or [indent.rstrip()]
    return "\n".join(out)


def _failure(err: Exception, out: Callable[[], Path | None], debug: Callable[[], bool]) -> int:
    """The exit code of an exception that is not a stop, its message printed."""
    if isinstance(err, InputError):
        print(f"error: {err}", file=sys.stderr)
        return EXIT_INPUT
    if isinstance(err, (CalibrationImpossible, IndeterminateSystem)):
        print(wrapped(f"calibration impossible: {err}"), file=sys.stderr)
        return EXIT_IMPOSSIBLE
    return report_bug(err, out(), debug())  # a bug: a short message, the traceback in a log
