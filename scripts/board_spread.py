"""How far each board moves the extrinsic, against the covariance ``calibrate`` reports (issue 34).

For each data set: ``calibrate``'s run (configs as shipped, ``run.pipeline.run``), then for each
sensor model it solved, the held-out boards' shifts of the extrinsic (``estimation.held_out``) and
``held_out.board_spread``: the jackknife and leverage-corrected (HC2) ratios ``trace(C^-1 V) / 6``
against that model's own covariance, and the chosen model's against the reported covariance. About
1 when the covariance is the spread the boards give. The held-out factor (``selection``) is shown
beside them. A diagnostic: docs/bench_joint_lidar.md reads it.

Run: ``OPENBLAS_NUM_THREADS=1 python scripts/board_spread.py ../shared/data/acfr-vlp16-fisheye
../shared/data/acfr-os1-fisheye`` (one BLAS thread, as the command line runs).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

import ilcc_graph.estimation.batch as batch
from ilcc_graph.datasets import open_source
from ilcc_graph.estimation.held_out import board_spread, held_out
from ilcc_graph.run.pipeline import run
from ilcc_graph.run.result import RunOptions


def spread(data: Path) -> list[str]:
    """The table rows of one data set."""
    seen = []
    solve = batch.solve_sources

    def keep(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202 - the batch solve's own arguments
        got = solve(*args, **kwargs)
        seen.append(got)
        return got

    batch.solve_sources = keep  # the last batch solve of the run is the one it reports
    try:
        res = run([open_source(data)], RunOptions())
    finally:
        batch.solve_sources = solve
    got = seen[-1]
    rows = []
    for name, sol in got.sols[0].items():
        s = board_spread(held_out(sol, 0), sol.extrinsic(0).covariance)
        factor = next(c.factor for c in got.selection.candidates if c.name == name)
        rows.append(
            f"| {data.name} | {name}{' (chosen)' if name == got.selection.chosen else ''} | "
            f"{len(sol.boards)} | "
            f"{factor:.2f} | {s['jackknife']:.2f} | {s['hc2']:.2f} | {s['leverage_max']:.2f} | "
            f"{1e3 * s['shift_max_m']:.1f} |"
        )
    rep = board_spread(held_out(got.chosen[0], 0), np.asarray(res.calibration.covariance))
    rows.append(f"| {data.name} | reported covariance | | | {rep['jackknife']:.2f} | {rep['hc2']:.2f} | | |")
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", nargs="+", type=Path)
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    head = "| set | model | boards | held-out factor | jackknife | HC2 | largest leverage | largest shift mm"
    print(head + " |")
    print("|---|---|---|---|---|---|---|---|")
    for d in args.data:
        print("\n".join(spread(d)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
