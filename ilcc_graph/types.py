"""Plain data passed between pipeline stages (frozen dataclasses of numpy arrays).

Frames and units follow ``shared/interface.md``: metres, radians unless a name says
otherwise, poses as 4x4 homogeneous matrices ``T_a_b`` with ``p_a = T_a_b @ p_b``.
Covariances of poses are 6x6 in GTSAM's Pose3 tangent convention
``T_true = T_est * Pose3.Expmap(xi)``, ``xi = (rx, ry, rz, tx, ty, tz)``.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Names of the six 1-sigma values of a Pose3-tangent covariance, in calibration.yaml's units.
SIGMA_NAMES = ("rx_deg", "ry_deg", "rz_deg", "tx_mm", "ty_mm", "tz_mm")


def sigmas_deg_mm(cov: np.ndarray) -> np.ndarray:
    """(6,) 1-sigma values (deg, deg, deg, mm, mm, mm) of a (6, 6) Pose3-tangent covariance.

    NaN everywhere when the covariance is absent or not finite (the paper's refinement gives none).
    """
    c = np.asarray(cov, dtype=np.float64)
    if c.shape != (6, 6) or not np.all(np.isfinite(c)):
        return np.full(6, np.nan)
    s = np.sqrt(np.clip(np.diag(c), 0.0, None))
    return np.concatenate([np.degrees(s[:3]), 1e3 * s[3:]])


def worst_sigmas(cov: np.ndarray) -> tuple[float, float]:
    """The largest 1-sigma in any direction of a (6, 6) Pose3-tangent covariance: rotation (deg),
    translation (mm) (the square roots of each block's largest eigenvalue); NaN without one."""
    c = np.asarray(cov, dtype=np.float64)
    if c.shape != (6, 6) or not np.all(np.isfinite(c)):
        return math.nan, math.nan
    rot = math.degrees(math.sqrt(max(np.linalg.eigvalsh(c[:3, :3])[-1], 0.0)))
    return rot, 1e3 * math.sqrt(max(np.linalg.eigvalsh(c[3:, 3:])[-1], 0.0))


def reaches(cov: np.ndarray, target: tuple[float, float] | None) -> bool:
    """Whether a (6, 6) covariance's 1-sigma is within ``target`` (deg, mm) in every direction, as
    the verdict judges it (``worst_sigmas``); False without a target or a covariance."""
    return target_gap(worst_sigmas(cov), target) == "reached"


def target_gap(worst: tuple[float, float], target: tuple[float, float] | None) -> str:
    """The largest 1-sigma in any direction (deg, mm; ``worst_sigmas``) over ``target``: ``reached``
    (the one rule: ``reaches`` asks this) or each ratio in at most 6 characters (``x1.4 x2.0``); "" without a
    target; ``not yet`` without a finite covariance. check's target column and the incremental
    mode's updates show it."""
    if target is None:
        return ""
    r, t = worst[0] / target[0], worst[1] / target[1]
    if not (math.isfinite(r) and math.isfinite(t)):
        return "not yet"  # no covariance yet
    if worst[0] <= target[0] and worst[1] <= target[1]:
        return "reached"
    return " ".join(f"x{x:.1f}" if x < 100 else f"x{x:.0f}" if x < 9999.5 else f"x{x:.0e}" for x in (r, t))


def sigma_dict(cov: np.ndarray) -> dict[str, float]:
    """``{rx_deg, ry_deg, rz_deg, tx_mm, ty_mm, tz_mm}`` of a (6, 6) Pose3-tangent covariance."""
    return {k: float(v) for k, v in zip(SIGMA_NAMES, sigmas_deg_mm(cov), strict=True)}


@dataclass(frozen=True)
class Estimate:
    """A pose with its covariance (the one shape of a pose-with-covariance in the toolkit).

    T: (4, 4) the pose (``T_cam_lidar`` unless a name says otherwise).
    covariance: (6, 6) right-tangent covariance ``T_true = T * Expmap(xi)``, rotation first, rad and m.
    """

    T: np.ndarray
    covariance: np.ndarray

    @property
    def sigmas(self) -> np.ndarray:
        """(6,) standard deviations (rad, rad, rad, m, m, m)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def sigma_dict(self) -> dict[str, float]:
        """Sigmas as calibration.yaml writes them: rx_deg .. tz_mm."""
        return sigma_dict(self.covariance)

    @property
    def pose(self) -> Any:
        """``T`` as a ``gtsam.Pose3``."""
        import gtsam

        return gtsam.Pose3(np.asarray(self.T, dtype=np.float64))


@dataclass(frozen=True)
class PoseTerms:
    """A pose estimated jointly with the LiDAR's own range terms (the chosen sensor model's solve).

    T: (4, 4) the pose (``T_cam_lidar`` unless a name says otherwise). terms: the k terms' names
    (``offset``, ``dark``, ``offset[b]``, ``scale``). units: (k,) each term's unit (``m``; ``1`` for
    the scale). values: (k,) their estimates in those units. covariance: (6 + k, 6 + k) the joint
    covariance of the pose's right tangent (rotation first, rad and m) and the terms.
    """

    T: np.ndarray
    terms: tuple[str, ...]
    units: tuple[str, ...]
    values: np.ndarray
    covariance: np.ndarray

    def inverse(self) -> PoseTerms:
        """The same estimate of ``T^-1`` (its tangent is ``-Ad(T) xi``; the terms unchanged)."""
        import gtsam

        k = len(self.terms)
        A = np.eye(6 + k)
        A[:6, :6] = -np.asarray(gtsam.Pose3(np.asarray(self.T, dtype=np.float64)).AdjointMap())
        C = A @ self.covariance @ A.T
        return dataclasses.replace(self, T=np.linalg.inv(self.T), covariance=0.5 * (C + C.T))


def lidar_term_units(lidar_errors: dict[str, Any]) -> list[str]:
    """Each term's unit (``m``, ``rad`` or ``1``) of ``Calibration.sensors['lidar_errors']``: the
    ``units`` the solve recorded (``LidarLayout.units``); a dict made without them (older code, by
    hand) by the terms' names."""
    units = lidar_errors.get("units")
    if units is not None:
        return [str(u) for u in units]
    names = [str(n) for n in lidar_errors["names"]]
    return ["rad" if n.startswith("elevation") else "1" if n == "scale" else "m" for n in names]


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle (deg) of a (3, 3) rotation matrix."""
    return math.degrees(math.acos(float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


@dataclass(frozen=True)
class Scan:
    """One LiDAR scan.

    points: (N, 3) float64, LiDAR frame, metres.
    intensity: (N,) float64, the sensor's reflectance units (zeros when the file has none), or None
        when a caller gives none (the LiDAR stage then reads zeros and judges it unusable, as
        ``has_intensity`` False).
    ring: (N,) int32 ring value as the file gives it (the file's numbering: Ouster's ring 0 is the
        top beam, Velodyne CSVs carry the hardware laser id; an organised cloud's row), or None when
        the file has none. The LiDAR stage maps it onto its beam table (0 = lowest elevation) with
        ``lidars.beam_index``; the simulator writes 0 = lowest unless told otherwise.
    source: where it came from, for messages.
    columns: columns per turn of an organised cloud (PCD WIDTH when HEIGHT > 1), else None.
    has_intensity: False when the file has no intensity field (x y z only, as Open3D's legacy
        clouds and MATLAB's ``pcwrite`` of a cloud without Intensity write): the board is then placed
        by its shape alone, and writers leave the field out.
    """

    points: np.ndarray
    intensity: np.ndarray | None
    ring: np.ndarray | None = None
    source: str = ""
    columns: int | None = None
    has_intensity: bool = True

    def __len__(self) -> int:
        return int(self.points.shape[0])


@dataclass(frozen=True)
class BoardReturns:
    """A board's LiDAR returns as the estimation core uses them to calibrate the LiDAR's own errors.

    points: (M, 3) measured returns well inside the board, LiDAR frame, metres.
    ring: (M,) int beam index (0 = lowest beam). dark: (M,) 1.0 on black print, 0.0 on white.
    sigma_m: one-sigma range noise of a return (the stage's plane-fit residual), metres.
    inplane_cov: (3, 3) covariance of the intensity fit's in-plane pose (rz, tx, ty), board frame.
    inplane_coupling: (3, 3) K: the in-plane error caused by a plane error (rx, ry, tz), so that
        the in-plane measurement is ``e_in + K e_plane`` (``lidar.covariance.ray_coupling``).
    outline: the in-plane pose comes from the board's outline alone (the LiDAR shows no print):
        its covariance gets a variance component of its own in the graph (``estimation.noise_loop``).
    corrected: the pose was fitted on the ranges corrected by an estimate of the LiDAR's errors
        (``run.range_refit``; ``points`` are the measured returns all the same): it rests on that
        estimate, so only a sensor model with range terms may use it (``estimation.selection``).
    """

    points: np.ndarray
    ring: np.ndarray
    dark: np.ndarray
    sigma_m: float
    inplane_cov: np.ndarray
    inplane_coupling: np.ndarray
    outline: bool = False
    corrected: bool = False


@dataclass(frozen=True)
class BoardFit:
    """The LiDAR stage's answer for one frame.

    T_lidar_board: (4, 4) pose of the board frame (interface.md) in the LiDAR frame.
    covariance: (6, 6) Pose3-tangent covariance of ``T_lidar_board``.
    corners_lidar: (K, 3) inner corners, LiDAR frame, metres, index k = i*(cols-1)+j.
    points_lidar: (M, 3) the board segment's points, LiDAR frame.
    intensity: (M,) their intensities.
    half_turn_ambiguous: True when the pattern looks the same after a half turn about
        the board normal, so the corner order is known only up to that turn.
    cost: the paper's fitting cost at the optimum.
    diagnostics: free-form numbers for reports (gray zone, timings, ...).
    """

    T_lidar_board: np.ndarray
    covariance: np.ndarray
    corners_lidar: np.ndarray
    points_lidar: np.ndarray
    intensity: np.ndarray
    half_turn_ambiguous: bool
    cost: float = float("nan")
    diagnostics: dict[str, float] = field(default_factory=dict)
    returns: BoardReturns | None = None


@dataclass(frozen=True)
class ImageView:
    """A small view of a frame's picture, kept so that the report need not read the image again.

    purpose: ``"tight"`` / ``"wide"`` (windows around the detected corners) or ``"whole"`` (the
    picture scaled down). jpeg: the view's pixels (BGR, JPEG bytes). x0, y0: its window's first
    full-image column and row; width_full: the picture's width; wrap: the window may cross a
    panorama's seam; zoom: view pixels per full-image pixel (``image.previews.Crop``).
    """

    purpose: str
    jpeg: bytes
    x0: int
    y0: int
    width_full: int
    wrap: bool
    zoom: float


@dataclass(frozen=True)
class ImageCorners:
    """The image stage's answer for one frame.

    uv: (K, 2) pixels (OpenCV convention, pixel centres at integers), index k as the board's.
    bearings: (K, 3) unit vectors in the camera frame of the camera model.
    cov_px: (K, 2, 2) pixel covariance of each corner.
    half_turn_ambiguous: True when the order is known only up to the board's half turn.
    diagnostics: free-form numbers for reports.
    detector: which detector found the grid (e.g. ``"sb"``, ``"classic"``, ``"cbdetect+gamma"``);
        empty when unknown (corners read back from a file).
    views: small views of the picture around the corners for the report (``image.previews``);
        empty when not made.
    """

    uv: np.ndarray
    bearings: np.ndarray
    cov_px: np.ndarray
    half_turn_ambiguous: bool
    diagnostics: dict[str, float] = field(default_factory=dict)
    detector: str = ""
    views: tuple[ImageView, ...] = ()


@dataclass(frozen=True)
class GraphFrame:
    """One frame's input to the estimation core (corners already in the order used).

    name: frame name (file stem).
    T_lidar_board: (4, 4) board pose from the LiDAR stage, ``p_lidar = T_lidar_board @ p_board``.
    board_cov: (6, 6) its Pose3-tangent covariance (rotation first, rad and m).
    points_board: (K, 3) corners in the board frame, metres (``Board.corners_board()`` order).
    bearings: (K, 3) measured bearings of the same corners, camera frame (normalised by the core).
    cov_px: (K, 2, 2) pixel covariance of each image corner, px^2.
    returns: the board's LiDAR returns (to calibrate the LiDAR's own errors), or None.
    uv: (K, 2) the corners' measured pixels (to refine the camera's intrinsics), or None.
    """

    name: str
    T_lidar_board: np.ndarray
    board_cov: np.ndarray
    points_board: np.ndarray
    bearings: np.ndarray
    cov_px: np.ndarray
    returns: BoardReturns | None = None
    uv: np.ndarray | None = None


@dataclass(frozen=True)
class FrameResult:
    """What happened to one frame in a calibration.

    T_lidar_board_refined: (4, 4) the board pose the estimation core settled on (used frames).
    damaged: a file of the frame could not be read (the reason names it and the problem).
    """

    name: str
    used: bool
    reason: str | None = None
    board: BoardFit | None = None
    corners: ImageCorners | None = None
    rms_bearing_error_mrad: float | None = None
    T_lidar_board_refined: np.ndarray | None = None
    damaged: bool = False


@dataclass(frozen=True)
class MomentResult:
    """What a rig's stages found at one moment (issue 24): every sensor's answer or why not.

    name: the moment's name. boards: {LiDAR: BoardFit} (its own frame). corners: {camera:
    ImageCorners}. failures: {sensor: reason} for the sensors that had data but no board (or whose
    file could not be read). damaged: the sensors whose file could not be read. contradicted: the
    cameras whose image showed the print's lower-left square in the other colour than the board's
    ``lower_left`` (``errors.BoardColourMismatch``; the rig's start turns the colour on their vote).
    Each observation's corner order is its own stage's (known up to the board's half turn when
    ``half_turn_ambiguous``); ``init.rig_start`` makes them agree.
    """

    name: str
    boards: dict[str, BoardFit] = field(default_factory=dict)
    corners: dict[str, ImageCorners] = field(default_factory=dict)
    failures: dict[str, str] = field(default_factory=dict)
    damaged: tuple[str, ...] = ()
    contradicted: tuple[str, ...] = ()

    @property
    def sensors(self) -> tuple[str, ...]:
        """The sensors that saw the board (LiDARs first, then cameras)."""
        return (*self.boards, *self.corners)


@dataclass(frozen=True)
class Calibration:
    """The extrinsic with its uncertainty.

    T_cam_lidar: (4, 4), ``p_cam = T_cam_lidar @ p_lidar``.
    covariance: (6, 6) Pose3-tangent covariance of ``T_cam_lidar`` (rotation first); NaN when the
        method gives none.
    frames: every frame, used or not, in input order.
    method: how it was estimated (``graph``, ``paper``, ``incremental``, ``joint-rigid``, ...).
    camera: the camera model's config section (our schema), so that exports need nothing else.
    sensors: the sensors' own errors the graph estimated, as plain data: ``lidar_errors`` (``names``,
        ``values``, ``sigmas`` in metres / rad / -, ``left_out``: [term, reason]) and
        ``camera_intrinsics`` (``names``, ``stated``, ``values``, ``sigmas``), each when present.
    causes: when the residuals are far above the detectors' stated noise, what likely explains them
        (``evaluation.causes.residual_causes``), one sentence each; the verdict names them.
    with_terms: ``T_cam_lidar`` with the LiDAR's range terms and their joint covariance, when the
        chosen sensor model has such terms (``verify`` compares the mount net of them).
    """

    T_cam_lidar: np.ndarray
    covariance: np.ndarray
    frames: tuple[FrameResult, ...]
    method: str = "graph"
    diagnostics: dict[str, float] = field(default_factory=dict)
    camera: dict[str, Any] | None = None
    sensors: dict[str, Any] = field(default_factory=dict)
    causes: tuple[str, ...] = ()
    with_terms: PoseTerms | None = None

    @property
    def extrinsic(self) -> Estimate:
        """``T_cam_lidar`` with its covariance."""
        return Estimate(self.T_cam_lidar, self.covariance)


@dataclass(frozen=True)
class ExpectedBoard:
    """Where the board is expected in a scan (e.g. predicted from the image and an extrinsic).

    T_lidar_board: (4, 4) predicted board pose in the LiDAR frame (board frame of interface.md;
        for a half-turn symmetric board either of the two equivalent poses).
    position_tol_m: how far the board's centre may be from the prediction, metres.
    angle_tol_deg: how far the board's normal may be turned from the prediction, degrees.
    """

    T_lidar_board: np.ndarray
    position_tol_m: float = 0.3
    angle_tol_deg: float = 20.0

    def __post_init__(self) -> None:
        T = np.asarray(self.T_lidar_board, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T_lidar_board must be a finite (4, 4) matrix, got shape {T.shape}")
        if not (self.position_tol_m > 0 and 0 < self.angle_tol_deg <= 180):
            raise ValueError("position_tol_m must be > 0 and angle_tol_deg in (0, 180]")
        object.__setattr__(self, "T_lidar_board", T)


@dataclass(frozen=True)
class RangeCorrection:
    """What a LiDAR's ranges read too long, as the graph estimated it (``estimation.lidar_errors``):
    a return of beam ``b`` at range ``rho`` reads ``offset_m + beam_offsets_m[b] + scale * rho``
    metres too long (beams not listed: no beam term). The dark print's offset is left out: the LiDAR
    stage fits the plane to the white print and finds the black's offset itself.
    """

    offset_m: float = 0.0
    beam_offsets_m: tuple[tuple[int, float], ...] = ()
    scale: float = 0.0

    def along_ray(self, ring: np.ndarray, rho: np.ndarray) -> np.ndarray:
        """(N,) metres each return (beam ``ring``, range ``rho``) reads too long."""
        r = np.asarray(ring).ravel()
        per_beam = np.zeros(len(r), dtype=np.float64)
        for b, v in self.beam_offsets_m:
            per_beam[r == b] = v
        return self.offset_m + per_beam + self.scale * np.asarray(rho, dtype=np.float64)

    def corrected(self, points: np.ndarray, ring: np.ndarray, sign: float = 1.0) -> np.ndarray:
        """(N, 3) ``points`` (LiDAR frame, metres) moved along their rays by the correction
        (``sign`` -1: the correction undone, the measured returns again)."""
        P = np.asarray(points, dtype=np.float64)
        rho = np.linalg.norm(P, axis=1)
        c = self.along_ray(ring, rho)
        return P * (1.0 - sign * c / np.maximum(rho, 1e-9))[:, None]


def to_plain(x: Any) -> Any:
    """Dataclasses, numpy arrays and scalars, tuples and paths -> plain dicts, lists, floats, ints,
    str (recursively), as YAML and JSON writers take them; TypeError for anything else."""
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return {f.name: to_plain(getattr(x, f.name)) for f in dataclasses.fields(x)}
    if isinstance(x, dict):
        return {str(k) if not isinstance(k, (int, float, bool)) else k: to_plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return to_plain(x.tolist())
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating):
        return float(x)
    if isinstance(x, os.PathLike):
        return os.fspath(x)
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    raise TypeError(f"cannot write a {type(x).__name__} as plain data: {x!r}")
