"""A ``Problem`` turned into factors once; graphs of board subsets with any variance scaling.

``Assembly`` builds every registered factor kind (``kinds/``: the board priors, the boards'
returns, the camera views, the ties, the range-offset, LiDAR-error and intrinsics priors) one time
for a problem and then gives the graph of any subset of its boards with any variance scaling, with
the ``Term`` bookkeeping the noise policy needs (which factor belongs to which board and noise
group, and which of its rows are which kind), the variables' start values and dimensions. Factor
order in a graph: the kinds' order. The extrinsics ``X(e)`` and the boards ``B(i)`` are its own
variables; every other variable belongs to the kind that owns its key letter.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import gtsam
import numpy as np

from factors import FrameBearingFactor, FramePixelFactor
from factors.board_moments import CompactBoardPoints
from factors.board_points import BoardPointsFactor
from factors.grouped import MEstimator
from ilcc_graph.cameras import CameraModel
from ilcc_graph.estimation.intrinsics import refinable
from ilcc_graph.estimation.keys import POSE3_DOF, B, X
from ilcc_graph.estimation.kinds import KINDS, FactorKind, Scales, Term
from ilcc_graph.estimation.kinds.board_returns import BoardReturns
from ilcc_graph.estimation.kinds.camera_views import CameraViews
from ilcc_graph.estimation.lidar_errors import LidarLayout
from ilcc_graph.estimation.problem import Problem
from ilcc_graph.estimation.solver import check_pose

__all__ = ["Assembly", "Term"]


class Assembly:
    """A ``Problem`` turned into factors once; graphs of board subsets with any variance scaling.

    robust: m-estimator applied per corner to the bearing factors (None: least squares).
    layouts: the LiDAR errors' layouts per LiDAR (default: from the returns,
    ``lidar_errors.layout_for``). refine: refine the cameras' intrinsics (default
    ``problem.intrinsics.refine``; a set names the camera indices). per_view: every view is its own
    noise group (``view_group``), so that it gets its own bearing variance component. ``cameras``
    lists the distinct cameras of the views; ``refined`` those whose intrinsics ``I(c)`` are
    variables. ``kinds``: one built instance per registered kind, in graph order.
    """

    def __init__(
        self,
        problem: Problem,
        robust: MEstimator | None = None,
        layouts: Mapping[int, LidarLayout] | None = None,
        refine: bool | set[int] | None = None,
        per_view: bool = False,
    ) -> None:
        self.problem = problem
        self.robust = robust
        self.per_view = per_view
        self.given_layouts = dict(layouts or {})
        self.cameras: list[CameraModel] = []
        self._camera_of: list[int] = []
        lenses: list[object] = []  # per camera c, what its views share (``View.lens_key``)
        for v in problem.views:
            same = [c for c, key in enumerate(lenses) if key == v.lens_key()]
            if not same:
                self.cameras.append(v.camera)
                lenses.append(v.lens_key())
            self._camera_of.append(same[0] if same else len(self.cameras) - 1)
        if refine is None:
            opts = problem.intrinsics
            refine = opts is not None and opts.refine and (opts.cameras is None or set(opts.cameras))
        chosen = refine if isinstance(refine, set) else set(range(len(self.cameras))) if refine else set()
        self.refined = {c for c, cam in enumerate(self.cameras) if c in chosen and refinable(cam)}
        self.kinds: list[FactorKind] = []
        for cls in KINDS:  # a kind may read the kinds built before it
            self.kinds.append(cls(self))
        self._by_name = {k.name: k for k in self.kinds}
        self._owner = {k.letter: k for k in self.kinds if k.letter is not None}

    def kind(self, name: str) -> FactorKind:
        """The built kind called ``name`` (``kinds``)."""
        return self._by_name[name]

    def camera_of(self, j: int) -> int:
        """Index into ``cameras`` of view ``j``'s camera."""
        return self._camera_of[j]

    # ---------------------------------------------------------------- what the kinds hold
    @property
    def _returns(self) -> BoardReturns:
        return self._by_name["board_returns"]  # type: ignore[return-value]

    @property
    def _views(self) -> CameraViews:
        return self._by_name["camera_views"]  # type: ignore[return-value]

    @property
    def views(self) -> list[tuple[int, FrameBearingFactor | FramePixelFactor]]:
        """(view index, factor) of the usable views."""
        return self._views.views

    @property
    def pixel_views(self) -> set[int]:
        """Views entering as pixel factors (their camera's intrinsics refined)."""
        return self._views.pixel_views

    @property
    def unusable(self) -> dict[int, str]:
        """Boards without a usable view, with the reason."""
        return self._views.unusable

    @property
    def layouts(self) -> dict[int, LidarLayout]:
        """Per LiDAR the terms of its errors that the boards' returns enter."""
        return self._returns.layouts

    @property
    def points(self) -> dict[int, BoardPointsFactor]:
        """Per board its returns factor (unscaled), for the boards whose returns enter."""
        return self._returns.points

    def points_factor(self, i: int, scales: Scales) -> BoardPointsFactor:
        """Board ``i``'s returns factor under the variance scales (``BoardReturns.points_factor``)."""
        return self._returns.points_factor(i, scales)

    def compact_factor(self, i: int, f: BoardPointsFactor) -> BoardPointsFactor | CompactBoardPoints:
        """Board ``i``'s returns factor ``f`` in compact form when that has fewer rows."""
        return self._returns.compact_factor(i, f)

    def point_lidars(self, boards: Sequence[int]) -> list[int]:
        """LiDARs whose parameters ``L(l)`` the boards' returns enter."""
        return self._returns.point_lidars(boards)

    def view_cameras(self, boards: Sequence[int]) -> list[int]:
        """Refined cameras whose intrinsics ``I(c)`` the views of ``boards`` enter."""
        return self._views.view_cameras(boards)

    def bearing_factors(self, board: int) -> list[FrameBearingFactor | FramePixelFactor]:
        """The (unscaled) view factors of one board."""
        return [fac for j, fac in self.views if self.problem.views[j].board == board]

    def view_group(self, j: int) -> str:
        """The noise group of view ``j``'s bearing or pixel rows."""
        v = self.problem.views[j]
        return f"{v.group}|{self.problem.boards[v.board].name}" if self.per_view else v.group

    @property
    def usable(self) -> list[int]:
        """Boards with at least one usable view, in problem order."""
        return [i for i in range(len(self.problem.boards)) if i not in self.unusable]

    # ---------------------------------------------------------------- graphs and values
    def graph(
        self, boards: Sequence[int], scales: Scales | None = None, plain: bool = False
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        """The graph of ``boards`` (every kind's factors, in the kinds' order) and its terms.

        scales: variance scale per (kind, group). plain: without the robust kernel (least squares).
        """
        keep = set(boards)
        order = [i for i in range(len(self.problem.boards)) if i in keep]
        graph, terms = gtsam.NonlinearFactorGraph(), []
        for kind in self.kinds:
            g, t = kind.graph(order, scales or {}, plain)
            graph.push_back(g)
            terms += t
        return graph, terms

    def compact(
        self, graph: gtsam.NonlinearFactorGraph, terms: Sequence[Term], scales: Scales | None = None
    ) -> gtsam.NonlinearFactorGraph:
        """``graph`` (``graph(boards, scales)``, its ``terms``) with each board's returns as
        ``CompactBoardPoints`` where that has fewer rows: the same cost and Gauss-Newton system, for
        optimising; every other factor shared."""
        out = gtsam.NonlinearFactorGraph()
        out.push_back(graph)
        for k, t in enumerate(terms):
            if t.parts and t.board in self.points:  # a board's returns
                f = self.points_factor(t.board, scales or {})
                c = self.compact_factor(t.board, f)
                if c is not f:
                    out.replace(k, c.factor())
        return out

    def newton_step(self, boards: Sequence[int], scales: Scales, values: gtsam.Values) -> gtsam.VectorValues:
        """One Gauss-Newton step from ``values`` of the graph of ``boards`` under ``scales`` (compact
        form); differences of such steps are an estimate's first-order sensitivities."""
        g, terms = self.graph(boards, scales)
        return self.compact(g, terms, scales).linearize(values).optimize()

    def values(self, boards: Sequence[int], known: Mapping[int, object] | None = None) -> gtsam.Values:
        """Start values of the graph of ``boards``: ``known[key]`` where given (e.g. the last
        solution's, ``read``), else each extrinsic at ``problem.T_init``, each board at its LiDAR
        prior, every other variable at its kind's default."""
        known = known or {}
        values = gtsam.Values()
        for e in self.extrinsics(boards):
            T = known.get(X(e))
            _insert(values, X(e), T if T is not None else check_pose(self.problem.T_init[e], f"T_init[{e}]"))
        for i in boards:
            bp = known.get(B(i))
            _insert(
                values, B(i), bp if bp is not None else check_pose(self.problem.boards[i].T_lidar_board, "")
            )
        for kind in self.kinds:
            for key in kind.keys(boards):
                _insert(values, key, kind.initial(key, known))
        return values

    def read(self, values: gtsam.Values, boards: Sequence[int]) -> dict[int, object]:
        """Every variable of the graph of ``boards`` in a solution ``values``, by key (``values``'s
        ``known``)."""
        out: dict[int, object] = {X(e): values.atPose3(X(e)) for e in self.extrinsics(boards)}
        out.update({B(i): values.atPose3(B(i)) for i in boards})
        for kind in self.kinds:
            out.update({key: kind.read(values, key) for key in kind.keys(boards)})
        return out

    def dim(self, key: int) -> int:
        """Tangent dimension of the variable behind ``key``."""
        letter = chr(gtsam.Symbol(key).chr()).lower()
        if letter in ("x", "b"):
            return POSE3_DOF
        return self._owner[letter].dim(key)

    @property
    def global_terms(self) -> set[str]:
        """``Term.kind`` of the priors on global variables (their chi-square enters the graph's
        variance factor as it is)."""
        return {k.term for k in self.kinds if k.global_prior}

    def extrinsics(self, boards: Sequence[int]) -> list[int]:
        """Extrinsic indices seen by the views of ``boards`` (and those tied to them), ascending."""
        keep = set(boards)
        used = {self.problem.views[j].extrinsic for j, _ in self.views if self.problem.views[j].board in keep}
        for _ in range(len(self.problem.ties) + 1):  # ties may chain extrinsics that no view sees
            more = {i for t in self.problem.ties for i in (t.a, t.b) if t.a in used or t.b in used}
            if more <= used:
                break
            used |= more
        return sorted(used)

    def lidars(self, boards: Sequence[int]) -> list[int]:
        """LiDARs of ``boards``, ascending."""
        return sorted({self.problem.boards[i].lidar for i in boards})


def _insert(values: gtsam.Values, key: int, value: object) -> None:
    """A variable's value into ``values``: a pose as a ``Pose3``, anything else as a vector."""
    if isinstance(value, gtsam.Pose3):
        values.insert(key, value)
    else:
        values.insert(key, np.asarray(value, dtype=np.float64))
