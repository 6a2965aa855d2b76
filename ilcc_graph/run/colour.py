"""The print's colour (``board.lower_left``) as the images show it.

For a board that looks the same after a half turn (even squares on both sides) the colour of the
lower-left square seen from the front is a property of the print, which the user may have
mistyped; the image stage tells it with certainty (``BoardColourMismatch``). ``colour_votes``
counts the first frames' image results for and against the config; ``check_board_colour`` runs
the image stage on the first frames until enough agree (``source.open_run(colour="now")``), the
batch pass votes on its own first results (``observe.observe``), ``check`` flips on its first image.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable, Iterator, Sequence
from typing import TypeVar

from ilcc_graph.config import Config, RigConfig
from ilcc_graph.datasets import FrameRef, FrameSource
from ilcc_graph.errors import BoardColourMismatch, FrameError
from ilcc_graph.run.stages import StageOptions, attempt, observe_image

log = logging.getLogger(__name__)

__all__ = ["check_board_colour", "colour_votes", "colour_warning", "other_colour"]


#: a pair's ``Config`` or a rig's ``RigConfig``: both hold the one ``board`` and their ``source``
C = TypeVar("C", Config, RigConfig)


def other_colour(config: C) -> C:
    """The config (a pair's or a rig's) with the other ``board.lower_left`` colour."""
    board = config.board
    other = "white" if board.lower_left == "black" else "black"
    return dataclasses.replace(config, board=dataclasses.replace(board, lower_left=other))


def check_board_colour(
    source: FrameSource,
    refs: Sequence[FrameRef],
    config: Config,
    options: StageOptions = StageOptions(),
    needed: int = 2,
    look: int = 6,
) -> tuple[Config, dict[str, object]]:
    """The config with ``board.lower_left`` as the images show it, and the image results computed.

    For a board that looks the same after a half turn (even squares on both sides) the colour of the
    lower-left square seen from the front is a property of the print, which the user may have
    mistyped. The image stage tells it with certainty; this looks at up to ``look`` frames until
    ``needed`` agree and turns the setting (with a warning) when the images contradict it. Returns
    the image stage's results (ImageCorners or FrameError) of the frames looked at when they hold
    for the config returned, so that they need not be computed again.
    """
    if not config.board.half_turn_symmetric:
        return config, {}
    seen: dict[str, object] = {}

    def results() -> Iterator[object]:
        for ref in refs[:look]:
            if ref.image is not None:
                seen[ref.name] = attempt(observe_image, source, ref, config, options)
                yield seen[ref.name]

    agree, disagree = colour_votes(results(), needed)
    if disagree <= agree:
        return config, seen
    return colour_warning(config, f"{disagree} of {agree + disagree} images checked"), {}


def colour_votes(results: Iterable[object], needed: int = 2) -> tuple[int, int]:
    """(agree, disagree): the image stage's results (ImageCorners, FrameError or None, in frame
    order; read until ``needed`` agree either way) that hold or contradict ``board.lower_left``
    (``BoardColourMismatch``)."""
    agree = disagree = 0
    for res in results:
        if isinstance(res, BoardColourMismatch):
            disagree += 1
        elif res is not None and not isinstance(res, FrameError):
            agree += 1
        if max(agree, disagree) >= needed:
            break
    return agree, disagree


def colour_warning(config: C, evidence: str) -> C:
    """The config (a pair's or a rig's) with the other print colour, said once (``evidence``: where
    the images say so)."""
    turned = other_colour(config)
    log.warning(
        "%s: board.lower_left is %s, but the print's lower-left square (seen from the front, long side "
        "horizontal) is %s in the %s; using %s", config.source, config.board.lower_left,
        turned.board.lower_left, evidence, turned.board.lower_left,
    )  # fmt: skip
    return turned
