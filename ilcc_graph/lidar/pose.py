"""The board's pose from its points: the in-plane fit (the intensity pattern checked and sharpened by
the board's outline, or the outline alone when the LiDAR does not show the print), the plane refitted
on the returns well inside the board, the covariance, the refusals, and the returns for the graph.

``fit_board_points(points, intensity, normal, offset, board, lidar_model, options) -> BoardFit``
(raises ``BoardNotFound`` when the fit cannot be trusted, with the reason). LiDAR frame, metres;
the pose is ``T_lidar_board`` with the covariance in its Pose3 tangent.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..board import Board
from ..errors import BoardNotFound
from ..lidars import LidarModel
from ..types import BoardFit, BoardReturns
from .board_tests import colour_agreement, print_visible
from .cost import intensity_classes
from .covariance import PlaneFit, assemble_covariance, plane_fit, ray_coupling, sampling_covariance
from .fit import InPlaneFit, align_to_plane, fit_in_plane, plane_frame, pose_from_in_plane, project_on_plane
from .margin import outline_board
from .options import LidarOptions, breach
from .outline import (
    EDGE_LEFT_OUT_REACH,
    ShapeCheck,
    apply_xi,
    fov_share,
    fuse,
    inplane_reach,
    lattice_moves,
    outline_coupling,
    outline_only,
    refuse_outline,
    shape_check,
    shape_diagnostics,
    shape_gate,
    slid_message,
)
from .shape import outline_posterior, outline_samples
from .soft_edge import se2_exp, soft_edge_refine, soft_intensity

__all__ = ["fit_board_points", "project"]


def project(points: np.ndarray, normal: np.ndarray, offset: float, how: str) -> np.ndarray:
    """(N, 3) points onto the plane: along their rays (``"ray"``) or orthogonally (``"normal"``)."""
    if how == "ray":
        return project_on_plane(points, normal, offset)
    return points - (points @ normal - offset)[:, None] * normal


def _to_board(P: np.ndarray, T: np.ndarray, how: str) -> np.ndarray:
    """(N, 3) points put on the plane of T (its z = 0) and expressed in its board frame."""
    n = T[:3, 2]
    Tinv = np.linalg.inv(T)
    return project(P, n, float(n @ T[:3, 3]), how) @ Tinv[:3, :3].T + Tinv[:3, 3]


def _on_board(b: np.ndarray, board: Board) -> np.ndarray:
    x0, x1, y0, y1 = board.extent()
    return (b[:, 0] >= x0) & (b[:, 0] <= x1) & (b[:, 1] >= y0) & (b[:, 1] <= y1)


def _core(b: np.ndarray, P: np.ndarray, T: np.ndarray, board: Board, s_z: float) -> np.ndarray:
    """(N,) bool: projected board coordinates b (N, 3) at least ``3 s_z tan(incidence)`` inside the board.

    A return's in-plane position moves with its noise (along the ray); selecting returns by it
    at the board's edge would keep those whose noise points one way on one side and the other way
    on the other side, and tilt the plane fitted to them.
    """
    u = P / np.linalg.norm(P, axis=1)[:, None]
    cos_i = np.clip(np.abs(u @ T[:3, 2]), 0.2, 1.0)
    x0, x1, y0, y1 = board.extent()
    inset = np.minimum(3.0 * s_z * np.sqrt(1 - cos_i**2) / cos_i + 0.005, 0.25 * (y1 - y0))
    core = (
        (b[:, 0] >= x0 + inset) & (b[:, 0] <= x1 - inset) & (b[:, 1] >= y0 + inset) & (b[:, 1] <= y1 - inset)
    )
    if core.sum() < 30:
        core = _on_board(b, board)
    return core


def _half_turn(T: np.ndarray, cov: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray]:
    """The same board's pose turned by pi about its normal through the pattern's centre, and its
    covariance (Pose3 tangent: xi' = Ad(H^-1) xi, H^-1 = H).

    The stage returns the pose whose board y axis points up (non-negative LiDAR z) when the two
    cannot be told apart: leaving the choice to floating-point ties made it change between numpy
    versions.
    """
    c = board.pattern_centre[:2]
    H = np.eye(4)
    H[:2, :2] = -np.eye(2)
    H[:2, 3] = 2 * c
    R, t = H[:3, :3], H[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Ad = np.zeros((6, 6))
    Ad[:3, :3], Ad[3:, 3:], Ad[3:, :3] = R, R, tx @ R
    return T @ H, Ad @ cov @ Ad.T


@dataclass
class _InPlane:
    """A board's in-plane fit: pose T (on its plane), the pool's returns it used, the plane noise
    s_z, the in-plane covariance (rz, tx, ty) given the plane and the coupling K to it, the
    intensity classes' thresholds and levels (None without a visible print), diagnostics, the board."""

    T: np.ndarray
    P: np.ndarray
    inten: np.ndarray
    ring: np.ndarray
    s_z: float
    cov: np.ndarray
    K: np.ndarray
    tau: tuple[float, float] | None = None
    levels: tuple[float, float] | None = None
    diag: dict[str, float] = field(default_factory=dict)
    board: Board | None = None  # the board as measured, when the scan contradicts the configured margin


def _plane_passes(P: np.ndarray, ring: np.ndarray, T: np.ndarray, board: Board, options: LidarOptions,
                  black_of: Callable[[np.ndarray], np.ndarray] | None = None,
                  ) -> tuple[np.ndarray, float]:  # fmt: skip
    """The plane refitted twice on the returns well inside the board at T (the white print's plane
    when ``black_of(mask)`` says which are black), T aligned to it; and the plane noise."""
    s_z = 0.02
    for _ in range(2):
        b = _to_board(P, T, options.projection)
        on = _on_board(b, board)
        if on.sum() < 30:
            raise BoardNotFound(
                f"only {int(on.sum())} points fall on the fitted board; the fit is not trustworthy "
                + breach("returns on the board", float(on.sum()), "<", 30.0)
            )
        core = _core(b, P, T, board, s_z)
        Tinv = np.linalg.inv(T)
        pf = plane_fit(P[core] @ Tinv[:3, :3].T + Tinv[:3, 3], None if black_of is None else black_of(core),
                       ring[core])  # fmt: skip
        s_z = pf.sigma
        rx, ry, tz = pf.coef[:3]
        n_b = np.array([ry, -rx, 1.0]) / np.sqrt(1 + rx * rx + ry * ry)  # plane normal, board frame
        n = T[:3, :3] @ n_b
        T = align_to_plane(T, n, float(n @ (T[:3, :3] @ np.array([0.0, 0.0, tz]) + T[:3, 3])))
    return T, s_z


def _refine(
    P: np.ndarray, inten: np.ndarray, ring: np.ndarray, T0: np.ndarray, s_z: float, board: Board,
    model: LidarModel, fit: InPlaneFit, options: LidarOptions,
) -> _InPlane:  # fmt: skip
    """The soft-edged intensity refinement from T0, its covariance (plus the edges' sampling) and
    coupling; BoardNotFound when the fitted pattern does not explain the intensities."""
    b = _to_board(P, T0, options.projection)
    on = _on_board(b, board)
    if on.sum() < 30:
        raise BoardNotFound(
            f"only {int(on.sum())} points fall on the fitted board; the fit is not trustworthy "
            + breach("returns on the board", float(on.sum()), "<", 30.0)
        )
    dist = float(np.linalg.norm(P[on].mean(axis=0)))
    blur0 = 0.5 * dist * max(model.beam_divergence_rad, np.deg2rad(model.horizontal_resolution_deg))
    soft = soft_edge_refine(b[on, :2], inten[on], board, fit.levels, blur0)
    T, cov_soft = T0, soft.cov
    if options.refine and soft.converged:
        H = se2_exp(soft.xi)  # the in-plane correction, Pose3.Expmap((0, 0, rz, tx, ty, 0))
        E = np.eye(4)
        E[:2, :2], E[:2, 3] = H[:2, :2], H[:2, 2]
        T = T0 @ E
    else:  # the start pose kept: its error covers where the soft model would have put it
        cov_soft = soft.cov + np.outer(soft.xi, soft.xi)
    b_fin = _to_board(P[on], T, options.projection)
    cls = intensity_classes(inten[on], *fit.tau)
    agree = colour_agreement(b_fin[:, :2], cls, board, soft.blur, dist, options.min_agreement)
    cov_q = sampling_covariance(b_fin[:, :2], cls, ring[on], board, soft.blur)
    K = np.zeros((3, 3))
    if options.projection == "ray":
        _, grad = soft_intensity(b_fin[:, :2], board, soft.a, soft.c, soft.blur)
        Tinv = np.linalg.inv(T)
        u_b = P[on] @ Tinv[:3, :3].T / np.linalg.norm(P[on], axis=1)[:, None]  # rays, board frame
        K = ray_coupling(b_fin[:, :2], u_b, (grad**2).sum(axis=1))
    levels = (soft.a, soft.a + soft.c) if soft.converged else fit.levels
    diag = {
        "soft_converged": float(soft.converged), "soft_blur_m": soft.blur, "soft_scale": soft.scale,
        "refine_shift_mm": 1e3 * float(np.linalg.norm(soft.xi[1:])), "colour_agreement": agree,
        "sigma_soft_txy_mm": 1e3 * float(np.sqrt(max(np.trace(soft.cov[1:, 1:]), 0.0))),
        "sigma_sampling_txy_mm": 1e3 * float(np.sqrt(max(np.trace(cov_q[1:, 1:]), 0.0))),
    }  # fmt: skip
    return _InPlane(T, P, inten, ring, s_z, cov_soft + cov_q, K, fit.tau, levels, diag)


def _pattern(
    P: np.ndarray, inten: np.ndarray, ring: np.ndarray, normal: np.ndarray, offset: float, board: Board,
    model: LidarModel, options: LidarOptions, rng: np.random.Generator, scan_pts: np.ndarray,
) -> _InPlane:  # fmt: skip
    """The paper's intensity fit, refined, checked against the outline (moved by whole squares to
    where the outline allows when it slid) and, with ``options.shape == "fuse"``, combined with it."""
    t0 = time.perf_counter()
    Pp = project(P, normal, offset, options.projection)
    frame = plane_frame(Pp, normal, offset)
    try:
        fit = fit_in_plane((Pp - frame.origin) @ frame.axes[:2].T, inten, board, options, rng)
    except ValueError as e:
        raise BoardNotFound(f"the board's points show no black/white contrast ({e})") from None
    t_powell = time.perf_counter() - t0
    black = lambda m: intensity_classes(inten[m], *fit.tau) == 0  # noqa: E731
    T, s_z = _plane_passes(P, ring, pose_from_in_plane(frame, fit.params), board, options, black)
    res = _refine(P, inten, ring, T, s_z, board, model, fit, options)
    res.diag.update({"powell_evals": float(fit.n_evals), "time_powell_s": t_powell, "cost": float(fit.cost),
                     "intensity_low": fit.levels[0], "intensity_high": fit.levels[1]})  # fmt: skip
    if options.shape == "off":
        return res
    ob, margin = outline_board(scan_pts, res.T, res.cov, board, model, s_z, options)  # margin measured
    res.diag.update(margin)
    if ob is None:  # the scan contradicts the configured margin and does not show the board's own
        return res
    if ob is not board:  # the plane fitted again on the returns of the board as measured
        res.T, res.s_z = _plane_passes(P, ring, res.T, ob, options, black)
        res.board = ob
    first = chk = shape_check(scan_pts, res.T, res.cov, ob, model, res.s_z, options, rng)
    moved = 0.0
    if chk.slid:  # the pattern moved by whole squares (or half-turned) to where the outline is
        res, chk, moved = _moved_to_outline(res, chk, fit, scan_pts, (board, ob), model, options, rng)
    res.diag.update(
        shape_diagnostics(chk.fit, first) | {"shape_chi2_final": chk.chi2, "pattern_moved_squares": moved}
    )
    if options.shape == "fuse" and chk.consistent:
        K_s = outline_coupling(chk.samples, chk.fit, ob)
        xi, res.cov, res.K = fuse(res.cov, res.K, chk, K_s)
        res.T = apply_xi(res.T, xi)
    return res


def _centre_shift(xi: np.ndarray, board: Board) -> np.ndarray:
    """(2,) where the in-plane correction xi's turn alone moves the board origin, for a turn about
    the pattern's centre (so a half turn in place counts as no move)."""
    c = board.pattern_centre[:2]
    w = float(xi[0])
    R = np.array([[np.cos(w), -np.sin(w)], [np.sin(w), np.cos(w)]])
    return c - R @ c


def _moved_to_outline(
    res: _InPlane, chk: ShapeCheck, fit: InPlaneFit, scan_pts: np.ndarray, boards: tuple[Board, Board],
    model: LidarModel, options: LidarOptions, rng: np.random.Generator,
) -> tuple[_InPlane, ShapeCheck, float]:  # fmt: skip
    """A slid pattern fit moved by the whole squares (up to two along each side) and/or the half turn
    the outline allows, refined again there: the first that agrees with the outline, its check and
    the move in squares; BoardNotFound when none does. When no move agrees with the whole outline,
    the same with the outline less one edge's samples (``outline.EDGE_LEFT_OUT_REACH``): a hand or a
    stand beside an edge draws the outline out by centimetres, more than its covariance says, and the
    pattern, which does not slide by less than a square, is checked by the other three edges. boards:
    the configured one (the pattern's) and the one whose outline checks it (``margin.outline_board``)."""
    board, ob = boards
    gate = shape_gate(options)
    keep = ("powell_evals", "time_powell_s", "intensity_low", "intensity_high")
    edge_rng = copy.deepcopy(rng)  # the edges' checks leave the stage's draws as they were
    precise = inplane_reach(res.cov, ob) <= EDGE_LEFT_OUT_REACH * ob.square_size  # no slide by half a square
    for edge in (None, 0, 1, 2, 3) if precise else (None,):
        check = chk
        if edge is not None:
            check = shape_check(scan_pts, res.T, res.cov, ob, model, res.s_z, options, edge_rng, edge)
            if inplane_reach(check.fit.cov, ob) > EDGE_LEFT_OUT_REACH * ob.square_size:
                continue  # without that edge the outline cannot tell a square's slide
            if not check.slid:
                res.diag["outline_edge_left_out"] = float(edge)
                return res, check, 0.0
        for xi in lattice_moves(ob, check, res.cov, gate)[:4]:
            try:
                alt = _refine(
                    res.P, res.inten, res.ring, apply_xi(res.T, xi), res.s_z, board, model, fit, options
                )
            except BoardNotFound:
                continue
            r = rng if edge is None else edge_rng
            same = edge if edge is None or abs(xi[0]) < 0.5 * np.pi else edge ^ 1  # a half turn: x0 is x1
            alt_chk = shape_check(scan_pts, alt.T, alt.cov, ob, model, res.s_z, options, r, same)
            if not alt_chk.slid:
                # (the paper's cost was Powell's, at the slid pose: not carried over)
                alt.diag.update({k: res.diag[k] for k in keep})
                if same is not None:
                    alt.diag["outline_edge_left_out"] = float(same)
                shift = se2_exp(xi)[:2, 2] - _centre_shift(xi, board)
                return alt, alt_chk, float(np.linalg.norm(shift)) / board.square_size
    raise BoardNotFound(slid_message(chk, board, options))


def _outline(
    P: np.ndarray, inten: np.ndarray, ring: np.ndarray, normal: np.ndarray, offset: float, board: Board,
    model: LidarModel, options: LidarOptions, rng: np.random.Generator, scan_pts: np.ndarray,
) -> _InPlane:  # fmt: skip
    """The in-plane pose from the board's outline alone (no print in the intensities)."""
    Pp = project(P, normal, offset, options.projection)
    frame = plane_frame(Pp, normal, offset)
    T0 = pose_from_in_plane(frame, np.array([0.0, *board.pattern_centre[:2]]))  # board centre at the centroid
    s_z0 = max(0.01, 1.4826 * float(np.median(np.abs((P - Pp) @ normal))))
    T1 = outline_only(scan_pts, T0, board, model, s_z0, options, rng)
    T, s_z = _plane_passes(P, ring, T1, board, options)
    s = outline_samples(scan_pts, T, board, model, s_z, options.outline_blur)
    shape = outline_posterior(s, board, rng)
    refuse_outline(shape, float(np.linalg.norm(T[:3, 3])), board, options)
    K = outline_coupling(s, shape, board)
    diag = shape_diagnostics(shape) | {"no_contrast": 1.0}
    return _InPlane(apply_xi(T, shape.xi), P, inten, ring, s_z, shape.cov, K, None, None, diag)


def _refuse_untrustworthy(cov: np.ndarray, board: Board, options: LidarOptions) -> None:
    """BoardNotFound when the covariance is not finite and positive definite, or the board's
    corners are known in its plane only to more than ``max_inplane_2sigma_squares`` squares (2 sigma)."""
    if not np.all(np.isfinite(cov)) or np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() <= 0:
        raise BoardNotFound("the fit's covariance is not finite: the returns do not fix the board's pose")
    reach = inplane_reach(cov[2:5, 2:5], board)  # (rz, tx, ty) of the Pose3 tangent
    if reach > options.max_inplane_2sigma_squares * board.square_size:
        raise BoardNotFound(
            f"the scan fixes the board's position in its plane only to +-{1e3 * reach:.0f} mm (2 sigma), "
            f"more than {options.max_inplane_2sigma_squares:g} square ({1e3 * board.square_size:.0f} mm) "
            + breach(
                "max_inplane_2sigma_squares",
                reach / board.square_size,
                ">",
                options.max_inplane_2sigma_squares,
                "squares",
            )
        )


def fit_board_points(
    points: np.ndarray,
    intensity: np.ndarray,
    normal: np.ndarray,
    offset: float,
    board: Board,
    lidar_model: LidarModel,
    options: LidarOptions = LidarOptions(),
    rng: np.random.Generator | None = None,
    ring: np.ndarray | None = None,
    scan_points: np.ndarray | None = None,
    contrast: bool | None = None,
) -> BoardFit:
    """Pose, corners and covariance from the board's points (M, 3) LiDAR frame and intensities (M,).

    normal/offset: the plane ``normal @ p = offset`` with the normal towards the sensor.
    ring: (M,) beam index of the points (None: from their elevation).
    scan_points: (N, 3) every return of the scan (the outline's evidence: rays that pass the
    board's plane near the board); None: the points alone (no pass-through evidence).
    contrast: whether the intensities show the print (None: judged from them,
    ``board_tests.print_visible``); without it the in-plane pose comes from the outline.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    rng = np.random.default_rng(0) if rng is None else rng
    P = np.asarray(points, dtype=np.float64)
    inten = np.asarray(intensity, dtype=np.float64)
    ring = lidar_model.ring_from_points(P) if ring is None else np.asarray(ring)
    scan_pts = P if scan_points is None else np.asarray(scan_points, dtype=np.float64)
    visible = (
        print_visible(inten, P, options.print_contrast_min, ring)[0] if contrast is None else bool(contrast)
    )
    how = _pattern if visible else _outline
    res = how(P, inten, ring, normal, offset, board, lidar_model, options, rng, scan_pts)
    board = res.board or board  # the board as measured, when the scan contradicts the configured margin
    fit = _finish(res, board, lidar_model, options, not visible, t0, c0)
    if scan_points is not None:  # the part beyond a cropped scan's window, too
        fit.diagnostics["outside_fov_share"] = fov_share(fit.T_lidar_board, board, lidar_model, scan_pts)
    return fit


def _finish(res: _InPlane, board: Board, model: LidarModel, options: LidarOptions, no_print: bool,
            t0: float, c0: float) -> BoardFit:  # fmt: skip
    """The plane at the final pose, the covariance (refused when untrustworthy), the half turn, the
    corners, the returns and diagnostics."""
    T, P, inten, ring = res.T, res.P, res.inten, res.ring
    b = _to_board(P, T, options.projection)
    on = _on_board(b, board)
    core = _core(b, P, T, board, res.s_z)
    Tinv = np.linalg.inv(T)
    b_raw = P[core] @ Tinv[:3, :3].T + Tinv[:3, 3]
    cls = intensity_classes(inten[core], *res.tau) if res.tau is not None else np.ones(int(core.sum()), int)
    pf = plane_fit(b_raw, cls == 0 if res.tau is not None else None, ring[core])
    cov = options.covariance_inflation * assemble_covariance(pf.cov, res.cov, res.K)
    _refuse_untrustworthy(cov, board, options)
    ambiguous = board.half_turn_symmetric or no_print
    cost = float(res.diag.pop("cost", float("nan")))
    if ambiguous and T[2, 1] < 0:
        T, cov = _half_turn(T, cov, board)
    diag: dict[str, float] = {
        "n_points": float(on.sum()),
        "range_m": float(np.linalg.norm(P[on].mean(axis=0))),
        "plane_sigma_m": pf.sigma,
        "dark_offset_mm": -1e3 * float(pf.coef[3]),
        "plane_residual_coef_mm": 1e3 * float(np.abs(pf.coef[:3]).max()),
        "plane_cov_clustered": float(pf.clustered),
        "outside_fov_share": fov_share(T, board, model),
        **res.diag,
    }
    if res.tau is not None:
        diag.update({"tau_l": res.tau[0], "tau_h": res.tau[1]})
    diag.update({"time_fit_s": time.perf_counter() - t0, "cpu_fit_s": time.process_time() - c0})
    return BoardFit(
        T_lidar_board=T,
        covariance=cov,
        corners_lidar=board.corners_board() @ T[:3, :3].T + T[:3, 3],
        points_lidar=P[on],
        intensity=inten[on],
        half_turn_ambiguous=ambiguous,
        cost=cost,
        diagnostics=diag,
        returns=_returns(P[core], ring[core], cls, pf, b_raw, cov, inten[core], res.levels),
    )


def _returns(
    points: np.ndarray, ring: np.ndarray, cls: np.ndarray, pf: PlaneFit, b_raw: np.ndarray, cov: np.ndarray,
    inten: np.ndarray, levels: tuple[float, float] | None,
) -> BoardReturns:  # fmt: skip
    """The board's returns for the estimation core: those well inside the board (``points``, their
    board-frame coordinates ``b_raw``), clearly black or white, within 3 sigma of the plane fit ``pf``;
    and the in-plane part of the final covariance ``cov`` (same board frame):
    ``cov_in = C_ii - K C_oo K^T``, ``K = C_io C_oo^-1`` (``covariance.assemble_covariance``).

    Each return's darkness is its intensity between the board's black and white ``levels``
    (1 black, 0 white, clipped): a footprint on both colours returns a blend, and the range walk of a
    weak return follows its strength, not the class it is sorted into. Without a print the LiDAR
    shows (``levels`` None) every return counts as white (darkness 0): nothing tells the print apart."""
    rx, ry, tz, delta = pf.coef[:4] if len(pf.coef) > 3 else (*pf.coef[:3], 0.0)
    res = b_raw[:, 2] - (tz + rx * b_raw[:, 1] - ry * b_raw[:, 0] + delta * (cls == 0))
    keep = (cls >= 0) & (np.abs(res) < 3.0 * pf.sigma)
    io, ii = [0, 1, 5], [2, 3, 4]
    C_oo, C_io = cov[np.ix_(io, io)], cov[np.ix_(ii, io)]
    K = np.linalg.solve(C_oo.T, C_io.T).T
    cov_in = cov[np.ix_(ii, ii)] - K @ C_oo @ K.T
    if levels is None:
        dark = np.zeros(int(keep.sum()))
    else:
        lo, hi = (float(v) for v in levels)
        if hi - lo > 1e-9:
            dark = np.clip((hi - np.asarray(inten, dtype=np.float64)[keep]) / (hi - lo), 0.0, 1.0)
        else:
            dark = (cls[keep] == 0).astype(np.float64)
    return BoardReturns(
        points[keep], np.asarray(ring)[keep], dark, float(pf.sigma), 0.5 * (cov_in + cov_in.T), K,
        outline=levels is None,
    )  # fmt: skip
