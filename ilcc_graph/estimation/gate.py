"""The chi-square gate's statistics: per board, its views and its returns, against their dof."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import cast

import gtsam
import numpy as np

from ilcc_graph.errors import GATE_DROPPED
from ilcc_graph.estimation.assembly import Assembly, Term

from . import chi2 as chi2_dist

__all__ = [
    "PRIOR_MAX_RATIO",
    "RETURNS_MAX_RATIO",
    "FAR_ABOVE",
    "BoardStats",
    "board_stats",
    "far_above",
    "gate_failures",
    "gate_scale",
    "graph_variance_factor",
]

#: a board's returns fail the gate only above this multiple of their dof (after the median scale)
RETURNS_MAX_RATIO = 2.0
#: a board's LiDAR pose (its prior's term alone) fails only above this multiple of its dof: the
#: LiDAR fit's errors are heavy-tailed (recorded sets: 35-41 on 6 dof for boards whose views and
#: returns are fine); a wrong correspondence moves a board by a square (chi2 in the hundreds)
PRIOR_MAX_RATIO = 8.0
#: variance components (residuals against the detectors' stated noise) above which more poses do not
#: mend the residuals and a cause is named: the image corners' at 4 (2 x their stated sigma; the
#: recorded sets 1.6), the LiDAR boards' poses at 16 (4 x; the recorded sets 5.5-6.7, the LiDAR fit's
#: errors being heavy-tailed, see ``PRIOR_MAX_RATIO``)
FAR_ABOVE = {"board": 16.0, "bearing": 4.0}


def far_above(components: tuple[float, float]) -> dict[str, float]:
    """The variance components (board priors, bearings) at or above ``FAR_ABOVE``, by kind."""
    got = dict(zip(("board", "bearing"), components, strict=True))
    return {k: float(v) for k, v in got.items() if v >= FAR_ABOVE[k]}


@dataclass(frozen=True)
class BoardStats:
    """Residual statistics of one board at the solution.

    chi2: its prior's term (the in-plane prior when its returns enter) plus its views' whitened
    squared bearing errors; dof: the views' residual count (2 per corner); rms_bearing_error_mrad:
    RMS angle between predicted and measured bearings; chi2_robust: with a robust kernel
    ``2 sum rho`` plus the prior's term (what the gate tests then); returns: (chi2, dof) of its
    LiDAR returns about the board's plane, when they enter the graph; prior: (chi2, dof) of its
    prior's term alone (6 dof for a pose prior, 3 for an in-plane prior).
    """

    chi2: float
    dof: int
    rms_bearing_error_mrad: float
    chi2_robust: float | None = None
    returns: tuple[float, int] | None = None
    prior: tuple[float, int] | None = None
    views: tuple[float, int] | None = None


def board_stats(
    graph: gtsam.NonlinearFactorGraph, terms: Sequence[Term], facs: Mapping[int, list], values: gtsam.Values
) -> dict[int, BoardStats]:
    """Per kept board: chi-square of its views (bearings or pixels, plus its pose prior or the
    in-plane prior of its returns) with their dof, that of its returns, the RMS bearing angle.

    facs: per board its view factors with, for a pixel factor, its camera (None for a bearing
    factor), whose intrinsics at their current value give the measured pixels' rays, and the
    variance component the factor was scaled by (for ``BoardStats.views``; 1 when absent)."""
    prior: dict[int, float] = {}
    prior_dof: dict[int, int] = {}
    returns: dict[int, tuple[float, int]] = {}
    for k, t in enumerate(terms):
        i = t.board
        if t.kind != "board" or i is None:  # a board's term always names its board
            continue
        if not t.parts:
            # every LiDAR that saw the board adds its pose's term (one LiDAR: one term)
            prior[i] = prior.get(i, 0.0) + 2.0 * graph.at(k).error(values)
            prior_dof[i] = prior_dof.get(i, 0) + graph.at(k).dim()
            continue
        # the returns' factor with its in-plane prior: a noise-model factor (factors.board_points)
        e = np.asarray(cast(gtsam.NoiseModelFactor, graph.at(k)).whitenedError(values))
        (_, a0, a1), (_, b0, b1) = t.parts
        returns[i] = (float(e[a0:a1] @ e[a0:a1]), a1 - a0 - 3)
        prior[i] = float(e[b0:b1] @ e[b0:b1])
        prior_dof[i] = b1 - b0
    out: dict[int, BoardStats] = {}
    for i, fs in facs.items():
        p0 = prior.get(i, 0.0)  # a board no LiDAR saw (a rig's cameras alone) has no prior term
        chi2 = p0
        robust = p0 if any(f[0].robust is not None for f in fs) else None
        dof, angles, raw = 0, [], 0.0
        for f, bearings, *scale in fs:
            T_cl, T_lb = values.atPose3(f.keys[0]), values.atPose3(f.keys[1])
            theta = values.atVector(f.keys[2]) if len(f.keys) == 3 else None
            args = (T_cl, T_lb) if bearings is None else (T_cl, T_lb, theta)
            e = f.unwhitened(*args)[0]
            r = np.einsum("kij,kj->ki", f.sqrt_info, e)
            chi2 += float(np.sum(r * r))
            raw += float(np.sum(r * r)) * (scale[0] if scale else 1.0)
            if robust is not None:
                robust += float(np.sum(f.evaluate(*args, False)[0] ** 2))
            dof += f.dim
            if bearings is None:  # a bearing factor: |e| is the sine of the angle between the bearings
                angles.append(np.arcsin(np.clip(np.linalg.norm(e, axis=1), 0.0, 1.0)))
            else:  # a pixel factor: the angle between the predicted ray and the measured pixel's ray
                bearings = bearings.with_intrinsics(theta).bearing(f.uv)
                T = (T_cl * T_lb).matrix()
                p = f.points_board @ T[:3, :3].T + T[:3, 3]
                c = np.linalg.norm(np.cross(p, bearings), axis=1)
                angles.append(np.arctan2(c, np.sum(p * bearings, axis=1)))
        a = np.concatenate(angles) if angles else np.full(1, np.nan)  # a board LiDARs alone saw: none
        rms = float(1e3 * np.sqrt(np.mean(a**2)))
        out[i] = BoardStats(chi2, dof, rms, robust, returns.get(i), (p0, prior_dof.get(i, 0)), (raw, dof))
    return out


def gate_scale(stats: Mapping[int, BoardStats], part: str = "views") -> float:
    """Robust noise scale for the gate: the median chi2/dof over boards, at least 1."""
    ratios = [c / d for c, d, _ in (_part(s, part) for s in stats.values()) if d > 0]
    return max(1.0, float(np.median(ratios))) if ratios else 1.0


def _part(s: BoardStats, part: str) -> tuple[float, int, str]:
    """(value the gate tests, its dof, its name) of the views or the returns of a board."""
    if part == "returns":
        return (s.returns[0], s.returns[1], "returns chi2") if s.returns else (0.0, 0, "")
    if part == "own_views":  # the views' rows alone, at the stated noise
        return (s.views[0], s.views[1], "views' chi2") if s.views else (0.0, 0, "")
    if part == "prior":
        if not s.prior:
            return (0.0, 0, "")
        what = "in-plane pose (intensity pattern)" if s.prior[1] == 3 else "pose"
        return (s.prior[0], s.prior[1], f"chi2 of the LiDAR's board {what} against the image's")
    return (s.chi2, s.dof, "chi2") if s.chi2_robust is None else (s.chi2_robust, s.dof, "robust chi2")


def gate_failures(
    stats: Mapping[int, BoardStats], prob: float, scales: Mapping[str, float], view_ratio: float = 0.0
) -> list[tuple[float, int, str]]:
    """Boards failing the gate as (log survival probability, board, reason), worst first.

    The parts named in ``scales`` are tested apart, each against its own median scale: the views
    (bearings and the board's prior, ``views``; or the views' rows alone at the stated noise,
    ``own_views``), the board's prior alone (where the views pulled the board away from where the
    LiDAR saw it, as a wrong correspondence does) and, where they enter, the board's LiDAR
    returns; the returns only
    against a gross misfit
    (``RETURNS_MAX_RATIO`` times their dof: their residuals are heavy-tailed, a wrong object is not),
    the prior alone above ``PRIOR_MAX_RATIO`` times its dof (likewise),
    the views only above ``view_ratio`` times their dof when that is larger than the quantile (each
    view then has its own variance component: only a view whose noise is far beyond the typical
    view's is dropped).
    """
    failing = []
    for i, s in stats.items():
        worst = None
        for part in scales:
            value, dof, what = _part(s, part)
            if dof <= 0:
                continue
            scale = scales.get(part, 1.0)
            value /= scale
            bound = float(chi2_dist.ppf(prob, dof))
            if part == "returns":  # heavy-tailed in practice: only a gross misfit (another object) fails
                bound = max(bound, RETURNS_MAX_RATIO * dof)
            elif part == "prior":
                bound = max(bound, PRIOR_MAX_RATIO * dof)
            else:
                bound = max(bound, view_ratio * dof)
            if value > bound:
                scaled = f" (divided by the frames' median chi2/dof {scale:.2f})" if scale > 1.0 else ""
                reason = (
                    f"{GATE_DROPPED}: residual {what}{scaled} {value:.1f} > {bound:.1f} ({dof} dof, "
                    f"p={prob}); rms bearing error {s.rms_bearing_error_mrad:.3f} mrad"
                )
                logp = float(chi2_dist.logsf(value, dof))
                if worst is None or logp < worst[0]:
                    worst = (logp, i, reason)
        if worst is not None:
            failing.append(worst)
    return sorted(failing)


def graph_variance_factor(
    g: gtsam.NonlinearFactorGraph, terms: Sequence[Term], values: gtsam.Values, asm: Assembly,
    st: Mapping[int, BoardStats],
) -> float:  # fmt: skip
    """``chi2 / (m - n)`` over the whole graph, at least 1 (bearings without their robust kernel)."""
    chi2 = sum(s.chi2 + (s.returns[0] if s.returns else 0.0) for s in st.values())
    chi2 += sum(2.0 * g.at(k).error(values) for k, t in enumerate(terms) if t.kind in asm.global_terms)
    m = sum(t.dim for t in terms)
    n = sum(asm.dim(k) for k in values.keys())
    return max(1.0, chi2 / (m - n)) if m > n else 1.0
