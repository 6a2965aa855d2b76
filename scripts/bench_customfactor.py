"""Benchmark: how gtsam.CustomFactor scales inside GTSAM's optimizers.

For N trivial factors (a Point3 prior written as a CustomFactor, one per variable) this measures
- ``graph.linearize(values)`` called from Python on a Python-owned ``Values``,
- one Gauss-Newton iteration inside ``GaussNewtonOptimizer`` (whose ``Values`` live in C++),
- the same two numbers for the built-in ``PriorFactorPoint3``,
- the time to copy a ``Values`` of N entries, and how many distinct ``Values`` objects the
  callbacks see (one per call means pybind11 copied the whole ``Values`` for each callback),
- one Levenberg-Marquardt step of ``ilcc_graph.estimation.solver.optimize`` (GTSAM's algorithm
  driven from Python on a Python-owned ``Values``: linearise, damped solve, cost).

Run: ``python3 scripts/bench_customfactor.py`` (prints a markdown table; ``--write`` appends it to
docs/bench_graph.md between markers).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gtsam
import numpy as np

SIZES = (250, 500, 1000, 2000)


def _custom_graph(n: int) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Unit.Create(3)
    eye = np.eye(3, order="F")

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        key = this.keys()[0]
        x = values.atPoint3(key)
        if H is not None:
            H[0] = eye
        return x - np.array([float(key), 0.0, 0.0])

    for i in range(n):
        graph.add(gtsam.CustomFactor(noise, [i], error))
    return graph


def _builtin_graph(n: int) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Unit.Create(3)
    for i in range(n):
        graph.add(gtsam.PriorFactorPoint3(i, np.array([float(i), 0.0, 0.0]), noise))
    return graph


def _values(n: int) -> gtsam.Values:
    values = gtsam.Values()
    for i in range(n):
        values.insert(i, np.array([float(i) + 0.5, 1.0, -1.0]))
    return values


def _best_of(fn, repeat: int = 3) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _gn_iteration(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> float:
    params = gtsam.GaussNewtonParams()
    optimizer = gtsam.GaussNewtonOptimizer(graph, values, params)
    t0 = time.perf_counter()
    optimizer.iterate()
    return time.perf_counter() - t0


def _our_step(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> float:
    import logging

    from ilcc_graph.estimation.solver import SolverOptions, optimize

    logging.getLogger("ilcc_graph").setLevel(logging.ERROR)  # one step is the limit on purpose
    t0 = time.perf_counter()
    optimize(graph, values, SolverOptions(max_iterations=1))
    return time.perf_counter() - t0


def run(sizes: tuple[int, ...] = SIZES) -> str:
    rows = [
        "| factors N | linearize, Python Values (ms) | GN iteration, CustomFactor (ms) | "
        "GN iteration, PriorFactorPoint3 (ms) | copy of Values(N) (us) | distinct Values seen in one "
        "GN iteration | one LM step of `solver.optimize`, CustomFactor (ms) |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n in sizes:
        values = _values(n)
        custom = _custom_graph(n)
        builtin = _builtin_graph(n)
        t_lin = _best_of(lambda custom=custom, values=values: custom.linearize(values))
        t_gn_custom = min(_gn_iteration(custom, values) for _ in range(2))
        t_gn_builtin = min(_gn_iteration(builtin, values) for _ in range(3))
        t_ours = min(_our_step(custom, values) for _ in range(3))
        t_copy = _best_of(lambda values=values: gtsam.Values(values), repeat=20)
        # keep every Values the callbacks receive alive, so that ids of freed copies are not reused
        kept: list[gtsam.Values] = []

        def error(this, v, H, kept=kept):  # noqa: ANN001
            kept.append(v)
            if H is not None:
                H[0] = np.eye(3, order="F")
            return v.atPoint3(this.keys()[0]) - np.zeros(3)

        counted = gtsam.NonlinearFactorGraph()
        for i in range(n):
            counted.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), [i], error))
        gtsam.GaussNewtonOptimizer(counted, values, gtsam.GaussNewtonParams()).iterate()
        distinct = len({id(v) for v in kept})
        kept.clear()
        rows.append(
            f"| {n} | {1e3 * t_lin:.1f} | {1e3 * t_gn_custom:.1f} | {1e3 * t_gn_builtin:.1f} | "
            f"{1e6 * t_copy:.0f} | {distinct} | {1e3 * t_ours:.1f} |"
        )
    return "\n".join(rows)


def write_section(path: Path, name: str, text: str) -> None:
    """Put ``text`` between ``<!-- name:begin -->`` and ``<!-- name:end -->`` in ``path``."""
    begin, end = f"<!-- {name}:begin -->", f"<!-- {name}:end -->"
    doc = path.read_text() if path.exists() else ""
    block = f"{begin}\n{text}\n{end}"
    if begin in doc and end in doc:
        doc = doc[: doc.index(begin)] + block + doc[doc.index(end) + len(end) :]
    else:
        doc = doc.rstrip("\n") + "\n\n" + block + "\n"
    path.write_text(doc)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="write the table into docs/bench_graph.md")
    args = parser.parse_args()
    table = run()
    print(table)
    if args.write:
        path = Path(__file__).resolve().parents[1] / "docs" / "bench_graph.md"
        write_section(path, "customfactor", table)
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
