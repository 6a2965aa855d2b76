"""The advice itself: what a board adds to the extrinsic's information, the candidates, the proposal."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ilcc_graph.config import Config
from ilcc_graph.estimation.graphs import board_face_samples, frame_bearing_factor, samples_from_corners
from ilcc_graph.estimation.next_board import SolvedGlobals, board_information, extrinsic_gain
from ilcc_graph.next_pose.lidar_noise import BoardNoiseModel, fit_noise_model
from ilcc_graph.next_pose.pose_geometry import Rig, board_outline, board_pose, in_view
from ilcc_graph.types import Calibration, GraphFrame, sigmas_deg_mm

if TYPE_CHECKING:  # the run hands its result down; next_pose does not import the run
    from ilcc_graph.run.result import Result

__all__ = [
    "Advisor",
    "for_run",
    "Proposal",
    "TURNED_CENTRES",
    "TURNS",
    "candidate_azimuths",
    "frame_information",
    "from_calibration",
    "held_out_factor",
    "median_pixel_cov",
    "noise_scaled",
    "propose",
]

DEFAULT_SCALE = (0.1, 1.0)  # deg, mm: the normalisation of the score when no target is given
#: a proposal is a new pose: its centre this far from every board so far, or its face turned this much
NEW_POSE_M, NEW_POSE_COS = 0.15, math.cos(math.radians(10.0))
#: the coarse search: every centre facing the rig, then these turns (yaw, pitch; deg) at the best few
TURNS, TURNED_CENTRES = ((30.0, 0.0), (-30.0, 0.0), (0.0, 25.0), (0.0, -25.0)), 8


def median_pixel_cov(frames: Sequence[GraphFrame]) -> np.ndarray:
    covs = [np.asarray(f.cov_px, dtype=np.float64).reshape(-1, 2, 2) for f in frames]
    c = np.concatenate(covs) if covs else np.zeros((0, 2, 2))
    c = c[np.all(np.isfinite(c), axis=(1, 2))]
    return np.median(c, axis=0) if len(c) else np.diag([0.25, 0.25])


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

    p_cam = in_view(rig, T_lidar_board) if p_cam is None else p_cam
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


def candidate_azimuths(rig: Rig, step_deg: float) -> np.ndarray:
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
    solved: the solved problem's globals (``estimation.next_board``): a candidate's information then
    goes through the chosen sensor model's shared terms (the range offset) into the extrinsic's
    marginal; None: the extrinsic's own information, as if the boards shared no sensor term.
    """

    def __init__(
        self,
        rig: Rig,
        frames: Sequence[GraphFrame],
        noise: BoardNoiseModel | None = None,
        information_scale: float = 1.0,
        distances: Sequence[float] = (1.3, 2.0, 3.0),
        solved: SolvedGlobals | None = None,
    ) -> None:
        self.rig = rig
        self.solved = solved
        self._dark = float(np.mean(rig.board.colour_at(board_face_samples(rig.board)) == 0.0))
        self._samples = samples_from_corners(rig.board.corners_board())
        self.frames = list(frames)
        self.noise = noise or fit_noise_model(frames, rig.board, rig.lidar)
        self.cov_px = median_pixel_cov(frames)
        self.information_scale = float(information_scale)
        self.distances = tuple(distances)
        self._towards = 0.5 * rig.camera_centre
        self._cache: dict[tuple, tuple[np.ndarray, np.ndarray] | None] = {}
        self._grid = _centres(rig, candidate_azimuths(rig, 30.0), self.distances, levels=2)

    def candidate(self, centre: np.ndarray, yaw: float, pitch: float) -> tuple[np.ndarray, np.ndarray] | None:
        """(T_lidar_board, information it adds) of a board centred at ``centre`` (LiDAR frame), turned
        ``yaw`` and tilted ``pitch`` degrees from facing the rig; None when it is not valid."""
        key = (*np.round(centre, 3), round(yaw, 1), round(pitch, 1))
        if key not in self._cache:
            T = board_pose(centre, self.rig.board, self._towards, yaw, pitch)
            val = None
            p_cam = in_view(self.rig, T)
            if p_cam is not None:
                cov_b = self.noise.covariance(T, self.rig.board, self.rig.lidar)
                dI = None if cov_b is None else self._information(T, cov_b, p_cam)
                val = None if dI is None else (T, dI)
            self._cache[key] = val
        return self._cache[key]

    def _information(self, T: np.ndarray, cov_b: np.ndarray, p_cam: np.ndarray) -> np.ndarray | None:
        """What a board at ``T`` (LiDAR covariance ``cov_b``, corners at ``p_cam`` in the camera
        frame) adds, divided by ``information_scale``: (6, 6) on the extrinsic, or with ``solved`` on
        its globals (``estimation.next_board.board_information``; ``gain`` maps it to the extrinsic)."""
        if self.solved is None:
            dI = frame_information(self.rig, T, cov_b, self.cov_px, p_cam)
            return None if dI is None else dI / self.information_scale
        b = p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
        cov_px = np.broadcast_to(self.cov_px, (len(p_cam), 2, 2))
        corners = self.rig.board.corners_board()
        a = self._coefficients(T) if self.solved.terms else None
        info = board_information(self.solved, T, cov_b, corners, b, cov_px, self.rig.camera, a, self._samples)
        return None if info is None else info / self.information_scale

    def _coefficients(self, T: np.ndarray) -> np.ndarray:
        """The range terms' mean coefficients over a board at ``T``'s returns: the beams its outline
        spans in elevation, the dark share of its face, its centre's range."""
        rig, solved = self.rig, self.solved
        assert solved is not None
        out = board_outline(rig.board) @ T[:3, :3].T + T[:3, 3]
        el = np.degrees(np.arctan2(out[:, 2] - rig.lidar.beam_origin_z_m, np.hypot(out[:, 0], out[:, 1])))
        va = np.asarray(rig.lidar.vertical_angles_deg)
        beams = [int(k) for k in np.flatnonzero((va >= el.min()) & (va <= el.max()))]
        centre = T[:3, :3] @ rig.board.pattern_centre + T[:3, 3]
        return solved.coefficients(self._dark, beams, float(np.linalg.norm(centre)))

    def gain(self, information: np.ndarray) -> np.ndarray:
        """(6, 6) the extrinsic's marginal information gain from a candidate's ``information``."""
        return information if self.solved is None else extrinsic_gain(self.solved, information)

    def propose(
        self, covariance: np.ndarray, target_sigma: tuple[float, float] | None = None,
        frames: Sequence[GraphFrame] | None = None,
    ) -> Proposal | None:  # fmt: skip
        """The candidate whose frame leaves the smallest largest sigma (each over the target), from
        the extrinsic's ``covariance`` (6, 6) now; a coarse grid (every centre facing the rig, then
        turned and tilted where that is among the best or gives no candidate), then around its
        best. ``frames``:
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

        def try_(centre: np.ndarray, yaw: float, pitch: float) -> float | None:
            got = self.candidate(centre, yaw, pitch)
            if got is None or repeats(got[0]):
                return None
            after = np.linalg.inv(info + self.gain(got[1]))
            scored.append((_score(after, scale), (yaw, pitch), got[0], after))
            return scored[-1][0]

        # every centre facing the rig; turned and tilted where facing is the best few, or no
        # candidate (out of view or a repeat: turned, a board may be neither)
        facing: list[tuple[float, np.ndarray]] = []
        turn: list[np.ndarray] = []
        for c in self._grid:
            got = try_(c, 0.0, 0.0)
            if got is None:
                turn.append(c)
            else:
                facing.append((got, c))
        turn += [c for _, c in sorted(facing, key=lambda v: v[0])[:TURNED_CENTRES]]
        for c in turn:
            for yaw, pitch in TURNS:
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


def noise_scaled(frames: Sequence[GraphFrame], k_board: float, k_view: float) -> list[GraphFrame]:
    """The frames with the noise a solve found: the boards' LiDAR covariances times its board
    component ``k_board``, the corners' pixel covariances times its bearing component ``k_view``."""
    kb, kv = max(float(k_board), 1e-12), max(float(k_view), 1e-12)
    return [
        replace(f, board_cov=kb * np.asarray(f.board_cov), cov_px=kv * np.asarray(f.cov_px)) for f in frames
    ]


