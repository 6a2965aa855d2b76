"""The observation pass: the per-frame stages over an opened source (``source.open_run``).

``observe`` runs both stages on every frame (a ``FrameError`` skips the frame with its reason; a
frame file that cannot be read is a ``DamagedFile``, which skips the frame too unless
``StageOptions.strict``; other ``InputError`` propagate) on ``StageOptions.jobs`` processes
(``workers.py``) and decides the print's colour from the first frames' image results as they come,
so that no frame waits for it. ``FrameStream`` gives the frames one at a time for a strategy that
reads them as it solves (incremental), on the same processes a few frames ahead. ``stage_alone``:
one stage over every frame.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

from ilcc_graph import signals, workers
from ilcc_graph.config import Config, RigConfig
from ilcc_graph.datasets import FrameRef, FrameSource, RigSource
from ilcc_graph.errors import FrameError, InputError
from ilcc_graph.run.colour import colour_votes, colour_warning
from ilcc_graph.run.rig_observe import RigObservation
from ilcc_graph.run.source import Opened, open_run
from ilcc_graph.run.stages import (
    StageOptions,
    attempt,
    observe_frame,
    observe_image,
    observe_lidar,
    warn_margin,
    warn_no_print,
)
from ilcc_graph.types import FrameResult

log = logging.getLogger(__name__)

__all__ = [
    "FrameStream",
    "Observation",
    "Progress",
    "observe",
    "stage_alone",
    "warn_damaged",
]

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class Observation:
    """A source observed: the config used (print colour checked) and every frame's stage results
    (frames without a partner come last, unused, with the reason); ``name``: the session's name in
    a run (the source's label made unique); ``stream``: for a strategy that reads the frames as it
    solves, the frames still to observe (``frames`` then empty); ``data``: a rig's observation
    (each moment's results per sensor: the rig strategy's own pass, ``Strategy.observe``), else None.
    Plain data a strategy interprets.

    source: a pair's ``FrameSource``, a rig's ``RigSource`` (the rig strategy's pass; ``config``
    then holds its ``RigConfig``), or None for frames observed elsewhere (``pipeline.solve_observed``).
    What reads a pair's frames again takes ``pair_source`` and ``pair_config`` (a rig's pairs:
    ``run.rig_views``)."""

    source: FrameSource | RigSource | None
    config: Config | RigConfig
    frames: list[FrameResult]
    name: str = ""
    stream: FrameStream | None = None
    data: RigObservation | None = None

    @property
    def pair_config(self) -> Config:
        """The single pair's config, which what reads a pair's frames takes; a ValueError for a
        rig's observation (its ``RigConfig`` is ``config``; its pairs: ``RigConfig.pair_config``)."""
        if not isinstance(self.config, Config):
            raise ValueError(f"{self.name or 'the observation'}: a rig's, not a single pair's")
        return self.config

    @property
    def pair_source(self) -> FrameSource | None:
        """The source when it is a pair's, whose frames can be read again; else None."""
        return self.source if isinstance(self.source, FrameSource) else None

    @property
    def rig_source(self) -> RigSource | None:
        """The source when it is a rig's; else None."""
        return self.source if isinstance(self.source, RigSource) else None

    @property
    def location(self) -> str:
        """Where the data is, for messages and reports ("" without a source)."""
        return "" if self.source is None else self.source.location


def _observe_frame_errors(source: FrameSource, ref: FrameRef, config: Config, options: StageOptions,
                          image: object = None) -> tuple[FrameResult, object]:  # fmt: skip
    """``observe_frame`` and the image stage's error (or None), for the colour verdict."""
    res = image
    if res is None:
        res = attempt(observe_image, source, ref, config, options)
    fr = observe_frame(source, ref, config, options, res)
    return fr, res if isinstance(res, FrameError) else None


