"""A ``Problem`` turned into factors once; graphs of board subsets with any variance scaling.

``Assembly`` builds every factor of a problem one time (bearing covariances mapped from pixels
through the camera models, square-root informations, Unit3 bases, the boards' returns) and then the
graph of any subset of its boards with any variance scaling, with the ``Term`` bookkeeping the noise
policy needs (which factor belongs to which board and noise group, and which of its rows are which
kind). Factor order in a graph: the board priors, the board returns, the views, the ties, the
offset priors, the LiDAR error priors.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from factors import FrameBearingFactor, FramePixelFactor
from factors.board_moments import CompactBoardPoints, Moments, moments_of
from factors.board_points import BoardPointsFactor
from ilcc_graph.cameras import CameraModel
from ilcc_graph.estimation.graphs import (
    Scales,
    bearing_graph,
    board_points_factor,
    board_prior_graph,
    frame_bearing_factor,
    frame_pixel_factor,
    intrinsics_prior_graph,
    lidar_prior_graph,
    offset_prior_graph,
    samples_from_corners,
    tie_graph,
)
from ilcc_graph.estimation.intrinsics import prior_sigmas, refinable
from ilcc_graph.estimation.keys import POSE3_DOF, B, I, L, O, X, key_dim
from ilcc_graph.estimation.lidar_errors import LidarLayout, layout_for
from ilcc_graph.estimation.problem import Problem
from ilcc_graph.estimation.solver import check_covariance, check_pose

log = logging.getLogger(__name__)

__all__ = ["Assembly", "Term"]


@dataclass(frozen=True)
class Term:
    """What one factor of an assembled graph is: ``kind`` board / bearing / tie / offset, its noise
    ``group`` (scaled by the variance components of board and bearing terms) and its board (or None)."""

    kind: str
    group: str
    board: int | None
    dim: int
    parts: tuple[tuple[str, int, int], ...] = ()  # (kind, first row, end row) when rows differ in kind


class Assembly:
    """A ``Problem`` turned into factors once; graphs of board subsets with any variance scaling.

    robust: m-estimator applied per corner to the bearing factors (None: least squares).
    Views with fewer than ``MIN_CORNERS`` usable corners are left out; ``unusable`` names their
    boards with the reason (a board without any usable view cannot be estimated). With
    ``problem.lidar_errors``, each board that carries its returns enters through a
    ``BoardPointsFactor`` on its LiDAR's parameters ``L(l)`` (``layouts`` per LiDAR, default from
    the returns: ``lidar_errors.layout_for``); the others through their LiDAR prior. With
    ``problem.intrinsics.refine`` (or ``refine=True`` here), the views of lens cameras enter as
    pixel factors on the camera's intrinsics ``I(c)`` (``cameras`` lists the distinct cameras;
    ``refine`` may also name the camera indices to refine). per_view: every view is its own noise
    group (``view_group``), so that it gets its own bearing variance component.
    """

    def __init__(
        self,
        problem: Problem,
        robust: gtsam.noiseModel.mEstimator.Base | None = None,
        layouts: Mapping[int, LidarLayout] | None = None,
        refine: bool | set[int] | None = None,
        per_view: bool = False,
    ) -> None:
        self.problem = problem
        self.robust = robust
        self.per_view = per_view
        self.cameras: list[CameraModel] = []
        cam_of: list[int] = []
        for v in problem.views:
            same = [c for c, cam in enumerate(self.cameras) if cam == v.camera]
            if not same:
                self.cameras.append(v.camera)
            cam_of.append(same[0] if same else len(self.cameras) - 1)
        if refine is None:
            refine = problem.intrinsics is not None and problem.intrinsics.refine
        chosen = refine if isinstance(refine, set) else set(range(len(self.cameras))) if refine else set()
        self.refined = {c for c, cam in enumerate(self.cameras) if c in chosen and refinable(cam)}
        self.priors = [
            check_covariance(b.covariance, POSE3_DOF, f"board {b.name!r} covariance") for b in problem.boards
        ]
        for b in problem.boards:
            check_pose(b.T_lidar_board, f"board {b.name!r} T_lidar_board")
        self.views: list[tuple[int, FrameBearingFactor | FramePixelFactor]] = []  # (view index, factor)
        self.pixel_views: set[int] = set()  # views entering as pixel factors
        seen: set[int] = set()
        reasons: dict[int, str] = {}
        for j, v in enumerate(problem.views):
            name = problem.boards[v.board].name
            if cam_of[j] in self.refined and v.uv is not None:
                fac, n_ok = frame_pixel_factor(
                    X(v.extrinsic), B(v.board), I(cam_of[j]), v.points_board, v.uv, v.cov_px, v.camera, robust
                )  # type: ignore[assignment]
                if fac is not None:
                    self.pixel_views.add(j)
            else:
                fac, n_ok = frame_bearing_factor(
                    X(v.extrinsic), B(v.board), v.points_board, v.bearings, v.cov_px, v.camera, robust, name
                )
            if fac is None:
                reasons.setdefault(v.board, f"only {n_ok} corners with a usable bearing and covariance")
                continue
            if n_ok < len(v.points_board):
                log.info(
                    "%s: %d of %d corners without a usable bearing covariance skipped",
                    name,
                    len(v.points_board) - n_ok,
                    len(v.points_board),
                )
            self.views.append((j, fac))
            seen.add(v.board)
        self.unusable = {
            i: reasons.get(i, "no view of it") for i in range(len(problem.boards)) if i not in seen
        }
        self.samples: dict[int, np.ndarray] = {}
        if problem.range_offset_sigma_m is not None:
            for i, b in enumerate(problem.boards):
                if b.samples_board is not None:
                    self.samples[i] = np.asarray(b.samples_board, dtype=np.float64)
                else:
                    pts = next(v.points_board for v in problem.views if v.board == i)
                    self.samples[i] = samples_from_corners(pts)
        self.layouts: dict[int, LidarLayout] = {}
        self.points: dict[int, BoardPointsFactor] = {}
        self._moments: dict[int, Moments] = {}  # the returns' moments per board (compact factors)
        # per board its latest scaling: (scales, factor, its compact form or None)
        self._scaled: dict[int, tuple[tuple[float, ...], BoardPointsFactor, CompactBoardPoints | None]] = {}
        opts = problem.lidar_errors
        if opts is not None and opts.any:
            by_lidar: dict[int, list[int]] = {}
            for i, b in enumerate(problem.boards):
                if b.returns is not None:
                    by_lidar.setdefault(b.lidar, []).append(i)
            for lid, idx in by_lidar.items():
                lay = (layouts or {}).get(lid) or layout_for([problem.boards[i].returns for i in idx], opts)
                self.layouts[lid] = lay
                if lay.dim == 0:
                    continue  # nothing left to estimate: the boards enter through their priors
                for i in idx:
                    self.points[i] = board_points_factor(
                        i,
                        problem.boards[i],
                        lay,
                        opts.max_points_per_board,
                        opts.board_plane,
                        opts.board_beam,
                    )

    def view_group(self, j: int) -> str:
        """The noise group of view ``j``'s bearing or pixel rows."""
        v = self.problem.views[j]
        return f"{v.group}|{self.problem.boards[v.board].name}" if self.per_view else v.group

    @property
    def usable(self) -> list[int]:
        """Boards with at least one usable view, in problem order."""
        return [i for i in range(len(self.problem.boards)) if i not in self.unusable]

    def graph(
        self, boards: Sequence[int], scales: Scales | None = None, plain: bool = False
    ) -> tuple[gtsam.NonlinearFactorGraph, list[Term]]:
        """The graph of ``boards`` (their priors and views, the ties, the offset priors) and its terms.

        scales: variance scale per (kind, group). plain: without the robust kernel (least squares).
        """
        pr = self.problem
        scales = scales or {}
        keep = set(boards)
        order = [i for i in range(len(pr.boards)) if i in keep]
        with_offset = pr.range_offset_sigma_m is not None
        plain_boards = [i for i in order if i not in self.points]
        priors = [
            (i, pr.boards[i], self.priors[i] * scales.get(("board", pr.boards[i].group), 1.0))
            for i in plain_boards
        ]
        graph = board_prior_graph(priors, with_offset, self.samples)
        terms = [Term("board", pr.boards[i].group, i, POSE3_DOF) for i in plain_boards]
        for i in order:
            if i in self.points:
                g = pr.boards[i].group
                f = self.points_factor(i, scales)
                graph.add(f.factor())
                m = f.n_points
                terms.append(Term("board", g, i, f.dim, (("points", 0, m), ("inplane", m, m + 3))))
        facs = []
        for j, fac in self.views:
            v = pr.views[j]
            if v.board not in keep:
                continue
            group = self.view_group(j)
            s = scales.get(("bearing", group), 1.0)
            fac = fac.scaled(s) if s != 1.0 else fac
            facs.append(fac.with_robust(None) if plain else fac)
            terms.append(Term("bearing", group, v.board, fac.dim))
        graph.push_back(bearing_graph(facs))
        exts = self.extrinsics(order)
        ties = [t for t in pr.ties if t.a in exts and t.b in exts]
        graph.push_back(tie_graph(ties))
        terms += [Term("tie", "", None, POSE3_DOF) for _ in ties]
        if with_offset:
            lidars = self.lidars(order)
            graph.push_back(offset_prior_graph(lidars, float(pr.range_offset_sigma_m)))
            terms += [Term("offset", "", None, 1) for _ in lidars]
        layouts = {lid: self.layouts[lid] for lid in self.point_lidars(order)}
        graph.push_back(lidar_prior_graph(layouts))
        terms += [Term("lidar", "", None, lay.dim) for lay in layouts.values()]
        cams = self.view_cameras(order)
        graph.push_back(intrinsics_prior_graph({c: self.intrinsics_prior(c) for c in cams}))
        terms += [Term("intrinsics", "", None, len(self.cameras[c].intrinsic_names)) for c in cams]
        return graph, terms

    def points_factor(self, i: int, scales: Scales) -> BoardPointsFactor:
        """Board ``i``'s returns factor under the variance scales (points, in-plane, its plane's
        offset and tilt, its beams' offsets: ``plane.KINDS``)."""
        g = self.problem.boards[i].group
        plane = (scales.get(("plane_offset", g), 1.0), scales.get(("plane_tilt", g), 1.0))
        beam = scales.get(("board_beam", g), 1.0)
        key = (scales.get(("points", g), 1.0), scales.get(("inplane", g), 1.0), *plane, beam)
        last = self._scaled.get(i)
        if last is None or last[0] != key:  # the noise policy builds each scaling twice in a row
            f = self.points[i].scaled(key[0], key[1], plane, beam)
            last = self._scaled[i] = (key, f, None)
        return last[1]

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

    def compact_factor(self, i: int, f: BoardPointsFactor) -> BoardPointsFactor | CompactBoardPoints:
        """Board ``i``'s returns factor ``f`` (any scaling) in compact form when that has fewer rows."""
        m = self._moments.get(i)
        if m is None:
            m = self._moments[i] = moments_of(self.points[i])
        if m.n_theta >= f.n_points:
            return f
        last = self._scaled.get(i)
        if last is not None and last[1] is f:
            if last[2] is None:
                last = self._scaled[i] = (last[0], f, CompactBoardPoints(f, m))
            return last[2]
        return CompactBoardPoints(f, m)

    def view_cameras(self, boards: Sequence[int]) -> list[int]:
        """Refined cameras whose intrinsics ``I(c)`` the views of ``boards`` enter."""
        keep = set(boards)
        return sorted(
            {gtsam.Symbol(fac.keys[2]).index() for j, fac in self.views
             if len(fac.keys) == 3 and self.problem.views[j].board in keep}
        )  # fmt: skip

    def intrinsics_prior(self, c: int) -> tuple[np.ndarray, np.ndarray]:
        """(values, sigmas) of camera ``c``'s intrinsics prior (``intrinsics.prior_sigmas``)."""
        cam = self.cameras[c]
        return cam.intrinsics(), prior_sigmas(cam)

    def point_lidars(self, boards: Sequence[int]) -> list[int]:
        """LiDARs whose parameters ``L(l)`` the boards' returns enter."""
        return sorted({self.problem.boards[i].lidar for i in boards if i in self.points})

    def dim(self, key: int) -> int:
        """Tangent dimension of the variable behind ``key``."""
        sym = gtsam.Symbol(key)
        letter = chr(sym.chr()).lower()
        if letter == "l":
            return self.layouts[int(sym.index())].dim
        if letter == "i":
            return len(self.cameras[int(sym.index())].intrinsic_names)
        return key_dim(key)

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
        return sorted({self.problem.boards[i].lidar for i in boards})

    def bearing_factors(self, board: int) -> list[FrameBearingFactor]:
        """The (unscaled) bearing factors of one board's views."""
        return [fac for j, fac in self.views if self.problem.views[j].board == board]

    def values(
        self,
        boards: Sequence[int],
        extrinsics: Mapping[int, gtsam.Pose3],
        board_poses: Mapping[int, gtsam.Pose3] | None = None,
        offsets: Mapping[int, float] | None = None,
        lidar: Mapping[int, np.ndarray] | None = None,
        intrinsics: Mapping[int, np.ndarray] | None = None,
    ) -> gtsam.Values:
        """Initial values: the extrinsics given, each board at ``board_poses`` or its LiDAR prior,
        each range offset at ``offsets`` or 0, each LiDAR's parameters at ``lidar`` or 0, each refined
        camera's intrinsics at ``intrinsics`` or the config's."""
        values = gtsam.Values()
        for e in self.extrinsics(boards):
            T = extrinsics.get(e)
            values.insert(X(e), T if T is not None else check_pose(self.problem.T_init[e], f"T_init[{e}]"))
        for i in boards:
            bp = (board_poses or {}).get(i)
            values.insert(
                B(i), bp if bp is not None else check_pose(self.problem.boards[i].T_lidar_board, "")
            )
        if self.problem.range_offset_sigma_m is not None:
            for lid in self.lidars(boards):
                values.insert(O(lid), np.array([(offsets or {}).get(lid, 0.0)]))
        for lid in self.point_lidars(boards):
            v = (lidar or {}).get(lid)
            values.insert(
                L(lid),
                v if v is not None and len(v) == self.layouts[lid].dim else np.zeros(self.layouts[lid].dim),
            )
        for c in self.view_cameras(boards):
            th = (intrinsics or {}).get(c)
            values.insert(I(c), th if th is not None else self.cameras[c].intrinsics())
        return values
