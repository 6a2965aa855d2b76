"""A rig's other LiDARs: each one's view of a board as ``BetweenFactorPose3(Y(l), B(i), T_lidar_board)``.

The boards ``B(i)`` are in the base LiDAR's frame (the rig's first LiDAR, whose boards enter through
``board_prior``); ``Y(l)`` is LiDAR l's pose ``T_base_lidar`` in it (``p_base = Y(l) p_lidar``), so
that its view of board i is ``Y(l)^-1 B(i)``. The LiDAR stage's covariance is in the tangent of its
``T_lidar_board`` (``T_true = T Exp(xi)``), which is ``BetweenFactorPose3``'s error convention. Data:
``Problem.evidence["lidar_boards"]``, a :class:`LidarBoards`; one variance component per LiDAR
(noise group ``LidarBoard.group``, kind ``board``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import gtsam
import numpy as np
from gtsam.symbol_shorthand import Y

from ilcc_graph.estimation.keys import POSE3_DOF, B
from ilcc_graph.estimation.kinds.base import FactorKind, Scales, Term, register
from ilcc_graph.estimation.solver import check_covariance, check_pose, gaussian

if TYPE_CHECKING:
    from ilcc_graph.estimation.assembly import Assembly

__all__ = ["LidarBoard", "LidarBoards", "LidarBoardViews", "Y"]


@dataclass(frozen=True)
class LidarBoard:
    """LiDAR ``lidar``'s (index >= 1) board fit of board ``board``: ``T_lidar_board`` (4, 4) and its
    (6, 6) covariance; ``group``: its noise group (the LiDAR's name)."""

    board: int
    lidar: int
    T_lidar_board: np.ndarray
    covariance: np.ndarray
    group: str


@dataclass(frozen=True)
class LidarBoards:
    """Every other LiDAR's board fits and each LiDAR's start ``T_base_lidar`` (4, 4)."""

    views: tuple[LidarBoard, ...]
    T_init: Mapping[int, np.ndarray]


@register
class LidarBoardViews(FactorKind):
    name = "lidar_boards"
    order = 15
    term = "board"
    letter = "y"

    def __init__(self, asm: Assembly) -> None:
        super().__init__(asm)
        data: LidarBoards | None = asm.problem.evidence.get(self.name)
        self.data = data if data is not None else LidarBoards((), {})
        self.factors = [
            (
                v,
                check_pose(v.T_lidar_board, f"LiDAR {v.lidar}'s board {v.board}"),
                check_covariance(v.covariance, POSE3_DOF, f"LiDAR {v.lidar}'s board {v.board} covariance"),
            )
            for v in self.data.views
        ]

    def graph(
        self, boards: Sequence[int], scales: Scales, plain: bool
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        keep = set(boards)
        graph, terms = gtsam.NonlinearFactorGraph(), []
        for v, T, C in self.factors:
            if v.board in keep:
                noise = gaussian(C * scales.get(("board", v.group), 1.0))
                graph.add(gtsam.BetweenFactorPose3(Y(v.lidar), B(v.board), T, noise))
                terms.append(Term(self.term, v.group, v.board, POSE3_DOF))
        return graph, terms

    def sightings(self) -> dict[int, int]:
        out: dict[int, int] = {}
        for v in self.data.views:
            out[v.board] = out.get(v.board, 0) + 1
        return out

    def keys(self, boards: Sequence[int]) -> list[int]:
        keep = set(boards)
        return [Y(lid) for lid in sorted({v.lidar for v in self.data.views if v.board in keep})]

    def dim(self, key: int) -> int:
        return POSE3_DOF

    def initial(self, key: int, known: Mapping[int, object]) -> object:
        v = known.get(key)
        if v is not None:
            return v
        return check_pose(
            self.data.T_init[gtsam.Symbol(key).index()], f"T_init of LiDAR {gtsam.Symbol(key).index()}"
        )

    def read(self, values: gtsam.Values, key: int) -> object:
        return values.atPose3(key)
