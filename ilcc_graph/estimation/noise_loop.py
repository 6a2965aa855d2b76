"""The fits of one solve under the noise policy (``noise.solve_problem``): the graph of a set of
boards solved from every variable's latest estimate, the chi-square gate that drops the worst board
until none fails, and the variance components iterated until they settle (Foerstner; the boards'
planes' components by a Fisher-scoring step, ``plane.components``)."""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import gtsam

from factors.grouped import MEstimator
from ilcc_graph.estimation import plane
from ilcc_graph.estimation.assembly import Assembly, Term
from ilcc_graph.estimation.gate import BoardStats, board_stats, gate_failures, gate_scale
from ilcc_graph.estimation.graphs import Scales
from ilcc_graph.estimation.linear import redundancies
from ilcc_graph.estimation.problem import Problem
from ilcc_graph.estimation.solver import SolverOptions, optimize

log = logging.getLogger(__name__)

__all__ = [
    "COMPONENT_FLOORS",
    "COMPONENT_KINDS",
    "Fitted",
    "Fits",
    "Gated",
    "VIEW_MAX_RATIO",
    "component_floor",
]

#: kinds of residual rows with a variance component each (per noise group)
COMPONENT_KINDS = ("board", "bearing", "points", "inplane", "outline")
#: the least each component may be (its stated noise as a bound: 1), but for the outline's in-plane
#: priors: their covariance is the spread of a flat-topped posterior whose edges' blur and growth are
#: stated wide on purpose (a footprint's mixed returns, ``lidar.shape``), so the residuals may say
#: it is narrower (down to a third in sigma); estimated only with the redundancy to tell
#: (``components.component_uncertainty`` carries the estimate's own uncertainty)
COMPONENT_FLOORS = {"outline": 0.1}


def component_floor(key: tuple[str, str]) -> float:
    """The floor of the variance component ``key`` = (kind, group): 1, or the kind's own."""
    return COMPONENT_FLOORS.get(key[0], 1.0)


#: with a component per view, a view fails only above this multiple of its dof (recorded views: to 5.5x)
VIEW_MAX_RATIO = 8.0


@dataclass
class Fitted:
    """One fit: its graph, the graph's terms and the solution."""

    graph: gtsam.NonlinearFactorGraph
    terms: list[Term]
    values: gtsam.Values


@dataclass
class Gated:
    """The boards the gate kept, those it dropped (``(name, reason)``, in order), the last fit and
    its per-board statistics; failing: ``(name, reason)`` of kept boards that still fail the gate
    when it may drop no more (``allowed_drops``)."""

    kept: list[int]
    gone: list[tuple[str, str]]
    fitted: Fitted
    stats: dict[int, BoardStats]
    failing: list[tuple[str, str]] = field(default_factory=list)


