"""Graph-level synthetic frames for the joint, incremental and range-offset tests and benchmarks.

Boards are placed at random around (or in front of) the sensors; each camera's bearings carry noise
drawn from the pixel covariance mapped through the camera model; each board prior is the pose a
LiDAR with a range offset ``b`` would report (an exact rigid fit to the board's face points pushed
by ``b`` along their rays, *not* the first-order model of ``factors.range_offset``) times
``Expmap(xi)``, ``xi ~ N(0, board_cov)``. Seeded by the caller's ``np.random.Generator``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import gtsam
import numpy as np

from factors.testing import sample_bearing
from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.estimation.graphs import board_face_samples
from ilcc_graph.init.rig_start import orient_corners, orient_fit
from ilcc_graph.types import BoardFit, GraphFrame, ImageCorners, MomentResult

BOARD_SIGMAS = (2e-3, 2e-3, 1e-3, 3e-3, 3e-3, 2e-3)


def random_spd(rng: np.random.Generator, sigmas: np.ndarray) -> np.ndarray:
    """SPD matrix with a random orientation and the given standard deviations."""
    Q, _ = np.linalg.qr(rng.standard_normal((len(sigmas), len(sigmas))))
    return Q @ np.diag(np.asarray(sigmas) ** 2) @ Q.T


def random_board_pose(
    rng: np.random.Generator,
    board: Board,
    towards: np.ndarray | None = None,
    spread: float = 0.35,
    distance: tuple[float, float] = (1.5, 5.0),
) -> gtsam.Pose3:
    """A board 1.5-5 m from the LiDAR facing it (tilted ~0.4 rad); all around, or near ``towards`` (3,)."""
    if towards is None:
        az, el = rng.uniform(-np.pi, np.pi), rng.uniform(-0.35, 0.35)
    else:
        t = np.asarray(towards, dtype=np.float64)
        az0, el0 = np.arctan2(t[1], t[0]), np.arctan2(t[2], np.hypot(t[0], t[1]))
        az, el = az0 + rng.uniform(-spread, spread), el0 + rng.uniform(-0.6 * spread, 0.6 * spread)
    d = rng.uniform(*distance)
    c = d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    z = gtsam.Rot3.Expmap(rng.normal(0, 0.4, 3)).rotate(-c / d)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    return gtsam.Pose3(gtsam.Rot3(R), c - R @ board.corners_board().mean(axis=0))


def _kabsch(P: np.ndarray, Q: np.ndarray) -> gtsam.Pose3:
    """Rigid T minimising sum |T P_k - Q_k|^2."""
    cp, cq = P.mean(axis=0), Q.mean(axis=0)
    U, _, Vt = np.linalg.svd((P - cp).T @ (Q - cq))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return gtsam.Pose3(gtsam.Rot3(R), cq - R @ cp)


def lidar_board_pose(T_lidar_board: gtsam.Pose3, board: Board, range_offset_m: float) -> gtsam.Pose3:
    """The board pose a LiDAR reading ``range_offset_m`` long fits (exact rigid fit, no noise)."""
    if range_offset_m == 0.0:
        return T_lidar_board
    S = board_face_samples(board)
    p = np.asarray(T_lidar_board.transformFrom(S.T)).T
    q = p + range_offset_m * p / np.linalg.norm(p, axis=1, keepdims=True)
    return _kabsch(S, q)


def observe(
    rng: np.random.Generator,
    camera: CameraModel,
    T_cam_lidar: gtsam.Pose3,
    T_lidar_board: gtsam.Pose3,
    points_board: np.ndarray,
    sigma_px: float = 0.5,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Noisy bearings (K, 3) and pixel covariances (K, 2, 2); None unless every corner is in the image."""
    p_cam = np.asarray(T_cam_lidar.compose(T_lidar_board).transformFrom(points_board.T)).T
    uv = camera.project(p_cam)
    if not np.all(np.isfinite(uv)) or not np.all(camera.in_image(uv)):
        return None
    b_true = p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
    cov_px = np.stack([random_spd(rng, sigma_px * rng.uniform(0.6, 1.4, 2)) for _ in points_board])
    bases = np.stack([gtsam.Unit3(b).basis() for b in b_true])
    cov_t = camera.bearing_tangent_cov(b_true, cov_px, bases)
    return sample_bearing(rng, b_true, cov_t), cov_px


