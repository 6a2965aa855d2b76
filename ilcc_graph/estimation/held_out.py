"""Each board's image held out: how well the rest of a solved problem predicts it.

The score of a sensor-error model (``selection``): for each kept board k, the board's pose in the
camera frame as its image alone gives it (``image_alone``: its bearings fitted with the extrinsic
held at identity, covariance ``s (A^T A)^-1`` with s its own chi-square per dof, at least 1) is
compared with what the model predicts for it from everything else, its own LiDAR data included:
``T_cam_lidar * T_lidar_board`` with both taken from the solve without board k's view. The
predictive log density ``-1/2 (d^T S^-1 d + log det S)``, ``S = C_image + J C J^T``, sums over the
boards (leave-one-board-out cross-validation of the image given the LiDAR).

The target (the image's pose, its covariance) does not depend on the model: models that read the
LiDAR differently (its boards as 6-dof poses, or its returns with beam and board terms) are scored
on the same numbers. No re-solve: the solve without board k's view is one step of the linearised
system from the solution (the view's rows taken out of the information of board k and the globals,
``linear.reduce``), exact for a linear model (``tests/test_selection.py`` checks it against re-solves).

The same scores gate the boards (``held_out_gate``): a board whose image every candidate model
predicts far off is dropped, what the chi-square gate misses when that board has inflated the
variance components it is judged under.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import gtsam
import numpy as np

from factors import FrameBearingFactor
from ilcc_graph.errors import GATE_DROPPED
from ilcc_graph.estimation.chi2 import ppf as chi2_ppf
from ilcc_graph.estimation.keys import POSE3_DOF, B, X
from ilcc_graph.estimation.linear import reduce
from ilcc_graph.estimation.noise import Solution

__all__ = ["HELD_OUT_GATE", "HeldOut", "board_spread", "held_out", "held_out_gate", "image_alone"]


@dataclass(frozen=True)
class HeldOut:
    """Board k's image held out: chi2 ``d^T S^-1 d`` (6 dof when the model is right), ``log det S``
    and the log density ``-1/2 (chi2 + log det S)`` (up to a constant common to every model);
    shift: (6,) what taking the view out moves the extrinsic (Pose3 tangent); leverage: the view's
    share of the extrinsic's information, ``1 - trace(C_without^-1 C) / 6`` (0 .. 1)."""

    chi2: float
    logdet: float
    shift: np.ndarray
    leverage: float = float("nan")

    @property
    def log_density(self) -> float:
        return -0.5 * (self.chi2 + self.logdet)


def image_alone(
    fac: FrameBearingFactor, start: gtsam.Pose3, iterations: int = 10
) -> tuple[gtsam.Pose3, np.ndarray]:
    """(T_cam_board, its (6, 6) covariance) from one view's bearing factor ``fac`` alone (Gauss-Newton
    from ``start`` with the extrinsic at identity); the covariance scaled by the view's chi-square
    per dof when above 1."""
    ident = gtsam.Pose3()
    T = start
    for _ in range(iterations):
        r, _, A = fac.evaluate(ident, T, True)
        step = np.linalg.lstsq(A, -r, rcond=None)[0]
        T = T.retract(step)
        if np.abs(step).max() < 1e-10:
            break
    r, _, A = fac.evaluate(ident, T, True)
    s = max(1.0, float(r @ r) / max(len(r) - POSE3_DOF, 1))
    return T, s * np.linalg.inv(A.T @ A)


def held_out(sol: Solution, e: int = 0) -> dict[int, HeldOut]:
    """Per kept board with a bearing view on extrinsic ``e`` (camera ``e`` of a rig): its image in
    that camera held out (module docstring; the board's views in other cameras stay).

    The covariances are those the solution reports (its components' posterior means, its final
    factor, the components' spread on the extrinsic). Boards whose views are pixel factors (refined
    intrinsics) are left out: their image's pose depends on the intrinsics being estimated. Empty
    when extrinsic ``e`` is not in the solution (a rig's camera whose every view was dropped)."""
    if not sol.values.exists(X(e)):
        return {}
    asm = sol.assembly
    scales = sol.covariance_scales or sol.scales
    graph, terms = asm.graph(sol.boards, scales)
    red = reduce(graph, sol.values, terms, asm.dim)
    S_inv = np.linalg.inv(red.S)
    xe = sol.values.atPose3(X(e))
    spread = sol.spread_of([X(e)], [POSE3_DOF])
    views = {
        v.board: fac
        for j, fac in asm.views
        if isinstance(fac, FrameBearingFactor) and (v := sol.problem.views[j]).extrinsic == e
    }
    out: dict[int, HeldOut] = {}
    for kind, _, bk, A_b, g_keys, A_g, b, count in red.blocks:
        if kind != "bearing" or count is not None or bk is None or A_b is None or g_keys != [X(e)]:
            continue
        k = int(gtsam.Symbol(bk).index())
        if k not in views:
            continue
        c = red.cols(g_keys)
        di, ci = red.Dinv[bk], red.C[bk]
        S_bg = -di @ ci @ S_inv
        S_bb = di - S_bg @ ci.T @ di
        Sig = np.block([[S_bb, S_bg[:, c]], [S_bg[:, c].T, S_inv[np.ix_(c, c)]]])
        A = np.hstack([A_b, A_g])
        C = np.linalg.inv(np.linalg.inv(Sig) - A.T @ A)  # board k and the extrinsic without the view
        delta = -C @ A.T @ b
        C = C * sol.variance_factor
        board = sol.values.atPose3(B(k)).retract(delta[:POSE3_DOF])
        pred = xe.retract(delta[POSE3_DOF:]).compose(board)
        J = np.hstack([np.eye(POSE3_DOF), board.inverse().AdjointMap()])  # d(X B) over (dB, dX)
        C_pred = J @ C @ J.T + J[:, POSE3_DOF:] @ spread @ J[:, POSE3_DOF:].T
        T_img, C_img = image_alone(views[k], pred)
        d = np.asarray(pred.localCoordinates(T_img), dtype=np.float64)
        S = C_img + C_pred
        C_x = sol.variance_factor * S_inv[np.ix_(c, c)]  # the extrinsic's, with the view
        lev = 1.0 - float(np.trace(np.linalg.solve(C[POSE3_DOF:, POSE3_DOF:], C_x))) / POSE3_DOF
        chi2 = float(d @ np.linalg.solve(S, d))
        out[k] = HeldOut(chi2, float(np.linalg.slogdet(S)[1]), delta[POSE3_DOF:], lev)
    return out


