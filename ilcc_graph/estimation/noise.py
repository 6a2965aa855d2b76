"""The one noise policy of the estimation core: chi-square gate, variance components, final factor.

``solve_problem`` solves any ``Problem`` (batch, sessions, rig) the same way:

1. with a robust kernel, a least-squares pass first (from a start far off every residual is
   "large" and a redescending kernel would weight them all to zero);
2. **gate**: the board whose chi-square (its prior's term plus its views' whitened bearing errors;
   dof = the views' residual count) most exceeds the ``chi2_gate_prob`` quantile is dropped and
   the graph re-solved, until none fails or ``max_dropped_fraction`` of the boards are gone. With
   ``variance_components`` the chi-squares are first divided by the median chi2/dof over the boards
   (when above 1), so a noise model too optimistic for every board drops none of them;
3. **variance components** (Foerstner): per noise group (session or camera) one factor for the
   board priors and one for the bearings, each the group's chi-square over its redundancy (its
   residual count less ``trace(N^-1 N_g)``), iterated until they settle, never below 1; computed on
   the kept boards, then every board is gated again under that noise and the components re-estimated;
4. **final factor**: covariances are multiplied by ``chi2 / (m - n)`` over the whole graph when it
   exceeds 1 (m residuals, n parameters);
5. **the components' own uncertainty** (``components.component_uncertainty``): a component
   estimated from a redundancy r is itself uncertain (sd of its log ``sqrt(psi'(r / 2))``, about
   ``sqrt(2 / r)``). The covariances use each estimated component's posterior mean ``s r / (r - 2)``
   (Jeffreys prior) instead of s, and add what the components' uncertainty moves the estimate:
   ``sum_k psi'(r_k / 2) d_k d_k^T``, ``d_k`` the globals' shift per unit of ``log s_k`` (one
   Gauss-Newton step of the graph with ``s_k`` perturbed). The estimate itself is that of the
   components found. Components held at their floor are not estimated and left as they are.

The systems are arrow-shaped: each factor touches at most one board (``B(i)``), every other variable
(extrinsics, range offsets) is global, so traces and marginals of boards cost O(boards) through the
Schur complement on the globals. The covariances returned are ``gtsam.Marginals``'s.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import gtsam
import numpy as np

from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation import plane
from ilcc_graph.estimation.assembly import Assembly
from ilcc_graph.estimation.components import component_uncertainty, estimated_components
from ilcc_graph.estimation.gate import BoardStats
from ilcc_graph.estimation.gate import graph_variance_factor as graph_factor
from ilcc_graph.estimation.graphs import Scales
from ilcc_graph.estimation.keys import POSE3_DOF, B, I, L, O, X
from ilcc_graph.estimation.lidar_errors import LidarLayout
from ilcc_graph.estimation.linear import consider_covariance
from ilcc_graph.estimation.noise_loop import COMPONENT_KINDS, Fits
from ilcc_graph.estimation.problem import Problem
from ilcc_graph.estimation.solver import MarginalCovariances, SolverOptions, robust_kernel
from ilcc_graph.types import Estimate

log = logging.getLogger(__name__)

__all__ = ["BoardStats", "NoiseOptions", "Solution", "replace_scales", "solve_problem"]

MIN_BOARDS_ADVISED = 4


@dataclass(frozen=True)
class NoiseOptions:
    """How the noise model is checked and the graph solved.

    robust: None or an m-estimator per corner on its whitened bearing error (``solver.KERNELS``).
    robust_k: its threshold in sigmas (None: the usual 95 %-efficiency value).
    chi2_gate_prob: quantile of the per-board chi-square gate; None disables the gate. With a robust
        kernel the gate tests the robust cost ``2 sum rho`` (never above the chi-square).
    max_dropped_fraction: the gate drops at most this fraction of the usable boards.
    variance_components: scale the gate by the median chi2/dof, estimate the variance components
        (not with a robust kernel) and apply the final variance factor.
    view_components: every view gets its own bearing variance component (views differ in blur,
        viewing angle and how well the lens model fits where they sit), and the gate drops a view
        only when its own rows' chi-square (stated noise, median scale) exceeds ``VIEW_MAX_RATIO`` x dof.
    solver: Levenberg-Marquardt stopping rules.
    """

    robust: str | None = None
    robust_k: float | None = None
    chi2_gate_prob: float | None = 0.999
    max_dropped_fraction: float = 0.5
    variance_components: bool = True
    view_components: bool = True
    solver: SolverOptions = SolverOptions()

    def __post_init__(self) -> None:
        if self.chi2_gate_prob is not None and not 0.0 < self.chi2_gate_prob < 1.0:
            raise ValueError(f"chi2_gate_prob must be in (0, 1) or None, got {self.chi2_gate_prob!r}")
        if not 0.0 <= self.max_dropped_fraction <= 1.0:
            raise ValueError(f"max_dropped_fraction must be in [0, 1], got {self.max_dropped_fraction!r}")
        robust_kernel(self.robust, self.robust_k)  # validates the name and threshold


@dataclass
class Solution:
    """A solved problem: the kept boards, the noise found, and covariances on demand.

    boards: indices of the kept boards. dropped: ``(name, reason)`` of the others, in the order
    dropped. scales: variance component per (kind, group). variance_factor: the final factor (every
    covariance returned is multiplied by it). redundancy: per (kind, group) with a component, its
    redundancy at the last estimate. uncertain: the estimated components (key: redundancy) whose
    uncertainty the covariances carry (module docstring step 5): ``covariance_scales`` and
    ``spread``, computed with the first covariance asked for. failing: ``(name, reason)`` of kept
    boards that fail the gate though it may drop no more (``max_dropped_fraction``): the noise found
    does not cover them.
    """

    problem: Problem
    assembly: Assembly
    boards: list[int]
    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    stats: dict[int, BoardStats]
    dropped: list[tuple[str, str]]
    scales: dict[tuple[str, str], float]
    variance_factor: float
    iterations: int
    timings: dict[str, float] = field(default_factory=dict)
    redundancy: dict[tuple[str, str], float] = field(default_factory=dict)
    uncertain: dict[tuple[str, str], float] = field(default_factory=dict)
    failing: list[tuple[str, str]] = field(default_factory=list)
    _marginals: MarginalCovariances | None = None
    _uncertainty: tuple[dict[tuple[str, str], float] | None, list] | None = None

    def _component_uncertainty(self) -> tuple[dict[tuple[str, str], float] | None, list]:
        if self._uncertainty is None:
            t0 = time.perf_counter()
            self._uncertainty = component_uncertainty(self.assembly, self.boards, self.scales, self.uncertain,
                                                      self.values)  # fmt: skip
            self.timings["component_uncertainty"] = time.perf_counter() - t0
        return self._uncertainty

    @property
    def covariance_scales(self) -> dict[tuple[str, str], float] | None:
        """The components the covariances use: the estimated ones' posterior means (None: ``scales``)."""
        return self._component_uncertainty()[0]

    @property
    def spread(self) -> list[tuple[float, dict[int, np.ndarray]]]:
        """Per estimated component (var of log s, each global's shift per unit of log s)."""
        return self._component_uncertainty()[1]

    def board_plane(self, group: str = "") -> plane.BoardPlane | None:
        """The boards' plane sigmas the solve used (estimated or configured), or None without them."""
        n = sum(1 for i in self.boards if i in self.assembly.points and self.problem.boards[i].group == group)
        return plane.board_plane(self.problem.lidar_errors, self.scales, self.redundancy, n, group)

    @property
    def marginals(self) -> MarginalCovariances:
        if self._marginals is None:
            t0 = time.perf_counter()
            graph = self.graph
            if self.covariance_scales is not None:
                graph = self.assembly.graph(self.boards, self.covariance_scales)[0]
            self._marginals = MarginalCovariances(graph, self.values, self.variance_factor)
            self.timings["marginals"] = self.timings.get("marginals", 0.0) + time.perf_counter() - t0
        return self._marginals

    def extrinsic(self, e: int = 0) -> Estimate:
        """``T_cam_lidar`` of extrinsic ``e`` with its marginal covariance (plus the stated
        uncertainty of intrinsics that were not refined, ``intrinsics.IntrinsicsOptions.propagate``)."""
        T = np.asarray(self.values.atPose3(X(e)).matrix(), dtype=np.float64)
        C = self.marginals.covariance(X(e), f"T_cam_lidar (X({e}))")
        return Estimate(T, C + self.spread_of([X(e)], [POSE3_DOF]) + self.consider(e))

    def spread_of(self, keys: Sequence[int], dims: Sequence[int]) -> np.ndarray:
        """What the components' uncertainty adds to the joint covariance of the global ``keys`` (of
        dimensions ``dims``), in that order (module docstring step 5; zeros when none was estimated)."""
        out = np.zeros((sum(dims), sum(dims)))
        for w, d in self.spread:
            v = np.concatenate([d.get(k, np.zeros(n)) for k, n in zip(keys, dims, strict=True)])
            out += w * np.outer(v, v)
        return out

    def consider(self, e: int = 0) -> np.ndarray:
        """(6, 6) what the stated sigmas of the cameras' unrefined intrinsics add to extrinsic ``e``'s
        covariance (zero when none are stated, they are refined, or propagation is off)."""
        opts = self.problem.intrinsics
        if opts is None or not opts.propagate:
            return np.zeros((POSE3_DOF, POSE3_DOF))
        return consider_covariance(self, e)

    def intrinsics(self, c: int = 0) -> tuple[list[str], np.ndarray, np.ndarray] | None:
        """(names, values, sigmas) of camera ``c``'s refined intrinsics, or None when not refined."""
        if c not in self.assembly.view_cameras(self.boards):
            return None
        v = np.asarray(self.values.atVector(I(c)), dtype=np.float64)
        C = self.marginals.covariance(I(c), f"the intrinsics of camera {c}")
        C = C + self.spread_of([I(c)], [len(v)])
        return list(self.assembly.cameras[c].intrinsic_names), v, np.sqrt(np.diag(C))

    def joint_covariance(self, extrinsics: Sequence[int]) -> np.ndarray:
        """(6n, 6n) joint marginal covariance of the extrinsics, in the order given."""
        keys, dims = [X(e) for e in extrinsics], [POSE3_DOF] * len(extrinsics)
        return self.marginals.joint(keys, dims) + self.spread_of(keys, dims)

    def board_pose(self, i: int) -> np.ndarray:
        """(4, 4) the solved ``T_lidar_board`` of board ``i``."""
        return np.asarray(self.values.atPose3(B(i)).matrix(), dtype=np.float64)

    def offset(self, lidar: int) -> tuple[float, float]:
        """(value, sigma) of LiDAR ``lidar``'s range offset, metres."""
        v = float(self.values.atVector(O(lidar))[0])
        C = self.marginals.covariance(O(lidar), f"range offset O({lidar})") + self.spread_of([O(lidar)], [1])
        return v, float(np.sqrt(C[0, 0]))

    def components(self, group: str = "") -> tuple[float, float]:
        """(board priors, bearings) variance components of ``group`` (with the boards' returns in the
        graph, the first is that of their in-plane priors, the intensity fit's or else the outline's;
        with a component per view, the second is their median)."""
        inplane = self.scales.get(("inplane", group), self.scales.get(("outline", group), 1.0))
        board = self.scales.get(("board", group), inplane)
        views = [
            v
            for (k, g), v in self.scales.items()
            if k == "bearing" and (g == group or g.startswith(group + "|"))
        ]
        return board, float(np.median(views)) if views else 1.0

    def view_component(self, board: int) -> float:
        """The bearing variance component of a board's (first) view."""
        for j, _ in self.assembly.views:
            if self.problem.views[j].board == board:
                return self.scales.get(("bearing", self.assembly.view_group(j)), 1.0)
        return 1.0

    def lidar(self, lidar: int = 0) -> tuple[list[str], np.ndarray, np.ndarray] | None:
        """(names, values, sigmas) of LiDAR ``lidar``'s own errors (``lidar_errors``), or None."""
        got = self.lidar_estimate(lidar)
        if got is None:
            return None
        v, C = got
        return self.assembly.layouts[lidar].names, v, np.sqrt(np.diag(C))

    def lidar_estimate(self, lidar: int = 0) -> tuple[np.ndarray, np.ndarray] | None:
        """(values, covariance) of LiDAR ``lidar``'s own errors (layout order), or None."""
        C = self.lidar_covariance(lidar)
        if C is None:
            return None
        return np.asarray(self.values.atVector(L(lidar)), dtype=np.float64), C

    def lidar_covariance(self, lidar: int = 0) -> np.ndarray | None:
        """(n, n) marginal covariance of LiDAR ``lidar``'s own errors (layout order), or None."""
        lay = self.assembly.layouts.get(lidar)
        if lay is None or lidar not in self.assembly.point_lidars(self.boards):
            return None
        C = self.marginals.covariance(L(lidar), f"the errors of LiDAR {lidar}")
        return C + self.spread_of([L(lidar)], [len(C)])


