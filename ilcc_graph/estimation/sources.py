"""The one solve of one source or of several sessions: the sensor model chosen, each source solved.

Every source (a data set's problem without sensor terms) is solved under each candidate model by the
one noise policy (``model_solves.solve_models``: gate, variance components, held-out scores); the model
is chosen once for all of them (``model_solves.decide`` on the boards of every source; one source: exactly
``model_solves.select_model``'s choice); with that model the camera's intrinsics are refined when asked,
or when the boards support it (``camera_choice``; several sources: when every source's do). The batch
strategy (``batch.solve``) is the one-source case; the sessions (``sessions.solve_sessions``) join the
sources' answers under the noise each found.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

from ilcc_graph.estimation.camera_choice import CameraChoice, choose_intrinsics
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.model_solves import Solved, decide, select_model, solve_models
from ilcc_graph.estimation.noise import NoiseOptions, Solution, solve_problem
from ilcc_graph.estimation.problem import Problem
from ilcc_graph.estimation.selection import Candidate, Selection, SensorModel

__all__ = ["Chosen", "solve_sources"]


@dataclass(frozen=True)
class Chosen:
    """The sources solved: per source its solutions by model (``sols``) and its answer under the
    chosen model (``chosen``: with the intrinsics refined when ``refined``, else ``sols[k][chosen
    model]``); the selection (the model, the evidence, the camera's choice); per source the choice
    its own boards make (``own``: the weights its own covariance is averaged with, as ``calibrate``
    of it alone averages)."""

    sols: list[dict[str, Solution]]
    chosen: list[Solution]
    selection: Selection
    refined: bool = False
    own: list[Selection] = field(default_factory=list)


def solve_sources(
    bases: Sequence[Problem],
    models: Sequence[SensorModel],
    options: NoiseOptions = NoiseOptions(),
    intrinsics: IntrinsicsOptions | None = None,
    intrinsics_choice: str = "stated",
    solve: Callable[..., Solution] = solve_problem,
) -> Chosen:
    """Choose the sensor model among ``models`` for the ``bases`` (problems without sensor terms, one per
    source) and solve each under it (module docstring). ``intrinsics``: refine the camera's intrinsics
    (after the choice, which is made with them as stated), or propagate their stated sigmas;
    ``intrinsics_choice``: ``auto`` refines them when the boards support it (``camera_choice``).
    Raises CalibrationImpossible, IndeterminateSystem (every candidate of some source failed)."""
    refine = intrinsics is not None and intrinsics.refine
    # a choice among LiDAR models is made with the intrinsics as stated (the held-out images' poses
    # need them); a forced model is solved as asked
    stated = intrinsics if len(models) == 1 or intrinsics is None else replace(intrinsics, refine=False)
    bases = [replace(b, intrinsics=stated) for b in bases]
    if len(bases) == 1:
        one, selection = select_model(bases[0], models, options, solve)
        sols, own = [one], [selection]
    else:
        sols, selection, own = _select_joint(bases, models, options, solve)
    plain = [s[selection.chosen] for s in sols]
    if refine and len(models) > 1:  # refined as asked, with the LiDAR model chosen
        again = [solve(replace(s.problem, intrinsics=intrinsics), options) for s in plain]
        return Chosen(sols, again, selection, True, own)
    if intrinsics_choice != "auto" or refine:
        return Chosen(sols, plain, selection, False, own)
    choices = [choose_intrinsics(s.problem, options) for s in plain]
    refined = all(r is not None for r, _ in choices)
    selection = replace(selection, camera=_camera(choices, refined))
    answers = [r for r, _ in choices] if refined else plain
    return Chosen(sols, answers, selection, refined, own)  # type: ignore[arg-type]


def _camera(
    choices: Sequence[tuple[Solution | None, CameraChoice | None]], refined: bool
) -> CameraChoice | None:
    """The camera's choice to report: the first source's when all refine, else the first that did not."""
    if refined:
        return choices[0][1]
    return next((c for r, c in choices if r is None), None)


def _select_joint(
    bases: Sequence[Problem],
    models: Sequence[SensorModel],
    options: NoiseOptions,
    solve: Callable[..., Solution],
) -> tuple[list[dict[str, Solution]], Selection, list[Selection]]:
    """Several sources: each solved under every candidate, one choice from the boards of all (held-out
    scores keyed by source; range terms' chi-squares summed, independent sources; a candidate that
    fails for some source fails), and each source's own choice."""
    got: list[Solved] = [solve_models(b, models, options, solve) for b in bases]
    for g in got:
        if not g.sols:
            assert g.first is not None
            raise g.first
    names = got[0].names  # the same rule for every source but for boards on corrected ranges
    common = [n for n in names if all(n in g.sols for g in got)]
    if not common:
        raise next(g.first for g in got if g.first is not None)
    sols = [{n: g.sols[n] for n in common} for g in got]
    failures = {n: why for g in got for n, why in g.failures.items()}
    used = {n: sum(len(s[n].boards) for s in sols) for n in common}
    if len(names) == 1:
        name = names[0]
        return sols, _forced(name, used[name]), [_forced(name, len(s[name].boards)) for s in sols]
    scored = [n for n in common if all(n in g.scores for g in got)]
    scores = {n: {(k, *key): h for k, g in enumerate(got) for key, h in g.scores[n].items()} for n in scored}
    terms = {n: (sum(g.terms[n][0] for g in got), sum(g.terms[n][1] for g in got)) for n in common}
    solved = [m for m in got[0].models if m.name in common]
    own = [_own(g, s, scored, solved) for g, s in zip(got, sols, strict=True)]
    return sols, decide(scores, used, names, failures, terms, solved), own


def _forced(name: str, used: int) -> Selection:
    """The selection of a forced model that kept ``used`` boards."""
    return Selection(name, (Candidate(name, used=used, weight=1.0),), True)


def _own(got: Solved, sols: dict[str, Solution], scored: list[str], solved: list[SensorModel]) -> Selection:
    """One source's own choice among the candidates every source solved and scored."""
    used = {n: len(s.boards) for n, s in sols.items()}
    scores = {n: got.scores[n] for n in scored}
    return decide(scores, used, got.names, got.failures, {n: got.terms[n] for n in sols}, solved)
