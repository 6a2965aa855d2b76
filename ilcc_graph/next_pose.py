"""Where to hold the board next: the pose that shrinks the worst-determined part of the extrinsic most.

The extrinsic's information now is the inverse of its marginal covariance (batch or iSAM2). A new
board at pose ``T_lidar_board`` adds, through the graph's own two factors on (``X(0)``, ``B(new)``),

    dI = A_x^T A_x - A_x^T A_b (A_b^T A_b + Sigma_B^-1)^-1 A_b^T A_x,

where ``A_x, A_b`` are the whitened Jacobians of that board's grouped bearing factor
(``graphs.frame_bearing_factor``: the corners projected with the current extrinsic, each with the
median pixel covariance of the image corners seen so far) and ``Sigma_B`` the LiDAR board prior's
covariance predicted for that pose (:class:`BoardNoiseModel`): the LiDAR's beam table is cast on
the board to get its returns; the plane block (rx, ry, tz) is ``a (A^T A)^-1 + b`` x the same
sandwich with one range bias per beam (what the stage's ring jackknife sees); the in-plane block
(rz, tx, ty) ``c`` x the inverse information of the stage's soft-edged intensity model at those
returns plus ``d`` x the stage's own edge-sampling covariance (``lidar.covariance``), with the
stage's ray coupling between them. ``a..d`` are fitted (non-negative least squares) to the
covariances the LiDAR stage gave for the boards so far.

Candidates: board centres around the rig (every 30 deg of azimuth for a panorama, across the
image otherwise) at 1.2-3.4 m and three heights inside the LiDAR's vertical field, the board
facing the rig, turned about the vertical and tilted up or down by up to 40 deg, held as a diamond
(45 deg in its plane, as the paper's layout). A candidate counts only when every board corner
lies in the image (3 % border) and in front of the camera, the whole board inside the LiDAR's
vertical field, at least 4 beams cross it, and it is not where a board was already (its centre
15 cm and its face 10 deg from every earlier one's). The score is the largest sigma after the frame,
each divided by the target (``target_sigma``; default 0.1 deg / 1 mm for the scale only): the
proposal is the candidate with the smallest, then refined around it.

The LiDAR's own error terms (``--lidar-errors``) are not part of the prediction.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.config import Config
from ilcc_graph.estimation.graphs import frame_bearing_factor
from ilcc_graph.lidar.covariance import assemble_covariance, ray_coupling, sampling_covariance, soft_intensity
from ilcc_graph.lidars import LidarModel
from ilcc_graph.types import Calibration, GraphFrame, sigmas_deg_mm

__all__ = [
    "Advisor",
    "BoardNoiseModel",
    "Proposal",
    "Rig",
    "beam_hits",
    "board_pose",
    "fit_noise_model",
    "frame_information",
    "from_calibration",
    "propose",
]

DEFAULT_SCALE = (0.1, 1.0)  # deg, mm: the normalisation of the score when no target is given
MIN_BEAMS = 4
IMAGE_BORDER = 0.03
ROLL_DEG = 45.0
#: a proposal is a new pose: its centre this far from every board so far, or its face turned this much
NEW_POSE_M, NEW_POSE_COS = 0.15, math.cos(math.radians(10.0))


@dataclass(frozen=True)
class Rig:
    """The sensors as the advice sees them: camera model, current ``T_cam_lidar`` (4, 4), the LiDAR's
    beam table and the board."""

    camera: CameraModel
    T_cam_lidar: np.ndarray
    lidar: LidarModel
    board: Board

    @property
    def camera_centre(self) -> np.ndarray:
        """(3,) the camera centre in the LiDAR frame."""
        T = np.asarray(self.T_cam_lidar, dtype=np.float64)
        return -T[:3, :3].T @ T[:3, 3]


# ------------------------------------------------------------------------------ geometry
def _rot(axis: int, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def board_pose(
    centre: np.ndarray,
    board: Board,
    towards: np.ndarray,
    yaw_deg: float,
    pitch_deg: float,
    roll_deg: float = ROLL_DEG,
) -> np.ndarray:
    """(4, 4) ``T_lidar_board`` with the pattern centre at ``centre`` (LiDAR frame), the printed face
    towards ``towards``, then turned by ``yaw_deg`` about the vertical (positive: the face turns
    counter-clockwise seen from above), tilted by ``pitch_deg`` (positive: the face looks up) and
    turned ``roll_deg`` in its plane."""
    z0 = np.asarray(towards, dtype=np.float64) - centre
    z0 /= np.linalg.norm(z0)
    x0 = np.cross([0.0, 0.0, 1.0], z0)
    x0 /= np.linalg.norm(x0)
    y0 = np.cross(z0, x0)
    R = np.column_stack([x0, y0, z0]) @ _rot(1, math.radians(yaw_deg)) @ _rot(0, -math.radians(pitch_deg))
    R = R @ _rot(2, math.radians(roll_deg))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre - R @ board.pattern_centre
    return T


@functools.lru_cache(maxsize=8)
def _outline_cached(board: Board, n: int) -> np.ndarray:
    x0, x1, y0, y1 = board.extent()
    t = np.linspace(0.0, 1.0, n)
    xs = np.concatenate([x0 + (x1 - x0) * t, np.full(n, x1), x1 - (x1 - x0) * t, np.full(n, x0)])
    ys = np.concatenate([np.full(n, y0), y0 + (y1 - y0) * t, np.full(n, y1), y1 - (y1 - y0) * t])
    out = np.column_stack([xs, ys, np.zeros_like(xs)])
    out.setflags(write=False)
    return out


def _outline(board: Board, n: int = 6) -> np.ndarray:
    """(4 n, 3) points along the board's physical edge, board frame."""
    return _outline_cached(board, n)


