"""The estimation strategies, registered by mode: the one place a mode string is dispatched.

A strategy is ``solve(observations, options, report=None) -> Result``: ``observations`` one
``run.observe.Observation`` per source (plain data the strategy interprets: the config, every
frame's stage results, the session's name; ``Observation.stream`` instead of ``frames`` for a
strategy that reads frames as it solves), ``options`` the run's ``RunOptions``, ``report(line)``
a line to print while it runs (incremental: one per update). A new strategy is one file
``run/strategies/solve_<name>.py`` that calls ``register(Strategy(...))`` and one import line below.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ilcc_graph.run.observe import Observation
    from ilcc_graph.run.result import Result, RunOptions

__all__ = ["Reporter", "Strategy", "choose", "modes", "one", "refinements", "register", "strategy"]

Reporter = Callable[[str], None]


@dataclass(frozen=True)
class Strategy:
    """A registered strategy.

    mode: its name (``RunOptions.mode``). solve: ``(observations, options, report) -> Result``.
    joint: the mode that solves several sources (or a range offset) in its place (itself when it
    can; None: it calibrates one source). streams: it reads the frames as it solves
    (``Observation.stream``); the frames it read are then taken as ``calibrate`` takes them once it
    has an answer (boards on corrected ranges, second look), solved again by ``graph`` when those
    change a board, and ``restate(streamed, again, report)`` gives its result with that answer.
    second_pass: the run looks again for the boards the
    LiDAR stage missed once it has an extrinsic, and solves again. sensor_errors: it estimates the
    sensors' own errors (the LiDAR's are turned on when most boards show no print). observe: the
    observation pass of each source, ``(source, stages, progress) -> Observation`` (None:
    ``observe.observe``; a multi-sensor strategy brings its own and its sources). refinement: a user
    picks it with ``calibrate --refine`` (it refines one pair's frames).
    """

    mode: str
    solve: Callable[[Sequence[Observation], RunOptions, Reporter | None], Result]
    joint: str | None = None
    streams: bool = False
    second_pass: bool = True
    sensor_errors: bool = True
    observe: Callable[..., Observation] | None = None
    refinement: bool = False
    restate: Callable[[Result, Result, Reporter | None], Result] | None = None


_REGISTRY: dict[str, Strategy] = {}


def register(s: Strategy) -> Strategy:
    """Add a strategy under its mode (a strategy module calls it once on import)."""
    if s.mode in _REGISTRY:
        raise ValueError(f"strategy {s.mode!r} registered twice")
    _REGISTRY[s.mode] = s
    return s


def modes() -> tuple[str, ...]:
    """The registered modes, in registration order."""
    return tuple(_REGISTRY)


def refinements() -> tuple[str, ...]:
    """The modes ``calibrate --refine`` offers (``Strategy.refinement``), in registration order."""
    return tuple(m for m, s in _REGISTRY.items() if s.refinement)


def strategy(mode: str) -> Strategy:
    """The strategy registered as ``mode`` (ValueError naming the modes when none is)."""
    try:
        return _REGISTRY[mode]
    except KeyError:
        raise ValueError(f"no strategy {mode!r}; registered: {', '.join(_REGISTRY)}") from None


def choose(options: RunOptions, n_sources: int) -> Strategy:
    """The strategy of ``options.mode`` for ``n_sources`` sources: its ``joint`` one for several
    sources or a range offset (ValueError when the mode calibrates one source)."""
    s = strategy(options.mode)
    if n_sources > 1 or options.joint.range_offset:
        if s.joint is None:
            raise ValueError(
                f"mode {s.mode!r} calibrates one data set without a range offset; {n_sources} were given"
            )
        s = strategy(s.joint)
    return s


def one(observations: Sequence[Observation], mode: str) -> Observation:
    """The only source of a strategy that calibrates one (ValueError otherwise)."""
    if len(observations) != 1:
        raise ValueError(f"mode {mode!r} calibrates one data set; {len(observations)} were given")
    return observations[0]


# the registry: one import per strategy (each module registers itself)
from ilcc_graph.run.strategies import (  # noqa: E402, F401
    solve_graph,
    solve_incremental,
    solve_paper,
    solve_rig,
    solve_sessions,
)
