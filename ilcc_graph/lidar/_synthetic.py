"""A small ray-cast scene generator for the LiDAR stage's own tests and benchmarks (no image rendering).

Scene: the chessboard (with its white margin) at a chosen pose, a wall behind it, the ground,
optionally a person-sized box touching the board and a thin stand under it. Rays follow the
LiDAR model's beams over an azimuth window; the range gets Gaussian noise along the ray, the
intensity comes from ``board.colour_at`` (black / white levels) or a per-surface level.
Not part of the public API; the project's simulator (ilcc_graph.simulate) is the full one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..board import Board
from ..lidars import LidarModel
from ..lidars.footprint import FOOTPRINT
from ..types import Scan


@dataclass(frozen=True)
class SynthScene:
    """Scene knobs. Distances in metres, angles in degrees, intensities in sensor units."""

    distance: float = 2.0
    azimuth_deg: float = 0.0
    elevation_deg: float = 0.0
    in_plane_deg: float = 0.0  # rotation of the board about its normal (45 = diamond)
    tilt_deg: tuple[float, float] = (0.0, 0.0)  # yaw / pitch of the board normal away from the sensor
    wall_gap: float | None = 1.0  # wall this far behind the board centre (None: no wall)
    ground_z: float | None = -1.5
    person: bool = False  # a 0.4 x 0.3 x 1.7 m box touching the board's right edge
    stand: bool = False  # a 4 cm pole from the board's lower edge to the ground
    black: float = 5.0
    white: float = 60.0
    intensity_sigma: float = 2.0
    range_sigma: float = 0.01
    azimuth_window_deg: float | None = 60.0  # None: full turn
    dropout: float = 0.0  # fraction of returns lost at random
    footprint: float = 0.01  # beam diameter at the sensor (m); grows with the model's divergence
    in_plane_sigma: float = 0.0016  # board points: Gaussian offsets within the board plane (m)
    # a board-sized panel facing the sensor at the board's distance and this azimuth, painted dark on
    # one half and bright on the other: it passes the paper's tests and the contrast test
    decoy_azimuth_deg: float | None = None
    decoy_distance: float | None = None  # None: the board's distance


def _rot(axis: np.ndarray, ang: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K


def board_pose(board: Board, sc: SynthScene) -> np.ndarray:
    """(4, 4) T_lidar_board for the scene: pattern centre at the given range/direction, z to the sensor."""
    az, el = np.deg2rad(sc.azimuth_deg), np.deg2rad(sc.elevation_deg)
    look = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    centre = sc.distance * look
    z = -look
    up = np.array([0.0, 0.0, 1.0])
    y = up - (up @ z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.stack([x, y, z], axis=1)
    R = _rot(y, np.deg2rad(sc.tilt_deg[0])) @ _rot(x, np.deg2rad(sc.tilt_deg[1])) @ R
    R = R @ _rot(np.array([0.0, 0.0, 1.0]), np.deg2rad(sc.in_plane_deg))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre - R @ board.pattern_centre
    return T


def _hit_rect(
    u: np.ndarray, T: np.ndarray, ext: tuple[float, float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    R, o = T[:3, :3], T[:3, 3]
    n = R[:, 2]
    den = u @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (o @ n) / den
    hit = t[:, None] * u
    local = (hit - o) @ R
    inside = (
        (t > 0)
        & (local[:, 0] >= ext[0])
        & (local[:, 0] <= ext[1])
        & (local[:, 1] >= ext[2])
        & (local[:, 1] <= ext[3])
    )
    return np.where(inside, t, np.inf), local


def _hit_box(u: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = lo / u, hi / u
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((tmax >= tmin) & (tmin > 0), tmin, np.inf)


def synth_scan(
    board: Board, model: LidarModel, sc: SynthScene, rng: np.random.Generator
) -> tuple[Scan, np.ndarray]:
    """Ray-cast one scan. Returns (Scan with ring, (4,4) true T_lidar_board)."""
    T = board_pose(board, sc)
    el = model.vertical_angles_rad
    step = np.deg2rad(model.horizontal_resolution_deg)
    if sc.azimuth_window_deg is None:
        az = np.arange(-np.pi, np.pi, step)
    else:
        half = np.deg2rad(sc.azimuth_window_deg)
        az = np.deg2rad(sc.azimuth_deg) + np.arange(-half, half, step)
    az = az + rng.uniform(0, step)  # random firing phase
    E, A = np.meshgrid(el, az, indexing="ij")
    ring = np.broadcast_to(np.arange(el.size)[:, None], E.shape).reshape(-1).astype(np.int32)
    u = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1).reshape(-1, 3)

    t_board, level_board = _board_returns(u, T, board, model, sc)
    hits, levels = _clutter(u, T, board, sc)
    hits.insert(0, t_board)
    levels.insert(0, level_board)
    H = np.stack(hits, axis=1)
    k = np.argmin(H, axis=1)
    t = H[np.arange(u.shape[0]), k]
    level = np.stack(levels, axis=1)[np.arange(u.shape[0]), k]
    keep = np.isfinite(t) & (t < 80) & (rng.random(t.size) >= sc.dropout)
    t = t[keep] + rng.normal(0, sc.range_sigma, keep.sum())
    pts = t[:, None] * u[keep]
    on_board = (k == 0)[keep]
    jitter = rng.normal(0, sc.in_plane_sigma, (int(on_board.sum()), 2)) @ T[:3, :2].T
    pts[on_board] += jitter
    inten = np.clip(level[keep] + rng.normal(0, sc.intensity_sigma, keep.sum()), 0, 255)
    perm = rng.permutation(pts.shape[0])  # points need not be in scan order
    return Scan(pts[perm], inten[perm], ring[keep][perm], source="synthetic"), T


def _board_returns(
    u: np.ndarray, T: np.ndarray, board: Board, model: LidarModel, sc: SynthScene
) -> tuple[np.ndarray, np.ndarray]:
    """Per ray ``u`` (N, 3) its range to the board (inf: a miss) and the intensity there: the colour
    averaged over the beam's footprint (``lidars.footprint.FOOTPRINT``'s even cover of its disc), in
    the board plane."""
    t_board, local = _hit_rect(u, T, board.extent())
    hit = np.flatnonzero(np.isfinite(t_board))
    rad = 0.5 * (sc.footprint + model.beam_divergence_rad * t_board[hit])
    pts = local[hit, None, :2] + rad[:, None, None] * FOOTPRINT[None, :, :]
    c = board.colour_at(pts.reshape(-1, 2)).reshape(len(hit), -1)
    ok = np.isfinite(c)
    colour = np.zeros(len(t_board))
    colour[hit] = np.where(ok, c, 0.0).sum(axis=1) / np.maximum(ok.sum(axis=1), 1)
    return t_board, sc.black + colour * (sc.white - sc.black)


def _clutter(
    u: np.ndarray, T: np.ndarray, board: Board, sc: SynthScene
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per ray ``u`` (N, 3) the ranges (inf: a miss) and intensities of what else the scene holds, in
    this order when present: the wall behind the board, the ground, a person holding the board's
    edge (body and arm), the board's stand, a decoy board."""
    hits: list[np.ndarray] = []
    levels: list[np.ndarray] = []
    R, centre = T[:3, :3], T[:3, :3] @ board.pattern_centre + T[:3, 3]
    if sc.wall_gap is not None:
        Tw = np.eye(4)
        Tw[:3, :3] = R
        Tw[:3, 3] = centre - sc.wall_gap * R[:, 2]
        t_wall, _ = _hit_rect(u, Tw, (-8.0, 8.0, -8.0, 8.0))
        hits.append(t_wall)
        levels.append(np.full(u.shape[0], 30.0))
    if sc.ground_z is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            t_g = sc.ground_z / u[:, 2]
        hits.append(np.where((t_g > 0) & (t_g < 60), t_g, np.inf))
        levels.append(np.full(u.shape[0], 15.0))
    x0, x1, y0, y1 = board.extent()
    if sc.person:
        # box just beyond the board's +x edge, same depth, from the ground up
        edge = T[:3, :3] @ np.array([x1 + 0.2, 0.5 * (y0 + y1), 0.0]) + T[:3, 3]
        gz = sc.ground_z if sc.ground_z is not None else edge[2] - 1.0
        lo = np.array([edge[0] - 0.15, edge[1] - 0.2, gz])
        hi = np.array([edge[0] + 0.15, edge[1] + 0.2, gz + 1.7])
        hits.append(_hit_box(u, lo, hi))
        levels.append(np.full(u.shape[0], 20.0))
        # an arm: a thin box from the body to the board's edge, touching it
        arm_end = T[:3, :3] @ np.array([x1 - 0.02, 0.5 * (y0 + y1), 0.03]) + T[:3, 3]
        a_lo, a_hi = np.minimum(edge, arm_end) - 0.04, np.maximum(edge, arm_end) + 0.04
        hits.append(_hit_box(u, a_lo, a_hi))
        levels.append(np.full(u.shape[0], 20.0))
    if sc.stand:
        foot = T[:3, :3] @ np.array([0.5 * (x0 + x1), y0, -0.03]) + T[:3, 3]
        gz = sc.ground_z if sc.ground_z is not None else foot[2] - 1.0
        lo = np.array([foot[0] - 0.02, foot[1] - 0.02, gz])
        hi = np.array([foot[0] + 0.02, foot[1] + 0.02, foot[2]])
        hits.append(_hit_box(u, lo, hi))
        levels.append(np.full(u.shape[0], 25.0))
    if sc.decoy_azimuth_deg is not None:
        d_decoy = sc.distance if sc.decoy_distance is None else sc.decoy_distance
        Td = board_pose(board, SynthScene(distance=d_decoy, azimuth_deg=sc.decoy_azimuth_deg))
        t_d, loc_d = _hit_rect(u, Td, board.extent())
        hits.append(t_d)
        levels.append(np.where(loc_d[:, 0] < 0.5 * (x0 + x1), sc.black, sc.white))
    return hits, levels
