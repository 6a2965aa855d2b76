"""Each board's LiDAR returns on ``(B(i), L(l))`` (``BoardPointsFactor``) when the LiDAR's own errors
are estimated (``Problem.lidar_errors``): the boards that carry their returns enter through them
instead of their pose prior; the compact form of the same cost for optimising."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import gtsam

from factors.board_moments import CompactBoardPoints, Moments, moments_of
from factors.board_points import BoardPointsFactor
from ilcc_graph.estimation.graphs import board_points_factor
from ilcc_graph.estimation.kinds.base import FactorKind, Scales, Term, register
from ilcc_graph.estimation.lidar_errors import LidarLayout, layout_for

if TYPE_CHECKING:
    from ilcc_graph.estimation.assembly import Assembly

__all__ = ["BoardReturns"]


@register
class BoardReturns(FactorKind):
    """layouts: per LiDAR the terms of its errors (``lidar_errors.LidarLayout``; the assembly's
    ``given_layouts``, else from the returns); points: per board its returns factor (unscaled)."""

    name = "board_returns"
    order = 20
    term = "board"

    def __init__(self, asm: Assembly) -> None:
        super().__init__(asm)
        pr = asm.problem
        self.layouts: dict[int, LidarLayout] = {}
        self.points: dict[int, BoardPointsFactor] = {}
        self._moments: dict[int, Moments] = {}  # the returns' moments per board (compact factors)
        # per board its latest scaling: (scales, factor, its compact form or None)
        self._scaled: dict[int, tuple[tuple[float, ...], BoardPointsFactor, CompactBoardPoints | None]] = {}
        opts = pr.lidar_errors
        if opts is None or not opts.any:
            return
        by_lidar: dict[int, list[int]] = {}
        for i, b in enumerate(pr.boards):
            if b.returns is not None:
                by_lidar.setdefault(b.lidar, []).append(i)
        for lid, idx in by_lidar.items():
            returns = [r for i in idx if (r := pr.boards[i].returns) is not None]  # every one has them
            lay = asm.given_layouts.get(lid) or layout_for(returns, opts)
            self.layouts[lid] = lay
            if lay.dim == 0:
                continue  # nothing left to estimate: the boards enter through their priors
            for i in idx:
                self.points[i] = board_points_factor(
                    i, pr.boards[i], lay, opts.max_points_per_board, opts.board_plane, opts.board_beam
                )

    def graph(
        self, boards: Sequence[int], scales: Scales, plain: bool
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        graph, terms = gtsam.NonlinearFactorGraph(), []
        for i in boards:
            if i in self.points:
                f = self.points_factor(i, scales)
                graph.add(f.factor())
                m = f.n_points
                group = self.asm.problem.boards[i].group
                terms.append(
                    Term(self.term, group, i, f.dim, (("points", 0, m), (self.inplane_kind(i), m, m + 3)))
                )
        return graph, terms

    def inplane_kind(self, i: int) -> str:
        """The variance component of board ``i``'s in-plane prior: ``outline`` when the outline alone
        placed it (no print), else ``inplane`` (the intensity fit's)."""
        r = self.asm.problem.boards[i].returns
        return "outline" if r is not None and r.outline else "inplane"

    def points_factor(self, i: int, scales: Scales) -> BoardPointsFactor:
        """Board ``i``'s returns factor under the variance scales (points, in-plane or outline, its
        plane's offset and tilt, its beams' offsets: ``plane.KINDS``)."""
        g = self.asm.problem.boards[i].group
        plane = (scales.get(("plane_offset", g), 1.0), scales.get(("plane_tilt", g), 1.0))
        beam = scales.get(("board_beam", g), 1.0)
        key = (scales.get(("points", g), 1.0), scales.get((self.inplane_kind(i), g), 1.0), *plane, beam)
        last = self._scaled.get(i)
        if last is None or last[0] != key:  # the noise policy builds each scaling twice in a row
            f = self.points[i].scaled(key[0], key[1], plane, beam)
            last = self._scaled[i] = (key, f, None)
        return last[1]

    def compact_factor(self, i: int, f: BoardPointsFactor) -> BoardPointsFactor | CompactBoardPoints:
        """Board ``i``'s returns factor ``f`` (any scaling) in compact form when that has fewer rows."""
        m = self._moments.get(i)
        if m is None:
            m = self._moments[i] = moments_of(self.points[i])
        if m.n_theta >= f.n_points:
            return f
        last = self._scaled.get(i)
        if last is not None and last[1] is f:
            compact = last[2]
            if compact is None:
                compact = CompactBoardPoints(f, m)
                self._scaled[i] = (last[0], f, compact)
            return compact
        return CompactBoardPoints(f, m)

    def point_lidars(self, boards: Sequence[int]) -> list[int]:
        """LiDARs whose parameters ``L(l)`` the boards' returns enter."""
        return sorted({self.asm.problem.boards[i].lidar for i in boards if i in self.points})
