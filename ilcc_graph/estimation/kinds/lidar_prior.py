"""A weak zero-mean prior on each LiDAR's error parameters ``L(l)`` (its layout's sigmas); owns the
``L`` variables that the boards' returns (``board_returns``) enter."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import gtsam
import numpy as np

from ilcc_graph.estimation.graphs import lidar_prior_graph
from ilcc_graph.estimation.keys import L
from ilcc_graph.estimation.kinds.base import FactorKind, Scales, Term, register

__all__ = ["LidarPrior"]


@register
class LidarPrior(FactorKind):
    name = "lidar_prior"
    order = 60
    term = "lidar"
    letter = "l"
    global_prior = True

    def graph(
        self, boards: Sequence[int], scales: Scales, plain: bool
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        layouts = {lid: self.asm.layouts[lid] for lid in self.asm.point_lidars(boards)}
        return lidar_prior_graph(layouts), [Term(self.term, "", None, lay.dim) for lay in layouts.values()]

    def keys(self, boards: Sequence[int]) -> list[int]:
        return [L(lid) for lid in self.asm.point_lidars(boards)]

    def dim(self, key: int) -> int:
        return self.asm.layouts[gtsam.Symbol(key).index()].dim

    def initial(self, key: int, known: Mapping[int, object]) -> object:
        v = known.get(key)
        n = self.dim(key)
        return v if v is not None and len(v) == n else np.zeros(n)  # type: ignore[arg-type]
