"""The board's pose from its points: the in-plane intensity fit, the plane refitted on the returns
well inside the board, the soft-edged refinement, the covariance, and the returns for the graph.

``fit_board_points(points, intensity, normal, offset, board, lidar_model, options) -> BoardFit``
(raises ``BoardNotFound`` when the fitted chessboard does not explain the returns). LiDAR frame,
metres; the pose is ``T_lidar_board`` with the covariance in its Pose3 tangent.
"""

from __future__ import annotations

import time

import numpy as np

from ..board import Board
from ..errors import BoardNotFound
from ..lidars import LidarModel
from ..types import BoardFit, BoardReturns
from .cost import intensity_classes
from .covariance import assemble_covariance, plane_fit, ray_coupling, sampling_covariance
from .fit import fit_in_plane, plane_frame, pose_from_in_plane, project_on_plane
from .options import LidarOptions
from .soft_edge import se2_exp, soft_edge_refine, soft_intensity

__all__ = ["fit_board_points", "project"]


def _align_to_plane(T: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """T_lidar_board turned by the smallest rotation to make its z ``normal``; its origin put on the plane."""
    z = T[:3, 2]
    v = np.cross(z, normal)
    sn, cs = np.linalg.norm(v), float(z @ normal)
    R = np.eye(3)
    if sn > 1e-12:
        k = v / sn
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R = np.eye(3) + sn * K + (1 - cs) * K @ K
    out = np.eye(4)
    out[:3, :3] = R @ T[:3, :3]
    o = T[:3, 3]
    out[:3, 3] = o - (o @ normal - offset) * normal
    return out


def project(points: np.ndarray, normal: np.ndarray, offset: float, how: str) -> np.ndarray:
    """(N, 3) points onto the plane: along their rays (``"ray"``) or orthogonally (``"normal"``)."""
    if how == "ray":
        return project_on_plane(points, normal, offset)
    return points - (points @ normal - offset)[:, None] * normal


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
        core = (b[:, 0] >= x0) & (b[:, 0] <= x1) & (b[:, 1] >= y0) & (b[:, 1] <= y1)
    return core


def _half_turn(T: np.ndarray, cov: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray]:
    """The equivalent pose of a half-turn symmetric board turned by pi about its normal through
    the pattern's centre, and its covariance (Pose3 tangent: xi' = Ad(H^-1) xi, H^-1 = H).

    The stage returns the pose whose board y axis points up (non-negative LiDAR z): the two poses
    fit equally well, and leaving the choice to floating-point ties made it change between numpy
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


def fit_board_points(
    points: np.ndarray,
    intensity: np.ndarray,
    normal: np.ndarray,
    offset: float,
    board: Board,
    lidar_model: LidarModel,
    options: LidarOptions = LidarOptions(),
    rng: np.random.Generator | None = None,
    pool: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ring: np.ndarray | None = None,
) -> BoardFit:
    """Pose, corners and covariance from the board's points (M, 3) LiDAR frame and intensities (M,).

    normal/offset: the plane ``normal @ p = offset`` with the normal towards the sensor.
    ring: (M,) beam index of the points (None: from their elevation).
    pool: optional (points (L, 3), intensities (L,), rings (L,)) near the plane from which the points
    on the fitted board are taken after the first fit (detection may have trimmed the board's corners).
    """
    t0, c0 = time.perf_counter(), time.process_time()
    rng = np.random.default_rng(0) if rng is None else rng
    P = np.asarray(points, dtype=np.float64)
    inten = np.asarray(intensity, dtype=np.float64)
    Pp = project(P, normal, offset, options.projection)
    frame = plane_frame(Pp, normal, offset)
    q = (Pp - frame.origin) @ frame.axes[:2].T
    try:
        fit = fit_in_plane(q, inten, board, options, rng)
    except ValueError as e:
        raise BoardNotFound(f"the board's points show no black/white contrast ({e})") from None
    T0 = pose_from_in_plane(frame, fit.params)
    t_powell = time.perf_counter() - t0

    # keep the points on the fitted board, refit the plane on them (drops a hand, the stand)
    ring = lidar_model.ring_from_points(P) if ring is None else np.asarray(ring)
    if pool is not None:
        P, inten, ring = np.asarray(pool[0], np.float64), np.asarray(pool[1], np.float64), np.asarray(pool[2])
    x0, x1, y0, y1 = board.extent()
    n_cur, d_cur = normal, offset
    T = T0
    s_z = 0.02
    for _ in range(2):
        Pp = project(P, n_cur, d_cur, options.projection)
        Tinv = np.linalg.inv(T)
        b = Pp @ Tinv[:3, :3].T + Tinv[:3, 3]
        on = (b[:, 0] >= x0) & (b[:, 0] <= x1) & (b[:, 1] >= y0) & (b[:, 1] <= y1)
        if on.sum() < 30:
            raise BoardNotFound(
                f"only {int(on.sum())} points fall on the fitted board; the fit is not trustworthy"
            )
        # the white print's plane (returns from black print may read long), in the current board frame,
        # from returns well inside the board (a selection at its edge would depend on the noise)
        core = _core(b, P, T, board, s_z)
        b_raw = P[core] @ Tinv[:3, :3].T + Tinv[:3, 3]
        black = intensity_classes(inten[core], *fit.tau) == 0
        pf = plane_fit(b_raw, black, ring[core])
        s_z = pf.sigma
        rx, ry, tz = pf.coef[:3]
        n_b = np.array([ry, -rx, 1.0]) / np.sqrt(1 + rx * rx + ry * ry)  # plane normal, board frame
        n_cur = T[:3, :3] @ n_b
        d_cur = float(n_cur @ (T[:3, :3] @ np.array([0.0, 0.0, tz]) + T[:3, 3]))
        T = _align_to_plane(T, n_cur, d_cur)
    Pp = project(P, n_cur, d_cur, options.projection)
    Tinv = np.linalg.inv(T)
    b = Pp @ Tinv[:3, :3].T + Tinv[:3, 3]
    on = (b[:, 0] >= x0) & (b[:, 0] <= x1) & (b[:, 1] >= y0) & (b[:, 1] <= y1)
    T0 = T

    dist = float(np.linalg.norm(P[on].mean(axis=0)))
    step = np.deg2rad(lidar_model.horizontal_resolution_deg)
    blur0 = 0.5 * dist * max(lidar_model.beam_divergence_rad, step)
    soft = soft_edge_refine(b[on, :2], inten[on], board, fit.levels, blur0)
    if options.refine and soft.converged:
        H = se2_exp(soft.xi)  # the in-plane correction, Pose3.Expmap((0, 0, rz, tx, ty, 0))
        E = np.eye(4)
        E[:2, :2], E[:2, 3] = H[:2, :2], H[:2, 2]
        T = T0 @ E
    # in-plane: intensity noise (soft model) plus the quantisation of the edges by the sampling
    Tinv = np.linalg.inv(T)
    b_fin = Pp[on] @ Tinv[:3, :3].T + Tinv[:3, 3]
    cls = intensity_classes(inten[on], *fit.tau)
    # the fitted pattern must explain the intensities: black returns on black squares, white on white
    # (away from the edges, where footprints straddle both)
    colour = board.colour_at(b_fin[:, :2])
    s_sq = board.square_size
    u = b_fin[:, :2] / s_sq
    inner = (np.abs(u - np.round(u)) > 0.15).all(axis=1) & (cls >= 0) & np.isfinite(colour)
    agree = float(np.mean(cls[inner] == colour[inner])) if inner.sum() >= 20 else 0.0
    if agree < options.min_agreement:
        raise BoardNotFound(
            f"a board-shaped object at {float(np.linalg.norm(P[on].mean(axis=0))):.2f} m, but the fitted "
            f"chessboard explains only {agree:.0%} of its black/white returns "
            f"(need {options.min_agreement:.0%})"
        )
    cov_q = sampling_covariance(b_fin[:, :2], cls, ring[on], board, soft.blur)
    cov_in = soft.cov + cov_q
    if not np.all(np.isfinite(cov_in)):
        s = board.square_size
        cov_in = np.diag([np.deg2rad(2.0) ** 2, (s / 4) ** 2, (s / 4) ** 2])

    # out-of-plane: the plane fit at the final pose
    core = _core(Pp @ Tinv[:3, :3].T + Tinv[:3, 3], P, T, board, s_z)
    b_raw = P[core] @ Tinv[:3, :3].T + Tinv[:3, 3]
    pf = plane_fit(b_raw, intensity_classes(inten[core], *fit.tau) == 0, ring[core])
    K = None
    if options.projection == "ray":
        _, grad = soft_intensity(b_fin[:, :2], board, soft.a, soft.c, soft.blur)
        u_b = P[on] @ Tinv[:3, :3].T / np.linalg.norm(P[on], axis=1)[:, None]  # rays, board frame
        K = ray_coupling(b_fin[:, :2], u_b, (grad**2).sum(axis=1))
    cov = options.covariance_inflation * assemble_covariance(pf.cov, cov_in, K)
    s_z = pf.sigma
    if board.half_turn_symmetric and T[2, 1] < 0:
        T, cov = _half_turn(T, cov, board)
    corners = board.corners_board() @ T[:3, :3].T + T[:3, 3]
    diag: dict[str, float] = {
        "n_points": float(on.sum()),
        "range_m": dist,
        "tau_l": fit.tau[0],
        "tau_h": fit.tau[1],
        "intensity_low": fit.levels[0],
        "intensity_high": fit.levels[1],
        "powell_evals": float(fit.n_evals),
        "soft_converged": float(soft.converged),
        "soft_blur_m": soft.blur,
        "soft_scale": soft.scale,
        "plane_sigma_m": s_z,
        "dark_offset_mm": -1e3 * float(pf.coef[3]),
        "plane_residual_coef_mm": 1e3 * float(np.abs(pf.coef[:3]).max()),
        "plane_cov_clustered": float(pf.clustered),
        "refine_shift_mm": 1e3 * float(np.linalg.norm(soft.xi[1:])),
        "colour_agreement": agree,
        "sigma_soft_txy_mm": 1e3 * float(np.sqrt(max(np.trace(soft.cov[1:, 1:]), 0.0))),
        "sigma_sampling_txy_mm": 1e3 * float(np.sqrt(max(np.trace(cov_q[1:, 1:]), 0.0))),
        "time_fit_s": time.perf_counter() - t0,
        "cpu_fit_s": time.process_time() - c0,
        "time_powell_s": t_powell,
    }
    return BoardFit(
        T_lidar_board=T,
        covariance=cov,
        corners_lidar=corners,
        points_lidar=P[on],
        intensity=inten[on],
        half_turn_ambiguous=board.half_turn_symmetric,
        cost=float(fit.cost),
        diagnostics=diag,
        returns=_returns(
            P[core],
            ring[core],
            intensity_classes(inten[core], *fit.tau),
            pf,
            b_raw,
            cov,
            inten[core],
            (soft.a, soft.a + soft.c) if soft.converged else fit.levels,
        ),  # fmt: skip
    )


def _returns(points, ring, cls, pf, b_raw, cov, inten, levels) -> BoardReturns:  # noqa: ANN001
    """The board's returns for the estimation core: those well inside the board (``points``, their
    board-frame coordinates ``b_raw``), clearly black or white, within 3 sigma of the plane fit ``pf``;
    and the in-plane part of the final covariance ``cov`` (same board frame):
    ``cov_in = C_ii - K C_oo K^T``, ``K = C_io C_oo^-1`` (``covariance.assemble_covariance``).

    Each return's darkness is its intensity between the board's black and white ``levels``
    (1 black, 0 white, clipped): a footprint on both colours returns a blend, and the range walk of a
    weak return follows its strength, not the class it is sorted into."""
    rx, ry, tz, delta = pf.coef[:4] if len(pf.coef) > 3 else (*pf.coef[:3], 0.0)
    res = b_raw[:, 2] - (tz + rx * b_raw[:, 1] - ry * b_raw[:, 0] + delta * (cls == 0))
    keep = (cls >= 0) & (np.abs(res) < 3.0 * pf.sigma)
    io, ii = [0, 1, 5], [2, 3, 4]
    C_oo, C_io = cov[np.ix_(io, io)], cov[np.ix_(ii, io)]
    K = np.linalg.solve(C_oo.T, C_io.T).T
    cov_in = cov[np.ix_(ii, ii)] - K @ C_oo @ K.T
    lo, hi = (float(v) for v in levels)
    if hi - lo > 1e-9:
        dark = np.clip((hi - np.asarray(inten, dtype=np.float64)[keep]) / (hi - lo), 0.0, 1.0)
    else:
        dark = (cls[keep] == 0).astype(np.float64)
    return BoardReturns(
        points[keep], np.asarray(ring)[keep], dark, float(pf.sigma), 0.5 * (cov_in + cov_in.T), K
    )