def board_prior(
    rng: np.random.Generator,
    T_lidar_board: gtsam.Pose3,
    board: Board,
    range_offset_m: float = 0.0,
    board_sigmas: tuple[float, ...] = BOARD_SIGMAS,
) -> tuple[np.ndarray, np.ndarray]:
    """The LiDAR stage's answer: (T_measured (4, 4), covariance (6, 6)) drawn from the covariance."""
    cov = random_spd(rng, np.asarray(board_sigmas) * rng.uniform(0.7, 1.3, 6))
    xi = rng.multivariate_normal(np.zeros(6), cov)
    T = lidar_board_pose(T_lidar_board, board, range_offset_m)
    return np.asarray(T.compose(gtsam.Pose3.Expmap(xi)).matrix()), cov


def session_frames(
    rng: np.random.Generator,
    n_frames: int,
    camera: CameraModel,
    T_cam_lidar: gtsam.Pose3,
    board: Board,
    range_offset_m: float = 0.0,
    sigma_px: float = 0.5,
    towards: np.ndarray | None = None,
    prefix: str = "",
) -> tuple[list[GraphFrame], dict[str, gtsam.Pose3]]:
    """``n_frames`` frames of one camera (boards redrawn until fully in its image) and true board poses."""
    p_board = board.corners_board()
    frames, truth = [], {}
    while len(frames) < n_frames:
        T_lb = random_board_pose(rng, board, towards)
        obs = observe(rng, camera, T_cam_lidar, T_lb, p_board, sigma_px)
        if obs is None:
            continue
        T_meas, cov = board_prior(rng, T_lb, board, range_offset_m)
        name = f"{prefix}{len(frames):04d}"
        frames.append(GraphFrame(name, T_meas, cov, p_board, obs[0], obs[1]))
        truth[name] = T_lb
    return frames, truth


def rig_moments(
    rng: np.random.Generator,
    n_moments: int,
    cameras: Mapping[str, CameraModel],
    T_cam_base: Mapping[str, gtsam.Pose3],
    board: Board,
    T_base_lidar: Mapping[str, gtsam.Pose3] | None = None,
    sigma_px: float = 0.5,
    min_views: int = 1,
    turn: bool = True,
    lidar_sees: Callable[[int, str], bool] | None = None,
    distance: tuple[float, float] = (1.5, 4.0),
    range_offset_m: float = 0.0,
) -> tuple[list[MomentResult], dict[str, gtsam.Pose3]]:
    """A rig's moments as its stages would report them: boards all around the base LiDAR (the first
    of ``T_base_lidar``, default one LiDAR ``lidar`` at the origin); each camera that sees the whole
    board gives image corners, each LiDAR facing the board's printed side a board fit (pose drawn from
    its covariance, as ``board_prior``). turn: each observation's corner order half-turned at random
    (the stages know it only up to the half turn). lidar_sees(k, lidar): whether LiDAR ``lidar`` scans
    the board of moment k (default: every LiDAR the board faces). min_views: camera views per moment.
    range_offset_m: the base LiDAR reads this much long (its fits as ``lidar_board_pose`` gives them).
    Returns the moments and the true ``T_base_board`` per moment."""
    lidars = dict(T_base_lidar or {"lidar": gtsam.Pose3()})
    p_board = board.corners_board()
    out: list[MomentResult] = []
    truth: dict[str, gtsam.Pose3] = {}
    while len(out) < n_moments:
        T_bb = random_board_pose(rng, board, distance=distance)
        corners = {}
        for name, cam in cameras.items():
            obs = observe(rng, cam, T_cam_base[name], T_bb, p_board, sigma_px)
            if obs is not None:
                uv = cam.project(obs[0])
                corners[name] = ImageCorners(uv, obs[0], obs[1], board.half_turn_symmetric)
        if len(corners) < min_views:
            continue
        k = len(out)
        fits = {}
        for name, T_bl in lidars.items():
            T_lb = T_bl.inverse().compose(T_bb)
            normal, centre = T_lb.rotation().matrix()[:, 2], T_lb.transformFrom(p_board.mean(axis=0))
            faces = float(normal @ centre) < -0.2 * np.linalg.norm(centre)
            if not (lidar_sees(k, name) if lidar_sees is not None else faces):
                continue
            T_meas, cov = board_prior(rng, T_lb, board, range_offset_m if name == next(iter(lidars)) else 0.0)
            c_lidar = p_board @ T_meas[:3, :3].T + T_meas[:3, 3]
            empty = (np.zeros((0, 3)), np.zeros(0))
            fits[name] = BoardFit(T_meas, cov, c_lidar, *empty, board.half_turn_symmetric)
        if turn and board.half_turn_symmetric:
            fits = {n: orient_fit(f, board) if rng.random() < 0.5 else f for n, f in fits.items()}
            corners = {n: orient_corners(c, board) if rng.random() < 0.5 else c for n, c in corners.items()}
        name = f"{k + 1:04d}"
        out.append(MomentResult(name, fits, corners))
        truth[name] = T_bb
    return out, truth


