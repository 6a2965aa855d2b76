"""Ties between extrinsics: ``BetweenFactorPose3(X(a), X(b), identity)`` with per-axis sigmas (the
sessions strategy's drift between sessions)."""

from __future__ import annotations

from collections.abc import Sequence

import gtsam

from ilcc_graph.estimation.graphs import tie_graph
from ilcc_graph.estimation.keys import POSE3_DOF
from ilcc_graph.estimation.kinds.base import FactorKind, Scales, Term, register

__all__ = ["Ties"]


@register
class Ties(FactorKind):
    name = "ties"
    order = 40
    term = "tie"
    global_prior = True

    def graph(
        self, boards: Sequence[int], scales: Scales, plain: bool
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        exts = self.asm.extrinsics(boards)
        ties = [t for t in self.asm.problem.ties if t.a in exts and t.b in exts]
        return tie_graph(ties), [Term(self.term, "", None, POSE3_DOF) for _ in ties]