@dataclass
class Fits:
    """The fits of one solve of ``problem`` over its assembly ``asm``.

    known: every variable's latest estimate by key (the start of the next fit; filled as it goes).
    names: the boards' names. allowed_drops: how many boards the gate may drop. gate: whether it
    does. robust: the m-estimator (None: least squares). lidar_errors, variance_components,
    view_components, chi2_gate_prob, solver: as in ``noise.NoiseOptions`` and ``Problem``.
    timings (build, optimize), iterations and redundancy (per (kind, group) at the last estimate)
    accumulate over the fits."""

    problem: Problem
    asm: Assembly
    known: dict[int, object]
    names: list[str]
    allowed_drops: int
    gate: bool
    robust: MEstimator | None
    variance_components: bool
    view_components: bool
    chi2_gate_prob: float | None
    solver: SolverOptions
    timings: dict[str, float] = field(default_factory=lambda: {"build": 0.0, "optimize": 0.0})
    iterations: int = 0
    redundancy: dict[tuple[str, str], float] = field(default_factory=dict)

    def fit(self, kept: Sequence[int], comps: Scales, plain: bool = False) -> Fitted:
        """The graph of the boards ``kept`` under the components ``comps`` solved (``plain``: without
        the robust kernel); its variables' estimates become the next fit's start."""
        asm = self.asm
        t0 = time.perf_counter()
        g, terms = asm.graph(kept, comps, plain)
        values = asm.values(kept, self.known)
        t1 = time.perf_counter()
        res, n_it = optimize(asm.compact(g, terms, comps), values, self.solver)
        self.timings["build"] += t1 - t0
        self.timings["optimize"] += time.perf_counter() - t1
        self.iterations += n_it
        self.known.update(asm.read(res, kept))
        return Fitted(g, terms, res)

    def stats_of(self, kept: Sequence[int], comps: Scales, fitted: Fitted) -> dict[int, BoardStats]:
        """Per kept board its statistics (``gate.board_stats``) with its views scaled by their
        components."""
        asm = self.asm
        facs: dict[int, list] = {i: [] for i in kept}
        for j, fac in asm.views:
            v = self.problem.views[j]
            if v.board in facs:
                s = comps.get(("bearing", asm.view_group(j)), 1.0)
                facs[v.board].append(
                    (fac.scaled(s) if s != 1.0 else fac, v.camera if j in asm.pixel_views else None, s)
                )
        return board_stats(fitted.graph, fitted.terms, facs, fitted.values)

    def gated(self, kept0: Sequence[int], comps: Scales) -> Gated:
        """Fit the boards ``kept0``, dropping the one that fails the chi-square gate worst and fitting
        again until none fails or no more may be dropped."""
        kept, gone, left = list(kept0), list[tuple[str, str]](), list[tuple[str, str]]()
        while True:
            fitted = self.fit(kept, comps)
            st = self.stats_of(kept, comps, fitted)
            if not self.gate or self.chi2_gate_prob is None:
                break
            on = self.variance_components
            view_ratio = VIEW_MAX_RATIO if self.view_components and on else 0.0
            # per-view components: the views' own rows (their verdict not hung on the LiDAR's fit)
            parts = ("own_views" if view_ratio and self.robust is None else "views", "prior", "returns")
            gate_scales = {p: gate_scale(st, p) if on else 1.0 for p in parts}
            failing = gate_failures(st, self.chi2_gate_prob, gate_scales, view_ratio)
            if not failing:
                break
            if len(gone) >= self.allowed_drops or len(kept) == 1:
                log.warning(
                    "chi-square gate fails for %d frame(s) (%s) but at most %d frames may be dropped; kept",
                    len(failing), ", ".join(self.names[i] for _, i, _ in failing), self.allowed_drops,
                )  # fmt: skip
                left = [(self.names[i], why) for _, i, why in failing]
                break
            _, worst, reason = failing[0]
            log.info("dropping frame %s: %s", self.names[worst], reason)
            gone.append((self.names[worst], reason))
            kept = [i for i in kept if i != worst]
        return Gated(kept, gone, fitted, st, left)

    def with_components(
        self, kept: Sequence[int], comps: dict[tuple[str, str], float]
    ) -> tuple[Fitted, dict[tuple[str, str], float]]:
        """The variance components of the boards ``kept`` iterated from ``comps`` until they settle
        (at most 8 rounds, 16 with the boards' planes' components), and the last fit."""
        asm, opts = self.asm, self.problem.lidar_errors
        fitted = self.fit(kept, comps)
        planes = plane.estimated(opts, asm, kept)  # the boards' planes' components
        for _ in range(16 if planes else 8):
            info: dict[tuple[str, str], float] | None = {} if planes else None
            extra = plane.extra_rows(asm, comps, planes) if planes else None
            ratios = redundancies(fitted.graph, fitted.values, fitted.terms, asm.dim, extra, info)
            ratios = plane.split_points(ratios) if planes else ratios
            new = dict(comps)
            for key, (c2, r) in ratios.items():
                if key[0] in COMPONENT_KINDS:
                    s = comps.get(key, 1.0) * (c2 / r if r > 0.5 else 1.0)
                    new[key] = max(component_floor(key), s)
            if planes and opts is not None:  # planes are estimated only with the LiDAR's errors
                new.update(plane.components(ratios, comps, opts, info))
            self.redundancy.update({k: r for k, (_, r) in ratios.items()})
            if all(abs(new[k] / comps.get(k, 1.0) - 1.0) < 0.02 for k in new):
                break
            comps = new
            fitted = self.fit(kept, comps)
        return fitted, comps
