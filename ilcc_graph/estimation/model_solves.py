"""The candidate sensor models solved on one problem and the choice among them (``selection``'s rule).

``solve_models`` solves a problem without sensor terms under each candidate (the one noise policy,
``noise.solve_problem``), scores each by its held-out boards (``held_out``) and drops a board whose
image the other boards contradict under every model (``held_out.held_out_gate``; then every model is
solved again without it); ``select_model`` chooses from one problem's solves, ``decide`` from scores
(also from a benchmark's cached solves).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem
from ilcc_graph.estimation.held_out import HeldOut, held_out, held_out_gate
from ilcc_graph.estimation.noise import NoiseOptions, Solution, solve_problem
from ilcc_graph.estimation.problem import Problem
from ilcc_graph.estimation.selection import (
    AUTO_MODELS,
    BoardKey,
    Candidate,
    Selection,
    SensorModel,
    candidates,
    choose,
    contradicted,
    range_terms,
)

log = logging.getLogger(__name__)

__all__ = ["Solved", "decide", "select_model", "solve_models"]


@dataclass
class Solved:
    """Each candidate model solved on one problem: the candidates (``candidates``' rule applied), the
    solutions by name (failed ones left out), why the others failed and the first error, with
    several candidates each one's held-out ``scores`` (per (extrinsic, board)) and ``range_terms``."""

    models: list[SensorModel]
    sols: dict[str, Solution]
    failures: dict[str, str]
    first: Exception | None
    scores: dict[str, dict[tuple[int, int], HeldOut]]
    terms: dict[str, tuple[float, int]]

    @property
    def names(self) -> list[str]:
        return [m.name for m in self.models]


def solve_models(
    base: Problem,
    models: Sequence[SensorModel] = AUTO_MODELS,
    options: NoiseOptions = NoiseOptions(),
    solve: Callable[..., Solution] = solve_problem,
) -> Solved:
    """``base`` (a problem without sensor terms) solved under each of ``models``, scored when there
    are several (``select_model`` chooses from it; the sessions choose from every session's). A board
    that fails ``held_out_gate`` is excluded from ``base`` (``Problem.excluded``, with its reason) and
    every model solved again, within the gate's ``max_dropped_fraction``."""
    while True:
        got = _solve_models(base, models, options, solve)
        if not options.chi2_gate_prob or not got.scores:
            return got
        index = {b.name: k for k, b in enumerate(base.boards)}
        gated = {n: {index[d] for d, _ in sol.dropped if d in index and d not in base.excluded}
                 for n, sol in got.sols.items()}  # fmt: skip
        worst = held_out_gate(got.scores, gated)
        sol = next(iter(got.sols.values()))
        usable = len(sol.boards) + len(sol.dropped)
        if worst is None or len(sol.dropped) + 1 > math.floor(options.max_dropped_fraction * usable):
            return got
        k, why = worst
        name = base.boards[k].name
        log.info("dropping frame %s: %s", name, why)
        base = replace(base, excluded={**base.excluded, name: why})


def _solve_models(
    base: Problem,
    models: Sequence[SensorModel],
    options: NoiseOptions,
    solve: Callable[..., Solution],
) -> Solved:
    """``solve_models`` without the held-out gate."""
    models = candidates(models, any(b.returns is not None and b.returns.corrected for b in base.boards))
    out = Solved(list(models), {}, {}, None, {}, {})
    for model in models:
        try:
            out.sols[model.name] = solve(model.problem(base), options)
        except (CalibrationImpossible, IndeterminateSystem, np.linalg.LinAlgError) as err:
            out.failures[model.name] = str(err)
            out.first = out.first or err
            log.info("sensor model %s: cannot solve: %s", model.name, err)
    if len(models) == 1:
        return out
    for name, sol in out.sols.items():
        try:  # every camera's views (a rig's): (extrinsic, board)
            out.scores[name] = {
                (e, k): h for e in sol.problem.extrinsics for k, h in held_out(sol, e).items()
            }
        except np.linalg.LinAlgError as err:  # a singular held-out system: no score, no weight
            out.failures[name] = f"held-out score: {err}"
    out.terms = {n: range_terms(sol) for n, sol in out.sols.items()}  # (0, 0): no range terms
    return out


def select_model(
    base: Problem,
    models: Sequence[SensorModel] = AUTO_MODELS,
    options: NoiseOptions = NoiseOptions(),
    solve: Callable[..., Solution] = solve_problem,
) -> tuple[dict[str, Solution], Selection]:
    """Solve ``base`` (a problem without sensor terms) under each of ``models`` and choose (module
    docstring). Returns the solutions by model name (failed candidates left out) and the selection.
    With one model the choice is forced. Raises the first candidate's error when every one fails.
    Boards fitted on corrected ranges (``BoardReturns.corrected``) rest on the LiDAR's estimated
    errors: only the models with range terms are candidates then."""
    got = solve_models(base, models, options, solve)
    sols, names = got.sols, got.names
    if not sols:
        assert got.first is not None
        raise got.first
    if len(names) == 1:
        return sols, Selection(
            names[0], (Candidate(names[0], used=len(sols[names[0]].boards), weight=1.0),), True
        )
    used = {n: len(sol.boards) for n, sol in sols.items()}
    solved = [m for m in got.models if m.name in sols]
    return sols, decide(got.scores, used, names, got.failures, got.terms, solved)


def decide(
    scores: Mapping[str, Mapping[BoardKey, HeldOut]],
    used: Mapping[str, int],
    names: Sequence[str],
    failures: Mapping[str, str] | None,
    terms: Mapping[str, tuple[float, int]],
    solved: Sequence[SensorModel],
) -> Selection:
    """``choose`` with the models the ``terms`` (each solved model's ``range_terms``) contradict left
    out (``contradicted``, said at INFO): the choice ``select_model`` makes, also from cached solves
    (scripts/bench_sensor_model.py)."""
    left_out = contradicted(terms, solved)
    for name, why in left_out.items():
        log.info("sensor model %s left out: %s", name, why)
    return choose(scores, used, names, failures, left_out)
