"""The ``ilcc-graph`` command line: arguments -> options -> run -> results written and printed.

- ``main(argv) -> exit code``: the entry point (``python -m ilcc_graph.app`` too);
- ``parser``: the parser's shell, one subparser per command of the registry ``commands``;
- ``cmd_<name>``: one module per command, its arguments (``add_arguments``) and its ``run(args)``;
  ``arguments``: the argument groups the commands share; ``flags``: the flags as the package's options;
- ``folders``: the only place that decides and claims output folders; ``write``: the one writer of
  a run's results; ``console``: progress bars, argument types, exit codes, a bug's log;
  ``check_view``: what ``check`` shows as the frames arrive.

Nothing below this package imports it.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from ilcc_graph import signals
from ilcc_graph.app.console import run_command, setup_logging
from ilcc_graph.app.parser import build_parser

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``ilcc-graph`` with ``argv`` (default: the process's arguments); returns the exit code
    (interface.md: 0, 1 a bug, 2 bad input, 3 calibration impossible, 129/130/143 a signal)."""
    # one BLAS thread unless the user says otherwise: the sensor models' many small dense products
    # run 3-8x slower in wall time with OpenBLAS's threads on a loaded machine (docs/bench_live.md)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    args = argparse.Namespace(debug="--debug" in (sys.argv[1:] if argv is None else argv))

    def command() -> int:  # under the signal handlers from the first import on
        nonlocal args
        args = build_parser().parse_args(argv)
        args.command_line = " ".join(sys.argv[1:] if argv is None else argv)  # for the folders' markers
        setup_logging(args.verbose)
        return args.fn(args)

    code = run_command(command, lambda: getattr(args, "out_dir", None), lambda: args.debug)
    if signals.stop_requested() is not None:
        signals.exit_now(code)  # after a stop: no interpreter teardown (signals.exit_now)
    return code