# ------------------------------------------------------------------------------- the solve
def solve_problem(
    problem: Problem,
    options: NoiseOptions = NoiseOptions(),
    *,
    boards: Sequence[str] | None = None,
    scales: Scales | None = None,
    variance_factor: float | None = None,
    gate: bool = True,
    start: Mapping[int, gtsam.Pose3 | None] | None = None,
    layouts: Mapping[int, LidarLayout] | None = None,
    uncertain: Mapping[tuple[str, str], float] | None = None,
) -> Solution:
    """Solve ``problem`` under the noise policy of this module.

    boards: names of the boards to use (None: all). scales: fixed variance components per (kind,
    group) (then none are estimated). variance_factor: a fixed final factor (None: estimated when
    ``options.variance_components``). gate: apply the chi-square gate. start: extrinsic starts per
    index (else ``problem.T_init``). layouts: the LiDAR errors' layouts per LiDAR (default: from
    the returns); with ``problem.lidar_errors``, terms the boards cannot determine are left out
    (``Solution.assembly.layouts[l].excluded`` says which and why) and the problem solved again.
    uncertain: with fixed ``scales`` that another solve estimated, its ``Solution.uncertain`` (their
    uncertainty then enters the covariances as there, step 5).

    Raises CalibrationImpossible (no usable board), IndeterminateSystem (the data do not determine
    the variables), ValueError (malformed input, the message names the board).
    """
    t_start = time.perf_counter()
    robust = robust_kernel(options.robust, options.robust_k)
    asm = Assembly(problem, robust, layouts, per_view=options.view_components)
    wanted = range(len(problem.boards)) if boards is None else [problem.index(n) for n in boards]
    names = [b.name for b in problem.boards]
    out = {i: asm.unusable.get(i) or problem.excluded.get(names[i]) for i in wanted}
    dropped = [(names[i], why) for i, why in out.items() if why]
    candidates = [i for i, why in out.items() if not why]
    if not candidates:
        detail = "; ".join(f"{n}: {r}" for n, r in dropped)
        raise CalibrationImpossible(
            f"no usable frame for the graph ({len(wanted)} given" + (f"; {detail})" if detail else ")")
        )
    fits = Fits(
        problem, asm,
        # every variable's latest estimate by key (the start of the next fit): the extrinsics' given starts
        {X(e): T for e, T in (start or {}).items() if T is not None},
        names, int(math.floor(options.max_dropped_fraction * len(candidates))), gate, robust,
        options.variance_components, options.view_components, options.chi2_gate_prob, options.solver,
    )  # fmt: skip
    if robust is not None:
        fits.fit(candidates, scales or {}, plain=True)
    fixed = scales is not None
    use_components = options.variance_components and robust is None and not fixed
    comps: dict[tuple[str, str], float] = dict(scales or {})
    run = fits.gated(candidates, comps)
    fitted, st = run.fitted, run.stats
    if use_components:
        # components on the kept boards only (an outlier would inflate what judges it); then every
        # board is gated again under that noise, and the components re-estimated
        _, comps = fits.with_components(run.kept, comps)
        run = fits.gated(candidates, comps)
        fitted, comps = fits.with_components(run.kept, comps)
        st = fits.stats_of(run.kept, comps, fitted)
    kept = run.kept
    dropped.extend(run.gone)
    if variance_factor is None:
        vf = (
            graph_factor(fitted.graph, fitted.terms, fitted.values, asm, st)
            if options.variance_components
            else 1.0
        )
    else:
        vf = variance_factor
    if use_components:
        uncertain = estimated_components(comps, fits.redundancy, problem.lidar_errors)
    fits.timings["total"] = time.perf_counter() - t_start
    sol = Solution(problem, asm, kept, fitted.graph, fitted.values, st, dropped, comps, float(vf),
                   fits.iterations, fits.timings, fits.redundancy, dict(uncertain or {}),
                   run.failing)  # fmt: skip
    weak = _unobservable(sol) if layouts is None else {}
    if weak:
        for lid, (terms_out, why) in weak.items():
            log.info("LiDAR %d: %s left out: %s", lid, ", ".join(terms_out), why)
        again = {lid: lay.without(*weak[lid]) if lid in weak else lay for lid, lay in asm.layouts.items()}
        return solve_problem(problem, options, boards=boards, scales=scales, variance_factor=variance_factor,
                             gate=gate, start=start, layouts=again, uncertain=uncertain)  # fmt: skip
    _log_noise(sol, fixed, variance_factor is None)
    return sol