def beam_hits(T_lidar_board: np.ndarray, board: Board, lidar: LidarModel) -> tuple[np.ndarray, ...]:
    """The returns the LiDAR's beam table puts on the board: (b (M, 3) board frame, ring (M,),
    u (M, 3) unit ray directions in the board frame). Beams from the LiDAR origin at every
    ``horizontal_resolution_deg`` over the board's azimuth span; the board's physical face counts."""
    T = np.asarray(T_lidar_board, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    out = _outline(board) @ R.T + t
    az = np.arctan2(out[:, 1], out[:, 0])
    ref = float(np.arctan2(t[1] + R[1] @ board.pattern_centre, t[0] + R[0] @ board.pattern_centre))
    daz = np.mod(az - ref + np.pi, 2 * np.pi) - np.pi
    step = math.radians(lidar.horizontal_resolution_deg)
    a = ref + np.arange(math.floor(daz.min() / step), math.ceil(daz.max() / step) + 1) * step
    origin = np.array([0.0, 0.0, lidar.beam_origin_z_m])
    el_out = np.arctan2(out[:, 2] - origin[2], np.hypot(out[:, 0], out[:, 1]))
    el_all = np.radians(lidar.vertical_angles_deg)
    rings = np.flatnonzero((el_all >= el_out.min() - 1e-3) & (el_all <= el_out.max() + 1e-3))
    E, A = np.meshgrid(el_all[rings], a, indexing="ij")
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1).reshape(-1, 3)
    ring = np.repeat(rings, len(a))
    n = R[:, 2]
    denom = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((t - origin) @ n) / denom
    ok = np.isfinite(s) & (s > 0)
    p = origin + s[ok, None] * d[ok]
    b = (p - t) @ R
    x0, x1, y0, y1 = board.extent()
    on = (b[:, 0] >= x0) & (b[:, 0] <= x1) & (b[:, 1] >= y0) & (b[:, 1] <= y1)
    return b[on], ring[ok][on], d[ok][on] @ R


# ---------------------------------------------------------------- the LiDAR board's noise
def _plane_parts(b: np.ndarray, ring: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3, 3) iid and per-beam-bias parts of the plane fit's (rx, ry, tz) covariance, unit variances."""
    A = np.column_stack([b[:, 1], -b[:, 0], np.ones(len(b))])
    Ninv = np.linalg.inv(A.T @ A)
    groups = np.unique(ring, return_inverse=True)[1]
    S = np.zeros((int(groups.max()) + 1, 3))
    np.add.at(S, groups, A)
    return Ninv, Ninv @ S.T @ S @ Ninv


