"""What a factor kind supplies to the assembly, and the registry of kinds (in graph order).

A kind is one sort of evidence or prior in the graph of a set of boards: it builds its factors once
from the problem (``__init__``), gives the factors of any subset of boards under any variance
scaling with their ``Term`` bookkeeping (``graph``), and owns the variables of one key letter, if
any: which of them the graph holds (``keys``), their dimension (``dim``), start value (``initial``)
and how to read them from a solution (``read``). ``X(e)`` and ``B(i)`` are the assembly's own.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import gtsam
import numpy as np

from ilcc_graph.estimation.graphs import Scales

if TYPE_CHECKING:
    from ilcc_graph.estimation.assembly import Assembly

__all__ = ["KINDS", "FactorKind", "Scales", "Term", "register"]


@dataclass(frozen=True)
class Term:
    """What one factor of an assembled graph is: ``kind`` board / bearing / tie / offset / lidar /
    intrinsics, its noise ``group`` (scaled by the variance components of board and bearing terms)
    and its board (or None)."""

    kind: str
    group: str
    board: int | None
    dim: int
    parts: tuple[tuple[str, int, int], ...] = ()  # (kind, first row, end row) when rows differ in kind


class FactorKind:
    """One kind of factor (module docstring). ``name``: unique; ``order``: its place in the graph
    (ascending); ``term``: the ``Term.kind`` of its factors; ``letter``: the key letter of the
    variables it owns, if any; ``global_prior``: its terms are priors on global variables, whose
    chi-square enters the graph's variance factor as it is."""

    name: ClassVar[str] = ""
    order: ClassVar[int] = 0
    term: ClassVar[str] = ""
    letter: ClassVar[str | None] = None
    global_prior: ClassVar[bool] = False

    def __init__(self, asm: Assembly) -> None:
        self.asm = asm

    def graph(
        self, boards: Sequence[int], scales: Scales, plain: bool
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        """Its factors in the graph of ``boards`` (problem order) under ``scales``; ``plain``: no
        robust kernel."""
        raise NotImplementedError

    def keys(self, boards: Sequence[int]) -> list[int]:
        """The variables it owns that the graph of ``boards`` holds."""
        return []

    def sightings(self) -> dict[int, int]:
        """Per board, how many LiDARs' poses of it its factors hold (a board no camera saw is of use
        when LiDARs saw it twice)."""
        return {}

    def dim(self, key: int) -> int:
        """Tangent dimension of its variable ``key``."""
        raise KeyError(key)

    def initial(self, key: int, known: Mapping[int, object]) -> object:
        """Start value of its variable ``key``: ``known[key]`` when it fits, else its default."""
        raise KeyError(key)

    def read(self, values: gtsam.Values, key: int) -> object:
        """Its variable ``key`` in a solution (a vector by default)."""
        return np.asarray(values.atVector(key))


#: every registered kind, in graph order
KINDS: list[type[FactorKind]] = []


def register(cls: type[FactorKind]) -> type[FactorKind]:
    """Class decorator: add a kind to ``KINDS`` (kept in ``order``; names and letters unique)."""
    if any(k.name == cls.name for k in KINDS):
        raise ValueError(f"factor kind {cls.name!r} registered twice")
    if cls.letter is not None and any(k.letter == cls.letter for k in KINDS):
        raise ValueError(f"factor kinds {cls.name!r} and another own the key letter {cls.letter!r}")
    KINDS.append(cls)
    KINDS.sort(key=lambda k: k.order)
    return cls