def observe(
    source: FrameSource, options: StageOptions = StageOptions(), progress: Progress | None = None
) -> Observation:
    """Open a source (``open_run``), run both stages per frame (damaged frames skipped with a
    warning, or InputError with ``strict``), check the print's colour.

    The colour check judges the first frames' image results as they come from the run over every
    frame; when the images contradict the config's ``board.lower_left``, the stages run again on
    every frame with the other colour.
    """
    if options.jobs > 1:
        workers.prestart()  # the fork server imports the stages while this process checks the config
    opened = open_run(source, options, colour="later")
    config, refs = opened.config, opened.refs
    signals.check()
    items = [(source, r, config, options) for r in refs]
    done = workers.map_processes(_observe_frame_errors, items, options.jobs, progress)
    frames = [fr for fr, _ in done]
    agree, disagree = colour_votes(err if err is not None else fr.corners for fr, err in done[:6])
    if config.board.half_turn_symmetric and disagree > agree:
        config = colour_warning(config, "images checked")
        items = [(source, r, config, options) for r in refs]
        frames = workers.map_processes(observe_frame, items, options.jobs, progress)
    warn_damaged(frames)
    boards = [f.board for f in frames if f.board is not None]
    warn_no_print(boards, config.source)
    warn_margin(boards, config.board, config.source)
    frames += [FrameResult(name=n, used=False, reason=why) for n, why in source.skipped()]
    return Observation(source, config, frames)


class FrameStream:
    """A source's frames observed one at a time, as a strategy reads them (the print's colour
    checked on the first images first: ``open_run(colour="now")``)."""

    def __init__(self, source: FrameSource, options: StageOptions = StageOptions()) -> None:
        self.opened: Opened = open_run(source, options, colour="now")
        self.options = options

    @property
    def config(self) -> Config:
        return self.opened.config

    def __iter__(self) -> Iterator[FrameResult]:
        """The frames in order; with ``StageOptions.jobs`` > 1 observed on that many processes a few
        frames ahead of the reader (what is ahead when the reader stops is dropped: not read, as
        ``unread`` says)."""
        o = self.opened
        items = [(o.source, ref, o.config, self.options, o.seen.get(ref.name)) for ref in o.refs]
        with contextlib.closing(workers.imap_processes(observe_frame, items, self.options.jobs)) as frames:
            yield from frames

    def unread(self, read: Sequence[FrameResult], why: str) -> list[FrameResult]:
        """The frames not read (with ``why``) and what could not become a frame, after ``read``."""
        names = {f.name for f in read}
        rest = [FrameResult(r.name, False, why) for r in self.opened.refs if r.name not in names]
        return rest + [FrameResult(name=n, used=False, reason=w) for n, w in self.opened.source.skipped()]


def warn_damaged(frames: Sequence[FrameResult]) -> None:
    """A warning per damaged frame; InputError when no frame's files can be read at all."""
    for f in frames:
        if f.damaged:
            log.warning("%s: skipped, %s", f.name, f.reason)
    if frames and all(f.damaged for f in frames):
        raise InputError(
            f"no frame's files can be read ({len(frames)} damaged): "
            + "; ".join(f"{f.name}: {f.reason}" for f in frames[:3])
        )


def stage_alone(
    source: FrameSource, stage: str, options: StageOptions, progress: Progress | None = None
) -> tuple[Config, list[FrameRef], list]:
    """One stage (``lidar`` or ``image``) over every frame that has its file: (config used, refs,
    per frame the stage's answer or its FrameError). The config is checked as for a calibration."""
    if options.jobs > 1:
        workers.prestart()
    image = stage == "image"
    opened = open_run(source, options, colour="now", sizes=image, require_image=image, require_scan=not image)
    config, refs = opened.config, opened.refs
    signals.check()
    fn = observe_image if image else observe_lidar
    items = [(fn, source, r, config, options) for r in refs]
    return config, refs, workers.map_processes(attempt, items, options.jobs, progress)
