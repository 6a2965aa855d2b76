"""Plain data passed between pipeline stages (frozen dataclasses of numpy arrays).

Frames and units follow ``shared/interface.md``: metres, radians unless a name says
otherwise, poses as 4x4 homogeneous matrices ``T_a_b`` with ``p_a = T_a_b @ p_b``.
Covariances of poses are 6x6 in GTSAM's Pose3 tangent convention
``T_true = T_est * Pose3.Expmap(xi)``, ``xi = (rx, ry, rz, tx, ty, tz)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Scan:
    """One LiDAR scan.

    points: (N, 3) float64, LiDAR frame, metres.
    intensity: (N,) float64, the sensor's reflectance units.
    ring: (N,) int32 beam index (0 = lowest elevation) or None when the file has none.
    source: where it came from, for messages.
    """

    points: np.ndarray
    intensity: np.ndarray
    ring: np.ndarray | None = None
    source: str = ""

    def __len__(self) -> int:
        return int(self.points.shape[0])


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
    """

    uv: np.ndarray
    bearings: np.ndarray
    cov_px: np.ndarray
    half_turn_ambiguous: bool
    diagnostics: dict[str, float] = field(default_factory=dict)
    detector: str = ""


@dataclass(frozen=True)
class FrameResult:
    """What happened to one frame in a calibration."""

    name: str
    used: bool
    reason: str | None = None
    board: BoardFit | None = None
    corners: ImageCorners | None = None
    rms_bearing_error_mrad: float | None = None


@dataclass(frozen=True)
class Calibration:
    """The extrinsic with its uncertainty.

    T_cam_lidar: (4, 4), ``p_cam = T_cam_lidar @ p_lidar``.
    covariance: (6, 6) Pose3-tangent covariance of ``T_cam_lidar`` (rotation first).
    frames: every frame, used or not, in input order.
    """

    T_cam_lidar: np.ndarray
    covariance: np.ndarray
    frames: tuple[FrameResult, ...]
    method: str = "graph"
    diagnostics: dict[str, float] = field(default_factory=dict)