def _footprint_sigma(lidar: LidarModel, rng: float) -> float:
    return 0.5 * (0.01 + lidar.beam_divergence_rad * rng) / 2.0


def _soft_part(b: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(3, 3) inverse information of the soft-edged intensity model (unit contrast and noise) of
    (rz, tx, ty), from its gradients ``g`` (M, 2) at the returns ``b``."""
    J = np.column_stack([g[:, 0] * b[:, 1] - g[:, 1] * b[:, 0], -g[:, 0], -g[:, 1]])
    return np.linalg.inv(J.T @ J + 1e-12 * np.eye(3))


def _sampling_part(b: np.ndarray, ring: np.ndarray, board: Board, blur: float) -> np.ndarray:
    """(3, 3) the stage's edge-sampling covariance of (rz, tx, ty) for returns ``b``."""
    colour = board.colour_at(b[:, :2])
    cls = np.where(np.isfinite(colour), np.round(np.nan_to_num(colour)), -1).astype(int)
    samp = sampling_covariance(b[:, :2], cls, ring, board, blur)
    return samp if np.all(np.isfinite(samp)) else np.zeros((3, 3))


@dataclass(frozen=True)
class _Parts:
    plane: tuple[np.ndarray, np.ndarray]
    inplane: tuple[np.ndarray, np.ndarray | None]  # the sampling part only when asked for
    K: np.ndarray


def _parts(
    T_lidar_board: np.ndarray, board: Board, lidar: LidarModel, sampling: bool = True
) -> _Parts | None:
    b, ring, u = beam_hits(T_lidar_board, board, lidar)
    if len(b) < 12 or len(np.unique(ring)) < MIN_BEAMS:
        return None
    blur = _footprint_sigma(lidar, float(np.linalg.norm(np.asarray(T_lidar_board)[:3, 3])))
    _, g = soft_intensity(b[:, :2], board, 0.0, 1.0, blur)
    samp = _sampling_part(b, ring, board, blur) if sampling else None
    K = ray_coupling(b[:, :2], u, np.sum(g * g, axis=1))
    return _Parts(_plane_parts(b, ring), (_soft_part(b, g), samp), K)


@dataclass(frozen=True)
class BoardNoiseModel:
    """The LiDAR board prior's covariance for a board pose (module docstring): ``plane`` (a, b) and
    ``inplane`` (c, d) scales; ``frames``: how many observed boards they were fitted on."""

    plane: tuple[float, float]
    inplane: tuple[float, float]
    frames: int = 0

    @classmethod
    def default(cls, lidar: LidarModel) -> BoardNoiseModel:
        """Without observed boards: the LiDAR's range noise along the normal, a 3 mm bias per beam,
        the soft model at a contrast-to-noise of 10 and the sampling as it is."""
        return cls((lidar.range_sigma_m**2, 0.003**2), (0.1**2, 1.0))

    def covariance(self, T_lidar_board: np.ndarray, board: Board, lidar: LidarModel) -> np.ndarray | None:
        """(6, 6) predicted Pose3 covariance of the board's LiDAR pose, or None when fewer than
        ``MIN_BEAMS`` beams cross it."""
        p = _parts(T_lidar_board, board, lidar, sampling=self.inplane[1] > 0)
        return None if p is None else self._assemble(p)

    def _assemble(self, p: _Parts) -> np.ndarray:
        out = self.plane[0] * p.plane[0] + self.plane[1] * p.plane[1]
        inn = self.inplane[0] * p.inplane[0]
        if p.inplane[1] is not None:
            inn = inn + self.inplane[1] * p.inplane[1]
        return assemble_covariance(out, inn, p.K)


_IO, _II = [0, 1, 5], [2, 3, 4]


def fit_noise_model(frames: Sequence[GraphFrame], board: Board, lidar: LidarModel) -> BoardNoiseModel:
    """The scales of :class:`BoardNoiseModel` fitted to the LiDAR stage's covariances of ``frames``
    (non-negative least squares on the diagonals, each relative to its observed value); the
    default for what fewer than two usable frames cannot tell."""
    rows_o, rows_i = [], []
    for f in frames:
        p = _parts(f.T_lidar_board, board, lidar)
        C = np.asarray(f.board_cov, dtype=np.float64)
        if p is None or not np.all(np.isfinite(C)):
            continue
        Co = C[np.ix_(_IO, _IO)]
        Ci = C[np.ix_(_II, _II)] - p.K @ Co @ p.K.T  # what the coupling does not explain
        for k in range(3):
            if Co[k, k] > 0:
                rows_o.append([p.plane[0][k, k] / Co[k, k], p.plane[1][k, k] / Co[k, k]])
            if Ci[k, k] > 0:
                rows_i.append([p.inplane[0][k, k] / Ci[k, k], p.inplane[1][k, k] / Ci[k, k]])
    d = BoardNoiseModel.default(lidar)

    def fit(rows: list, fallback: tuple[float, float]) -> tuple[float, float]:
        if len(rows) < 6:
            return fallback
        x, _ = nnls(np.asarray(rows), np.ones(len(rows)))
        return (float(x[0]), float(x[1])) if np.any(x > 0) else fallback

    return BoardNoiseModel(fit(rows_o, d.plane), fit(rows_i, d.inplane), len(rows_o) // 3)


# ------------------------------------------------------------------------- information
def _median_cov_px(frames: Sequence[GraphFrame]) -> np.ndarray:
    covs = [np.asarray(f.cov_px, dtype=np.float64).reshape(-1, 2, 2) for f in frames]
    c = np.concatenate(covs) if covs else np.zeros((0, 2, 2))
    c = c[np.all(np.isfinite(c), axis=(1, 2))]
    return np.median(c, axis=0) if len(c) else np.diag([0.25, 0.25])


def _in_view(rig: Rig, T_lidar_board: np.ndarray) -> np.ndarray | None:
    """The corners' camera-frame points when every corner and the board's outline are imaged
    inside the picture (3 % border) and the outline lies in the LiDAR's vertical field; else None."""
    T = np.asarray(T_lidar_board, dtype=np.float64)
    out = _outline(rig.board) @ T[:3, :3].T + T[:3, 3]
    el = np.degrees(np.arctan2(out[:, 2] - rig.lidar.beam_origin_z_m, np.hypot(out[:, 0], out[:, 1])))
    va = rig.lidar.vertical_angles_deg
    if el.min() < va[0] + 0.3 or el.max() > va[-1] - 0.3:
        return None
    Tc = np.asarray(rig.T_cam_lidar, dtype=np.float64) @ T
    pts = np.vstack([rig.board.corners_board(), _outline(rig.board)]) @ Tc[:3, :3].T + Tc[:3, 3]
    uv = rig.camera.project(pts)
    if not np.all(np.isfinite(uv)) or not np.all(rig.camera.fov_contains(pts)):
        return None
    cam = rig.camera
    if not cam.periodic_u:
        bw = IMAGE_BORDER * cam.width
        if uv[:, 0].min() < bw or uv[:, 0].max() > cam.width - 1 - bw:
            return None
    bh = IMAGE_BORDER * cam.height
    if uv[:, 1].min() < bh or uv[:, 1].max() > cam.height - 1 - bh:
        return None
    return pts[: rig.board.n_corners]


def frame_information(
    rig: Rig,
    T_lidar_board: np.ndarray,
    board_cov: np.ndarray,
    cov_px: np.ndarray,
    p_cam: np.ndarray | None = None,
) -> np.ndarray | None:
    """(6, 6) information a board at ``T_lidar_board`` adds to ``T_cam_lidar`` (module docstring),
    with the board's LiDAR covariance ``board_cov`` (6, 6) and pixel covariance ``cov_px`` (2, 2)
    per corner; None when the board is out of view. ``p_cam``: its corners in the camera frame
    when already known (``_in_view``)."""
    import gtsam

    p_cam = _in_view(rig, T_lidar_board) if p_cam is None else p_cam
    if p_cam is None:
        return None
    K = len(p_cam)
    b = p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
    fac, _ = frame_bearing_factor(
        0, 1, rig.board.corners_board(), b, np.broadcast_to(cov_px, (K, 2, 2)), rig.camera
    )
    if fac is None:
        return None
    T_cl = gtsam.Pose3(np.asarray(rig.T_cam_lidar, dtype=np.float64))
    T_lb = gtsam.Pose3(np.asarray(T_lidar_board, dtype=np.float64))
    _, Ax, Ab = fac.evaluate(T_cl, T_lb, True)
    Hbb = Ab.T @ Ab + np.linalg.inv(board_cov)
    dI = Ax.T @ Ax - Ax.T @ Ab @ np.linalg.solve(Hbb, Ab.T @ Ax)
    return 0.5 * (dI + dI.T)


# ---------------------------------------------------------------------------- proposal
@dataclass(frozen=True)
class Proposal:
    """Where to hold the board next and what it should give.

    T_lidar_board: (4, 4) the proposed pose. azimuth_deg: direction of its centre from the LiDAR
    (atan2(y, x), positive to the left). distance_m: range of its centre. height_m: its centre above
    the LiDAR's origin. yaw_deg / pitch_deg: turned about the vertical / tilted from facing the rig
    (``board_pose``). sigmas_now / sigmas_after: (6,) deg, deg, deg, mm, mm, mm. worst: the axis
    with the largest sigma relative to the target now. candidates: how many poses were valid.
    """

    T_lidar_board: np.ndarray
    azimuth_deg: float
    distance_m: float
    height_m: float
    yaw_deg: float
    pitch_deg: float
    sigmas_now: np.ndarray
    sigmas_after: np.ndarray
    worst: str
    candidates: int
    rig: Rig | None = None
    boards: tuple[np.ndarray, ...] = ()  # (4, 4) T_lidar_board of the boards so far

    def describe(self) -> str:
        """One line for a person."""
        left = "left" if self.azimuth_deg > 0 else "right"
        way = f"{abs(self.azimuth_deg):.0f} deg {left} of the LiDAR's x axis"
        if abs(self.azimuth_deg) < 2.5:
            way = "straight ahead of the LiDAR (its x axis)"
        elif abs(self.azimuth_deg) > 177.5:
            way = "straight behind the LiDAR"
        turn = []
        if abs(self.yaw_deg) >= 1:
            side = "right" if self.yaw_deg > 0 else "left"
            turn.append(f"face turned {abs(self.yaw_deg):.0f} deg to the rig's {side}")
        if abs(self.pitch_deg) >= 1:
            turn.append(f"tilted {abs(self.pitch_deg):.0f} deg {'up' if self.pitch_deg > 0 else 'down'}")
        h = f"{abs(self.height_m):.2f} m {'above' if self.height_m >= 0 else 'below'} the LiDAR"
        now, after = self.sigmas_now, self.sigmas_after
        return (
            f"next board pose: {way}, {self.distance_m:.1f} m away, centre {h}, "
            f"{', '.join(turn) or 'facing the rig'}; worst now {self.worst}; expected sigma "
            f"{np.max(now[:3]):.4f} -> {np.max(after[:3]):.4f} deg, {np.max(now[3:]):.3f} -> "
            f"{np.max(after[3:]):.3f} mm"
        )


_AXES = ("rx", "ry", "rz", "tx", "ty", "tz")


def _score(cov: np.ndarray, scale: np.ndarray) -> float:
    return float(np.max(np.sqrt(np.clip(np.diag(cov), 0.0, None)) / scale))


def _scale(target: tuple[float, float] | None) -> np.ndarray:
    deg, mm = target if target is not None else DEFAULT_SCALE
    return np.array([math.radians(deg)] * 3 + [1e-3 * mm] * 3)


def _azimuths(rig: Rig, step_deg: float) -> np.ndarray:
    if rig.camera.periodic_u:
        return np.arange(-180.0, 180.0, step_deg)
    cam = rig.camera
    uv = np.column_stack([np.linspace(0, cam.width - 1, 41), np.full(41, (cam.height - 1) / 2)])
    b = cam.bearing(uv)
    d = b[np.all(np.isfinite(b), axis=1)] @ np.asarray(rig.T_cam_lidar)[:3, :3]
    az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    lo, hi = float(az.min()), float(az.max())
    n = max(3, int(round((hi - lo) / (step_deg / 2))))
    return np.linspace(lo, hi, n + 2)[1:-1]


def _centres(rig: Rig, azimuths: np.ndarray, distances: Sequence[float], levels: int = 3) -> list[np.ndarray]:
    x0, x1, y0, y1 = rig.board.extent()
    radius = 0.5 * math.hypot(x1 - x0, y1 - y0)
    va = np.radians(rig.lidar.vertical_angles_deg)
    out = []
    for d in distances:
        a = math.asin(min(1.0, radius / d)) + math.radians(1.0)
        lo, hi = va[0] + a, va[-1] - a
        els = [0.5 * (lo + hi)] if hi <= lo else list(np.linspace(lo, hi, levels + 2)[1:-1])
        for az in np.radians(azimuths):
            for el in els:
                out.append(
                    d * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
                )
    return out


class Advisor:
    """Proposes the next board pose for one rig (module docstring).

    The information a candidate pose would add depends on the rig, the noise model and the pixel
    noise, not on the frames' current information: it is computed once per candidate and kept, so
    that asking again after each new frame costs only the 6 x 6 updates.

    frames: the boards so far (their pixel covariances; the LiDAR noise model unless ``noise``).
    information_scale: divides each new frame's information (e.g. the run's variance factor).
    """

    def __init__(
        self,
        rig: Rig,
        frames: Sequence[GraphFrame],
        noise: BoardNoiseModel | None = None,
        information_scale: float = 1.0,
        distances: Sequence[float] = (1.3, 2.0, 3.0),
    ) -> None:
        self.rig = rig
        self.frames = list(frames)
        self.noise = noise or fit_noise_model(frames, rig.board, rig.lidar)
        self.cov_px = _median_cov_px(frames)
        self.information_scale = float(information_scale)
        self.distances = tuple(distances)
        self._towards = 0.5 * rig.camera_centre
        self._cache: dict[tuple, tuple[np.ndarray, np.ndarray] | None] = {}
        self._coarse = [
            (c, yaw, pitch)
            for c in _centres(rig, _azimuths(rig, 30.0), self.distances, levels=2)
            for yaw, pitch in ((0.0, 0.0), (30.0, 0.0), (-30.0, 0.0), (0.0, 25.0), (0.0, -25.0))
        ]

    def candidate(self, centre: np.ndarray, yaw: float, pitch: float) -> tuple[np.ndarray, np.ndarray] | None:
        """(T_lidar_board, information it adds) of a board centred at ``centre`` (LiDAR frame), turned
        ``yaw`` and tilted ``pitch`` degrees from facing the rig; None when it is not valid."""
        key = (*np.round(centre, 3), round(yaw, 1), round(pitch, 1))
        if key not in self._cache:
            T = board_pose(centre, self.rig.board, self._towards, yaw, pitch)
            val = None
            p_cam = _in_view(self.rig, T)
            if p_cam is not None:
                cov_b = self.noise.covariance(T, self.rig.board, self.rig.lidar)
                dI = None if cov_b is None else frame_information(self.rig, T, cov_b, self.cov_px, p_cam)
                val = None if dI is None else (T, dI / self.information_scale)
            self._cache[key] = val
        return self._cache[key]

    def propose(
        self, covariance: np.ndarray, target_sigma: tuple[float, float] | None = None,
        frames: Sequence[GraphFrame] | None = None,
    ) -> Proposal | None:  # fmt: skip
        """The candidate whose frame leaves the smallest largest sigma (each over the target), from
        the extrinsic's ``covariance`` (6, 6) now; a coarse grid, then around its best. ``frames``:
        the boards so far when there are more than the advisor was made with (no repeat of one is
        proposed). None when no candidate is valid or the covariance is not finite."""
        if frames is not None:
            self.frames = list(frames)
        C = np.asarray(covariance, dtype=np.float64)
        if C.shape != (6, 6) or not np.all(np.isfinite(C)):
            return None
        info = np.linalg.inv(C)
        scale = _scale(target_sigma)
        scored: list[tuple[float, tuple, np.ndarray, np.ndarray]] = []

        poses = [np.asarray(f.T_lidar_board, dtype=np.float64) for f in self.frames]
        seen = [(T[:3, :3] @ self.rig.board.pattern_centre + T[:3, 3], T[:3, 2]) for T in poses]

        def repeats(T: np.ndarray) -> bool:
            c = T[:3, :3] @ self.rig.board.pattern_centre + T[:3, 3]
            return any(
                np.linalg.norm(c - c0) < NEW_POSE_M and T[:3, 2] @ n0 > NEW_POSE_COS for c0, n0 in seen
            )

        def try_(centre: np.ndarray, yaw: float, pitch: float) -> None:
            got = self.candidate(centre, yaw, pitch)
            if got is not None and not repeats(got[0]):
                after = np.linalg.inv(info + got[1])
                scored.append((_score(after, scale), (yaw, pitch), got[0], after))

        for c, yaw, pitch in self._coarse:
            try_(c, yaw, pitch)
        if not scored:
            return None
        _, (yaw0, pitch0), T0, _ = min(scored, key=lambda v: v[0])
        c0 = T0[:3, :3] @ self.rig.board.pattern_centre + T0[:3, 3]
        az0, d0 = math.atan2(c0[1], c0[0]), float(np.linalg.norm(c0))
        el0 = math.asin(c0[2] / d0)
        for daz in (-12.0, 0.0, 12.0):
            for dd in (-0.4, 0.0, 0.4):
                d, az = d0 + dd, az0 + math.radians(daz)
                if d < 1.0:
                    continue
                c = d * np.array([math.cos(el0) * math.cos(az), math.cos(el0) * math.sin(az), math.sin(el0)])
                for yaw in (yaw0 - 15.0, yaw0, yaw0 + 15.0):
                    for pitch in (pitch0 - 15.0, pitch0, pitch0 + 15.0):
                        if abs(yaw) <= 50.0 and abs(pitch) <= 40.0:
                            try_(c, yaw, pitch)
        _, (yaw, pitch), T, after = min(scored, key=lambda v: v[0])
        centre = T[:3, :3] @ self.rig.board.pattern_centre + T[:3, 3]
        now = np.sqrt(np.clip(np.diag(C), 0.0, None)) / scale
        return Proposal(
            T_lidar_board=T,
            azimuth_deg=math.degrees(math.atan2(centre[1], centre[0])),
            distance_m=float(np.linalg.norm(centre)),
            height_m=float(centre[2]),
            yaw_deg=float(yaw),
            pitch_deg=float(pitch),
            sigmas_now=sigmas_deg_mm(C),
            sigmas_after=sigmas_deg_mm(after),
            worst=_AXES[int(np.argmax(now))],
            candidates=len(scored),
            rig=self.rig,
            boards=tuple(np.asarray(f.T_lidar_board, dtype=np.float64) for f in self.frames),
        )


def propose(
    covariance: np.ndarray,
    rig: Rig,
    frames: Sequence[GraphFrame],
    target_sigma: tuple[float, float] | None = None,
    noise: BoardNoiseModel | None = None,
    information_scale: float = 1.0,
) -> Proposal | None:
    """``Advisor(rig, frames, noise, information_scale).propose(covariance, target_sigma)``."""
    return Advisor(rig, frames, noise, information_scale).propose(covariance, target_sigma)


def from_calibration(
    calibration: Calibration, config: Config, target_sigma: tuple[float, float] | None = None
) -> Proposal | None:
    """The next board pose after a calibration (its used frames, its covariance divided into the
    new frame's information by its variance factor); None without a covariance, a LiDAR beam
    table or a valid candidate."""
    if config.lidar is None:
        return None
    frames = [
        GraphFrame(
            f.name,
            f.board.T_lidar_board,
            f.board.covariance,
            config.board.corners_board(),
            f.corners.bearings,
            f.corners.cov_px,
        )
        for f in calibration.frames
        if f.used and f.board is not None and f.corners is not None
    ]
    if not frames:
        return None
    rig = Rig(config.camera, calibration.T_cam_lidar, config.lidar, config.board)
    vf = float(calibration.diagnostics.get("variance_factor", 1.0))
    return Advisor(rig, frames, information_scale=max(vf, 1.0)).propose(calibration.covariance, target_sigma)
