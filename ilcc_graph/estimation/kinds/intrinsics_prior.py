"""A prior on each refined camera's intrinsics ``I(c)`` (the config's values, their stated or
default sigmas: ``intrinsics.prior_sigmas``); owns the ``I`` variables the pixel views enter."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import gtsam

from ilcc_graph.estimation.graphs import intrinsics_prior_graph
from ilcc_graph.estimation.intrinsics import prior_sigmas
from ilcc_graph.estimation.keys import I
from ilcc_graph.estimation.kinds.base import FactorKind, Scales, Term, register

__all__ = ["IntrinsicsPrior"]


@register
class IntrinsicsPrior(FactorKind):
    name = "intrinsics_prior"
    order = 70
    term = "intrinsics"
    letter = "i"

    def graph(
        self, boards: Sequence[int], scales: Scales, plain: bool
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        cams = self.asm.view_cameras(boards)
        cameras = self.asm.cameras
        graph = intrinsics_prior_graph({c: (cameras[c].intrinsics(), prior_sigmas(cameras[c])) for c in cams})
        return graph, [Term(self.term, "", None, len(cameras[c].intrinsic_names)) for c in cams]

    def keys(self, boards: Sequence[int]) -> list[int]:
        return [I(c) for c in self.asm.view_cameras(boards)]

    def dim(self, key: int) -> int:
        return len(self.asm.cameras[gtsam.Symbol(key).index()].intrinsic_names)

    def initial(self, key: int, known: Mapping[int, object]) -> object:
        v = known.get(key)
        return v if v is not None else self.asm.cameras[gtsam.Symbol(key).index()].intrinsics()