def _log_noise(sol: Solution, fixed: bool, estimated_factor: bool) -> None:
    """What a solve found that the user should hear of: too few boards, the variance components
    (when estimated), the boards' plane sigmas, a final factor above 1 (when estimated)."""
    if len(sol.boards) < MIN_BOARDS_ADVISED:
        log.warning(
            "only %d usable frame(s) in the graph; %d or more advised",
            len(sol.boards), MIN_BOARDS_ADVISED,
        )  # fmt: skip
    if any(v != 1.0 for v in sol.scales.values()) and not fixed:
        log.info(
            "variance components (residuals against the stated noise): %s",
            ", ".join(
                f"{k}{'/' + grp.lstrip('|') if grp else ''} x {v:.2f}"
                for (k, grp), v in sorted(sol.scales.items())
            ),
        )
    plane.log_sigmas(sol.problem.lidar_errors, sol.board_plane())
    if sol.variance_factor > 1.0 and estimated_factor:
        log.info(
            "the residuals are %.2f times the stated noise variance; covariance scaled by it",
            sol.variance_factor,
        )


def _unobservable(sol: Solution) -> dict[int, tuple[list[str], str]]:
    """Per LiDAR, its error terms the boards hardly determine, and why (posterior over prior variance)."""
    out: dict[int, tuple[list[str], str]] = {}
    opts = sol.problem.lidar_errors
    for lid, lay in sol.assembly.layouts.items():
        if lid not in sol.assembly.point_lidars(sol.boards):
            continue
        C = sol.marginals.covariance(L(lid), f"the errors of LiDAR {lid}") / sol.variance_factor
        ratio = np.diag(C) / lay.prior_sigmas() ** 2
        weak = [n for n, q in zip(lay.names, ratio, strict=True) if q > opts.observable_ratio]  # type: ignore[union-attr]
        if weak:
            worst = float(ratio.max())
            out[lid] = (weak, f"not observable from the boards given (the boards shrink its prior variance "
                              f"only to {100 * worst:.0f} % of it or less)")  # fmt: skip
    return out


def replace_scales(sol: Solution, factor: float) -> dict[tuple[str, str], float]:
    """The solution's components with its final variance factor folded in (for sub-problem solves)."""
    groups = {(k, b.group) for b in sol.problem.boards for k in COMPONENT_KINDS if k != "bearing"}
    groups |= {("bearing", sol.assembly.view_group(j)) for j in range(len(sol.problem.views))}
    groups |= {key for key in sol.scales if key[0] in plane.KINDS}
    return {key: sol.scales.get(key, 1.0) * factor for key in groups}
