"""Each camera's view of a board: a grouped bearing factor on ``(X(e), B(i))``, or with the camera's
intrinsics refined a grouped pixel factor on ``(X(e), B(i), I(c))``. Views with fewer than
``graphs.MIN_CORNERS`` usable corners are left out; a board without a usable view is unusable."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING

import gtsam

from factors import FrameBearingFactor, FramePixelFactor
from ilcc_graph.estimation.graphs import bearing_graph, frame_bearing_factor, frame_pixel_factor
from ilcc_graph.estimation.keys import B, I, X
from ilcc_graph.estimation.kinds.base import FactorKind, Scales, Term, register

if TYPE_CHECKING:
    from ilcc_graph.estimation.assembly import Assembly

log = logging.getLogger(__name__)

__all__ = ["CameraViews"]


@register
class CameraViews(FactorKind):
    """views: (view index, factor) of the usable views; pixel_views: the views entering as pixel
    factors; unusable: per board without a usable view the reason."""

    name = "camera_views"
    order = 30
    term = "bearing"

    def __init__(self, asm: Assembly) -> None:
        super().__init__(asm)
        pr = asm.problem
        self.views: list[tuple[int, FrameBearingFactor | FramePixelFactor]] = []
        self.pixel_views: set[int] = set()
        seen: set[int] = set()
        reasons: dict[int, str] = {}
        fac: FrameBearingFactor | FramePixelFactor | None
        for j, v in enumerate(pr.views):
            name = pr.boards[v.board].name
            c = asm.camera_of(j)
            if c in asm.refined and v.uv is not None:
                fac, n_ok = frame_pixel_factor(
                    X(v.extrinsic), B(v.board), I(c), v.points_board, v.uv, v.cov_px, v.camera, asm.robust
                )
                if fac is not None:
                    self.pixel_views.add(j)
            else:
                fac, n_ok = frame_bearing_factor(
                    X(v.extrinsic),
                    B(v.board),
                    v.points_board,
                    v.bearings,
                    v.cov_px,
                    v.camera,
                    asm.robust,
                    name,
                )
            if fac is None:
                reasons.setdefault(v.board, f"only {n_ok} corners with a usable bearing and covariance")
                continue
            if n_ok < len(v.points_board):
                log.info(
                    "%s: %d of %d corners without a usable bearing covariance skipped",
                    name, len(v.points_board) - n_ok, len(v.points_board),
                )  # fmt: skip
            self.views.append((j, fac))
            seen.add(v.board)
        # a board no camera saw is still of use when LiDARs saw it twice (a rig's base LiDAR and
        # another, or two others: the kinds built before this one say)
        lidars: dict[int, int] = {}
        for kind in asm.kinds:
            for i, n in kind.sightings().items():
                lidars[i] = lidars.get(i, 0) + n
        seen |= {i for i, n in lidars.items() if n >= 2}
        self.unusable = {i: reasons.get(i, "no view of it") for i in range(len(pr.boards)) if i not in seen}

    def graph(
        self, boards: Sequence[int], scales: Scales, plain: bool
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        keep = set(boards)
        facs, terms = [], []
        for j, fac in self.views:
            v = self.asm.problem.views[j]
            if v.board not in keep:
                continue
            group = self.asm.view_group(j)
            s = scales.get(("bearing", group), 1.0)
            fac = fac.scaled(s) if s != 1.0 else fac
            facs.append(fac.with_robust(None) if plain else fac)
            terms.append(Term(self.term, group, v.board, fac.dim))
        return bearing_graph(facs), terms

    def view_cameras(self, boards: Sequence[int]) -> list[int]:
        """Refined cameras whose intrinsics ``I(c)`` the views of ``boards`` enter."""
        keep = set(boards)
        return sorted(
            {gtsam.Symbol(fac.keys[2]).index() for j, fac in self.views
             if len(fac.keys) == 3 and self.asm.problem.views[j].board in keep}
        )  # fmt: skip
