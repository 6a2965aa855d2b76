"""The run: sources -> open and observe -> the strategy of the mode -> the boards on corrected ranges
-> the second look -> a Result.

``run(sources, options)`` observes each source once (``observe.observe``; a streaming strategy
reads ``observe.FrameStream`` as it solves), hands the observations to the strategy the registry
gives for the mode (``strategies.choose``), fits the boards again on corrected ranges when the LiDAR's
estimated range errors are large (``range_refit``), looks again for the boards the LiDAR stage
missed where the answer puts them (``second_look``), solving again after each that changed a board,
and says which set-up mistake explains a failure (``setup_mistakes``). ``solve_observations``: the
same on observations made once (studies, benchmarks). Only sources read files; ``app.write`` writes
the ``Result``.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, cast

from ilcc_graph import signals
from ilcc_graph.config import Config
from ilcc_graph.datasets import FrameSource, RigSource
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.run.after import after, without_print
from ilcc_graph.run.observe import FrameStream, Observation, observe
from ilcc_graph.run.result import Result, RunOptions
from ilcc_graph.run.setup_mistakes import diagnose_failure, diagnose_result
from ilcc_graph.run.strategies import Reporter, choose, strategy
from ilcc_graph.types import Calibration, FrameResult

if TYPE_CHECKING:
    import gtsam
    import numpy as np

log = logging.getLogger(__name__)

__all__ = ["calibrate", "run", "session_names", "solve_observations", "solve_observed"]


def session_names(sources: Sequence[FrameSource | RigSource | None]) -> list[str]:
    """Source labels made unique (with an index where two share one); ``session<k>`` for a source
    without a label, or none (frames observed without their source)."""
    labels = [(s.label if s is not None else "") or f"session{i + 1}" for i, s in enumerate(sources)]
    return [f"{n}#{i + 1}" if labels.count(n) > 1 else n for i, n in enumerate(labels)]


def run(
    sources: Sequence[FrameSource] | Sequence[RigSource],
    options: RunOptions = RunOptions(),
    progress: Callable[[str, int, int], None] | None = None,
    report: Reporter | None = None,
) -> Result:
    """Calibrate from one or more sources in the mode of ``options`` (several sources: sessions).

    progress(source label, done, total) reports the per-frame stages; report(line) what a strategy
    says while it solves (incremental: each update). Raises InputError (bad input),
    CalibrationImpossible, IndeterminateSystem.
    """
    if not sources:
        raise ValueError("run: no source given")
    names = session_names(sources)
    chosen = choose(options, len(sources))
    if chosen.streams:
        first = cast(FrameSource, sources[0])  # a streaming strategy reads one pair's frames
        stream = FrameStream(first, options.stages)
        obs = Observation(first, stream.config, [], names[0], stream)
        opts = dataclasses.replace(options, mode=chosen.mode)
        streamed = chosen.solve([obs], opts, report)
        # the frames it read, as calibrate solves them once it has an answer (the batch strategy; first
        # under calibrate's noise policy when that differs from the stream's)
        seen, graph = [s.observation for s in streamed.sessions], strategy("graph")
        batch = without_print(seen, opts, graph)
        answer = streamed if batch is opts else graph.solve(seen, batch, None)
        again = after(graph, batch, answer, seen)
        if again is streamed or chosen.restate is None:
            return streamed
        return chosen.restate(streamed, again, report)
    observations = []
    for name, src in zip(names, sources, strict=True):
        cb = None if progress is None else (lambda i, n, name=name: progress(name, i, n))
        observe_source: Callable[..., Observation] = chosen.observe or observe  # a rig's: its own
        observed = observe_source(src, options.stages, cb)
        observations.append(dataclasses.replace(observed, name=name))
    signals.check()
    try:
        result = solve_observations(observations, dataclasses.replace(options, mode=chosen.mode))
    except CalibrationImpossible as err:  # say what set-up mistake explains it, when one does
        if not (hints := diagnose_failure(observations, options.stages)):
            raise
        advice = "\n".join(f"likely: {h}" for h in hints)  # the set-up mistake is the better advice
        raise CalibrationImpossible(str(err), err.frames, advice) from None
    for s in result.sessions:
        for line in diagnose_result(s.observation, s.calibration):
            log.warning("%s", line)
    return result


def solve_observations(
    observations: Sequence[Observation],
    options: RunOptions = RunOptions(),
    names: Sequence[str] | None = None,
) -> Result:
    """The strategy of ``options.mode`` on observed sources (``sessions`` for several, or with a
    range offset); ``names`` label the sessions (default: the observations' names, else the
    sources' labels). With ``options.range_refit`` the boards are fitted again on the ranges
    corrected by the LiDAR's estimated errors when those are large, and solved again. With
    ``options.second_pass`` the boards the LiDAR stage missed are searched where the answer puts
    them, and the data solved again when some are found. A solve again that cannot calibrate leaves
    the answer before it (a warning says so)."""
    if names is None and not all(o.name for o in observations):
        names = session_names([o.source for o in observations])
    if names is not None:
        observations = [dataclasses.replace(o, name=n) for o, n in zip(observations, names, strict=True)]
    chosen = choose(options, len(observations))
    if chosen.streams:
        raise ValueError(f"{chosen.mode} mode observes frame by frame: use run()")
    options = without_print(observations, dataclasses.replace(options, mode=chosen.mode), chosen)
    log.debug("estimating the extrinsic (%s) from %d source(s)", chosen.mode, len(observations))
    result = chosen.solve(observations, options, None)
    return after(chosen, options, result, observations)


def solve_observed(
    observed: Sequence[FrameResult], config: Config, options: RunOptions = RunOptions()
) -> Calibration:
    """The calibration of one source's observed frames by the strategy of ``options.mode`` (no
    second look), with ``calibrate``'s noise policy for them (the LiDAR's errors estimated when most
    boards were placed by their outline, not said again): the report's studies and the benchmarks
    refit subsets with it."""
    obs = Observation(None, config, list(observed), "frames")
    chosen = strategy(options.mode)
    return chosen.solve([obs], without_print([obs], options, chosen, say=False), None).calibration


def calibrate(data: str, options: RunOptions = RunOptions()) -> tuple[gtsam.Pose3, np.ndarray]:
    """Python API: the extrinsic of the data set at ``data`` as ``gtsam.Pose3`` (T_cam_lidar) and its
    6x6 covariance (interface.md convention)."""
    from ilcc_graph.datasets import open_source

    cal = run([open_source(data)], options).calibration
    return cal.extrinsic.pose, cal.covariance