def held_out_factor(calibration: Calibration) -> float:
    """The chosen sensor model's held-out factor (``estimation.selection``; 1 without a choice)."""
    model = (calibration.sensors or {}).get("model") or {}
    for c in model.get("candidates", []):
        if c.get("name") == model.get("chosen"):
            return float(c.get("factor", 1.0))
    return 1.0


def from_calibration(
    calibration: Calibration,
    config: Config,
    target_sigma: tuple[float, float] | None = None,
    solved: SolvedGlobals | None = None,
) -> Proposal | None:
    """The next board pose after a calibration (its used frames, its covariance); None without a
    covariance, a LiDAR beam table or a valid candidate.

    A new frame is predicted with the noise the run found, not the stages' stated noise: the boards'
    LiDAR covariances and the corners' pixel covariances scaled by the run's variance components
    (on the recorded Ouster set the board priors' is about 37: unscaled, one more board promised
    the translation's sigma 22 mm -> 0.8 mm), the new frame's information divided by the final
    variance factor or the chosen sensor model's held-out factor, whichever is larger (the covariance
    is the one the run reports: its sensor model's, averaged over the models when they were close).
    ``solved``: the solve's globals, so that the promise keeps the sensor model's shared terms."""
    if config.lidar is None:
        return None
    diag = calibration.diagnostics
    frames = [
        GraphFrame(
            f.name,
            f.board.T_lidar_board,
            f.board.covariance,
            config.board.corners_board(),
            f.corners.bearings,
            f.corners.cov_px,
        )  # fmt: skip
        for f in calibration.frames
        if f.used and f.board is not None and f.corners is not None
    ]
    if not frames:
        return None
    frames = noise_scaled(
        frames, diag.get("variance_component_board", 1.0), diag.get("variance_component_bearing", 1.0)
    )
    rig = Rig(config.camera, calibration.T_cam_lidar, config.lidar, config.board)
    scale = max(float(diag.get("variance_factor", 1.0)), held_out_factor(calibration), 1.0)
    return Advisor(rig, frames, information_scale=scale, solved=solved).propose(
        calibration.covariance, target_sigma
    )


def for_run(result: Result, target_sigma: tuple[float, float] | None = None) -> Proposal | None:
    """The next board pose after a run (``run.result.Result``) of one session with a covariance;
    None for several sessions, the paper's refinement (no covariance) or no valid candidate."""
    if len(result.sessions) != 1 or not np.all(np.isfinite(result.calibration.covariance)):
        return None
    config = result.sessions[0].observation.pair_config
    return from_calibration(result.calibration, config, target_sigma, result.solved)