def board_spread(scores: Mapping[int, HeldOut], covariance: np.ndarray) -> dict[str, float]:
    """How far the boards move the extrinsic against its ``covariance`` (6, 6), from each board's
    held-out ``scores`` (``held_out``): ``trace(C^-1 V) / 6`` for V the leave-one-board-out (jackknife)
    covariance and for its leverage-corrected form (HC2, ``sum (1 - h_k) s_k s_k^T``); about 1 when
    the covariance is the spread the boards give. A diagnostic (scripts/bench_joint_lidar.py,
    scripts/board_spread.py), not a step of any solve. Also the largest leverage and shift (m)."""
    S = np.array([h.shift for h in scores.values()])
    lev = np.array([h.leverage for h in scores.values()])
    n = len(S)
    if n < 2:
        return dict.fromkeys(("jackknife", "hc2", "leverage_max", "shift_max_m"), float("nan"))
    Sc = S - S.mean(axis=0)
    C = np.asarray(covariance, dtype=np.float64)
    V_jack, V_hc2 = (n - 1) / n * Sc.T @ Sc, (S * (1.0 - lev)[:, None]).T @ S
    return {
        "jackknife": float(np.trace(np.linalg.solve(C, V_jack)) / POSE3_DOF),
        "hc2": float(np.trace(np.linalg.solve(C, V_hc2)) / POSE3_DOF),
        "leverage_max": float(lev.max()),
        "shift_max_m": float(np.linalg.norm(S[:, 3:], axis=1).max()),
    }


#: a board is dropped when its image, predicted from the other boards and its own LiDAR data, lies
#: beyond this chi-square quantile (6 dof) under every candidate model, each model's held-out
#: chi-squares divided by their median's ratio to chi2(6)'s median (when above 1)
HELD_OUT_GATE = 0.999


def held_out_gate(
    scores: Mapping[str, Mapping[tuple[int, int], HeldOut]], gated: Mapping[str, set[int]] | None = None
) -> tuple[int, str] | None:
    """The board (index) whose held-out image fails ``HELD_OUT_GATE`` under every scored model (the
    keys of ``scores``) by the widest margin, and the reason; None when none does. ``gated``: per
    model, the boards its own chi-square gate dropped (unscored there): each counts as failing under
    that model. What it catches: a board moved between the scan and the photo pulls the extrinsic and
    inflates the boards' variance components until the chi-square gate, judging it under that noise,
    passes it; predicted from the other boards, it stands out (a simulated hand-held board moved 27 mm:
    held-out chi2 34-40 against 13 at most for the other boards; the recorded sets' largest 16-17). A
    model under which a second moved board stays in may pass the first; the models that dropped the
    second do not vouch for it."""
    if not scores:
        return None
    gated = gated or {}
    bound, median = float(chi2_ppf(HELD_OUT_GATE, POSE3_DOF)), float(chi2_ppf(0.5, POSE3_DOF))
    scaled: dict[str, dict[int, float]] = {}
    for name, s in scores.items():
        scale = max(1.0, float(np.median([h.chi2 for h in s.values()])) / median)
        per: dict[int, float] = {k: np.inf for k in gated.get(name, ())}
        for (_, k), h in s.items():
            per[k] = max(per.get(k, 0.0), h.chi2 / scale)
        scaled[name] = per
    common = set.intersection(*(set(p) for p in scaled.values()))
    failing = [(min(p[k] for p in scaled.values()), k) for k in common]
    failing = [(z, k) for z, k in failing if z > bound and np.isfinite(z)]
    if not failing:
        return None
    z, k = max(failing)
    by_gate = [n for n in scores if np.isinf(scaled[n][k])]
    scored = [n for n in scores if n not in by_gate]
    also = f"; {', '.join(by_gate)} dropped it at the chi-square gate" if by_gate else ""
    return k, (
        f"{GATE_DROPPED}: held out, predicted from the other boards and its own LiDAR data, its image "
        f"lies at chi2 {z:.1f} > {bound:.1f} (6 dof, p={1 - HELD_OUT_GATE:g}) under every sensor model "
        f"({', '.join(scored)}{also}): the board moved between the scan and the photo, or the two are not "
        "of one moment"
    )
