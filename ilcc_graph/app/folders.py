"""Where a command writes: the only place that decides and claims output folders.

``--out`` as given, else ``out/<timestamp>``, claimed before a long run (``io.output_folders``: new,
empty or an earlier result of ours, and not a data set the command reads), and a default folder
linked as ``out/latest`` once written. How a folder is claimed, staged and committed is
``io.output_folders`` (the simulator stages its data sets with it too).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path

__all__ = ["claim_given", "output_folder", "written"]


def output_folder(args: argparse.Namespace, reads: Sequence[str | Path] = (), root: str = "out") -> Path:
    """``--out`` as given (a link: its target), else ``out/<timestamp>`` (linked as ``out/latest``
    once written); claimed now, before a long run: new, empty or an earlier result of ours, and not
    a data set the command ``reads`` (``io.output_folders.claim_output``)."""
    from ilcc_graph.io.output_folders import claim_output

    out = getattr(args, "out_dir", None) or (
        Path(args.out) if args.out else Path(root) / time.strftime("%Y%m%d-%H%M%S")
    )
    out = claim_output(out, reads=reads)
    args.out_dir = out  # where an internal error's log goes (app.main)
    return out


def written(args: argparse.Namespace, out: Path) -> None:
    """The command wrote ``out``: a folder of ours by default (no ``--out``) becomes ``out/latest``."""
    from ilcc_graph.io.output_folders import link_latest

    if not args.out:
        link_latest(out)


def claim_given(args: argparse.Namespace, reads: Sequence[str | Path] = ()) -> None:
    """``--out`` claimed now when given (a command that writes only on request: ``evaluate``)."""
    from ilcc_graph.io.output_folders import claim_output

    if args.out:
        claim_output(args.out, reads=reads)