def board_returns(
    rng: np.random.Generator,
    T_lidar_board: gtsam.Pose3,
    board: Board,
    elevations_deg: np.ndarray,
    beam_offsets_m: np.ndarray,
    dark_offset_m: float = 0.0,
    sigma_m: float = 0.01,
    step_deg: float = 0.2,
    inplane_sigmas: tuple[float, float, float] = (2e-3, 1.5e-3, 1.5e-3),
    bend: tuple[float, float, float] = (0.0, 0.0, 0.0),
    beam_jitter_m: float = 0.0,
):
    """A spinning LiDAR's returns from the board's face, with per-beam range offsets and a dark-print
    offset (measured minus true range), and the in-plane pose an intensity fit would report.
    bend: (delta m, alpha, beta rad) the real face's height ``delta + alpha x + beta y`` above the
    board frame's plane (board-frame x, y): a bent or tilted print. beam_jitter_m: sigma of an extra
    range offset of each beam on this board (drawn per beam).

    Returns (BoardReturns, T_measured (4, 4), covariance (6, 6)): T_measured is the truth moved by
    an in-plane error drawn from ``inplane_sigmas`` (rz, tx, ty) and by the plane of the biased
    returns (a least-squares plane, as the LiDAR stage fits it); the covariance holds the in-plane
    sigmas and the plane fit's.
    """
    from ilcc_graph.types import BoardReturns

    R, t = T_lidar_board.rotation().matrix(), T_lidar_board.translation()
    n = R[:, 2]
    x0, x1, y0, y1 = board.extent()
    c = T_lidar_board.transformFrom(np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0]))
    az0 = np.arctan2(c[1], c[0])
    span = np.hypot(x1 - x0, y1 - y0) / np.linalg.norm(c)
    az = az0 + np.arange(-span, span, np.radians(step_deg))
    pts, ring, dark = [], [], []
    for b, el in enumerate(np.radians(elevations_deg)):
        d = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.full(az.size, np.sin(el))])
        s = (n @ t) / (d @ n)
        ok = s > 0
        p = d[ok] * s[ok, None]
        pb = (p - t) @ R
        inside = (pb[:, 0] > x0) & (pb[:, 0] < x1) & (pb[:, 1] > y0) & (pb[:, 1] < y1)
        if not inside.any():
            continue
        p, pb, dd = p[inside], pb[inside], d[ok][inside]
        w = 1.0 - board.colour_at(pb[:, :2])
        noise = rng.normal(0, sigma_m, len(p))
        h = bend[0] + bend[1] * pb[:, 0] + bend[2] * pb[:, 1]  # the real face, along the ray
        jitter = rng.normal(0, beam_jitter_m) if beam_jitter_m > 0 else 0.0
        rng_m = (
            np.linalg.norm(p, axis=1) + h / (dd @ n) + beam_offsets_m[b] + jitter + w * dark_offset_m + noise
        )
        pts.append(dd * rng_m[:, None])
        ring.append(np.full(len(p), b))
        dark.append(w)
    P, ring, dark = np.vstack(pts), np.concatenate(ring), np.concatenate(dark)
    # the plane of the biased returns, in the true board frame (z = a + bx x + by y)
    pb = (P - t) @ R
    A = np.column_stack([np.ones(len(pb)), pb[:, 0], pb[:, 1]])
    coef, *_ = np.linalg.lstsq(A, pb[:, 2], rcond=None)
    res = pb[:, 2] - A @ coef
    cov_plane = np.var(res) * np.linalg.inv(A.T @ A)  # (tz, slope x, slope y)
    xi = np.zeros(6)
    xi[0], xi[1], xi[5] = coef[2], -coef[1], coef[0]  # rotation about x tilts y, about y tilts -x
    sig_in = np.asarray(inplane_sigmas)
    xi[[2, 3, 4]] = rng.normal(0, sig_in)
    T_meas = T_lidar_board.compose(gtsam.Pose3.Expmap(xi))
    cov = np.zeros((6, 6))
    J = np.zeros((3, 3))  # (rx, ry, tz) from (tz, slope x, slope y)
    J[0, 2], J[1, 1], J[2, 0] = 1.0, -1.0, 1.0
    cov[np.ix_([0, 1, 5], [0, 1, 5])] = J @ cov_plane @ J.T
    cov[np.ix_([2, 3, 4], [2, 3, 4])] = np.diag(sig_in**2)
    returns = BoardReturns(P, ring, dark, sigma_m, np.diag(sig_in**2), np.zeros((3, 3)))
    return returns, np.asarray(T_meas.matrix()), cov
