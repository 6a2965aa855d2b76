"""A weak zero-mean prior on each LiDAR's range offset ``O(l)`` (Vector1, metres) when the problem
estimates one (``Problem.range_offset_sigma_m``); owns the ``O`` variables that the boards' priors
(``board_prior``) then enter."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import gtsam
import numpy as np

from ilcc_graph.estimation.graphs import offset_prior_graph
from ilcc_graph.estimation.keys import O
from ilcc_graph.estimation.kinds.base import FactorKind, Scales, Term, register

__all__ = ["OffsetPrior"]


@register
class OffsetPrior(FactorKind):
    name = "offset_prior"
    order = 50
    term = "offset"
    letter = "o"
    global_prior = True

    def _lidars(self, boards: Sequence[int]) -> list[int]:
        return [] if self.asm.problem.range_offset_sigma_m is None else self.asm.lidars(boards)

    def graph(
        self, boards: Sequence[int], scales: Scales, plain: bool
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        lidars = self._lidars(boards)
        if not lidars:
            return gtsam.NonlinearFactorGraph(), []
        graph = offset_prior_graph(lidars, float(self.asm.problem.range_offset_sigma_m))  # type: ignore[arg-type]
        return graph, [Term(self.term, "", None, 1) for _ in lidars]

    def keys(self, boards: Sequence[int]) -> list[int]:
        return [O(lid) for lid in self._lidars(boards)]

    def dim(self, key: int) -> int:
        return 1

    def initial(self, key: int, known: Mapping[int, object]) -> object:
        v = known.get(key)
        return np.array([0.0 if v is None else float(np.asarray(v)[0])])
