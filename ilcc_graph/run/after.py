"""The noise policy a run takes for its observations (``without_print``: the LiDAR's errors estimated
when most boards show no print) and the steps it takes once it has an answer (issue 34: one solve
session for every door): the boards fitted again on the ranges the LiDAR's estimated errors correct
(``range_refit``; a rig's base LiDAR through ``rig_views``), the second look for the boards the
LiDAR stage missed where the answer puts them (``second_look``), each solved again by the same
strategy when it changed a board.
``pipeline`` takes them after every strategy's answer; the incremental strategy takes them on the
frames read so far before it stops at its target, so it stops only where ``calibrate``'s answer does.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ilcc_graph.errors import CalibrationImpossible, IndeterminateSystem
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.range_refit import refit_pass
from ilcc_graph.run.result import Result, RunOptions
from ilcc_graph.run.rig_observe import RigObservation
from ilcc_graph.run.rig_views import look_rig, refit_rig
from ilcc_graph.run.second_look import second_pass
from ilcc_graph.types import BoardFit

if TYPE_CHECKING:  # the strategies take these steps themselves (the incremental one): no import cycle
    from ilcc_graph.run.strategies import Strategy

log = logging.getLogger(__name__)

__all__ = ["after", "mostly_outline", "solve_again", "without_print"]


def after(
    chosen: Strategy, options: RunOptions, result: Result, observations: Sequence[Observation]
) -> Result:
    """``result`` (the strategy ``chosen``'s on ``observations``) after the steps a run takes once it
    has an answer: the boards on corrected ranges, the second look, each solved again by ``chosen``
    when it changed a board; ``result`` itself when none did."""
    if not chosen.second_pass:
        return result
    corrected = False  # the boards on corrected ranges: the second look searches on them too
    stages = options.stages
    if options.range_refit:
        refit = [
            refit_pass(s.observation, s.alone, stages) if result.rig is None
            else refit_rig(s.observation, result.rig.T_ref_sensor, s.alone.sensors, stages)
            for s in result.sessions
        ]  # fmt: skip
        what = "fitted on corrected ranges"
        result, observations, corrected = solve_again(chosen, options, result, observations, refit, what)
    if not options.second_pass:
        return result
    again = [
        second_pass(s.observation, s.alone, stages, refit=corrected) if result.rig is None
        else look_rig(s.observation, result.rig, s.alone.sensors, stages, refit=corrected)
        for s in result.sessions
    ]  # fmt: skip
    return solve_again(chosen, options, result, observations, again, "found by the second look")[0]


def solve_again(
    chosen: Strategy, options: RunOptions, result: Result, observations: Sequence[Observation],
    changed: Sequence[Observation | None], what: str,
) -> tuple[Result, list[Observation], bool]:  # fmt: skip
    """(the result, the observations, True) with the ``changed`` ones (None: unchanged) solved again;
    ``result``, the observations as they were and False when none changed or the solve of the changed
    ones fails (said)."""
    if all(a is None for a in changed):
        return result, list(observations), False
    again = [o if a is None else a for o, a in zip(observations, changed, strict=True)]
    try:
        return chosen.solve(again, options, None), again, True
    except (CalibrationImpossible, IndeterminateSystem) as err:
        log.warning("the boards %s do not calibrate (%s): the answer without them stands", what, err)
        return result, list(observations), False


def without_print(
    observations: Sequence[Observation], options: RunOptions, chosen: Strategy, say: bool = True
) -> RunOptions:
    """The options with the LiDAR's errors estimated when most boards were placed by their outline
    (``RunOptions.lidar_errors_without_print``), said once (with ``say``); as given otherwise."""
    if options.lidar_errors is not None or not options.lidar_errors_without_print or not chosen.sensor_errors:
        return options
    boards = [b for o in observations for b in _boards(o)]
    if (plain := mostly_outline(boards)) is None:
        return options
    (log.warning if say else log.debug)(
        "%d of %d boards were placed by their outline: the LiDAR's own errors (each beam's range offset) "
        "are estimated, as with --lidar-errors, since the boards' planes then carry the translation",
        plain, len(boards),
    )  # fmt: skip
    return dataclasses.replace(options, lidar_errors=LidarErrorOptions())


def _boards(o: Observation) -> list[BoardFit]:
    """The boards of an observation whose LiDAR errors the graph would estimate: a pair's used frames',
    a rig's base LiDAR's (``rig_observe.RigObservation``)."""
    if isinstance(o.data, RigObservation):
        base = o.data.rig.lidars[0]
        return [m.boards[base] for m in o.data.moments if base in m.boards]
    return [f.board for f in o.frames if f.used and f.board is not None]


def mostly_outline(boards: Sequence[BoardFit]) -> int | None:
    """How many of ``boards`` were placed by their outline (no print in the LiDAR's intensity) when
    they are most of them, else None (``without_print``)."""
    plain = sum(1 for b in boards if b.diagnostics.get("no_contrast"))
    return plain if boards and 2 * plain > len(boards) else None
