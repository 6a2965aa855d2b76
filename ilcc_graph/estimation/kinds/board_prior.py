"""Each board's LiDAR pose as a prior on ``B(i)`` (the LiDAR stage's pose and covariance), or with a
range offset ``O(l)`` as ``RangeOffsetBoardFactor`` over the board's face; not for boards whose
returns enter instead (``board_returns``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import gtsam
import numpy as np

from ilcc_graph.estimation.graphs import board_prior_graph, samples_from_corners
from ilcc_graph.estimation.keys import POSE3_DOF
from ilcc_graph.estimation.kinds.base import FactorKind, Scales, Term, register
from ilcc_graph.estimation.solver import check_covariance, check_pose

if TYPE_CHECKING:
    from ilcc_graph.estimation.assembly import Assembly

__all__ = ["BoardPriors"]


@register
class BoardPriors(FactorKind):
    """The boards' LiDAR priors; ``samples``: per board its face points for the range offset."""

    name = "board_prior"
    order = 10
    term = "board"

    def __init__(self, asm: Assembly) -> None:
        super().__init__(asm)
        pr = asm.problem
        # per board its checked covariance; a board without one has no LiDAR prior (a rig's board
        # that only cameras saw)
        self.covariances = {
            i: check_covariance(b.covariance, POSE3_DOF, f"board {b.name!r} covariance")
            for i, b in enumerate(pr.boards)
            if b.covariance is not None
        }
        for b in pr.boards:
            check_pose(b.T_lidar_board, f"board {b.name!r} T_lidar_board")
        self.samples: dict[int, np.ndarray] = {}
        if pr.range_offset_sigma_m is not None:
            for i, b in enumerate(pr.boards):
                if b.samples_board is not None:
                    self.samples[i] = np.asarray(b.samples_board, dtype=np.float64)
                else:
                    pts = next(v.points_board for v in pr.views if v.board == i)
                    self.samples[i] = samples_from_corners(pts)

    def sightings(self) -> dict[int, int]:
        return dict.fromkeys(self.covariances, 1)

    def graph(
        self, boards: Sequence[int], scales: Scales, plain: bool
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        pr = self.asm.problem
        own = [i for i in boards if i not in self.asm.points and i in self.covariances]
        priors = [
            (i, pr.boards[i], self.covariances[i] * scales.get(("board", pr.boards[i].group), 1.0))
            for i in own
        ]
        graph = board_prior_graph(priors, pr.range_offset_sigma_m is not None, self.samples)
        return graph, [Term(self.term, pr.boards[i].group, i, POSE3_DOF) for i in own]
