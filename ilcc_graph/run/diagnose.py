"""Likely causes of a frame the estimation dropped, in words a person reads.

The gate says *that* a board disagrees with the rest; this says *where*: its image corners are
fitted alone as a flat board under the lens model (bearing angles, camera frame), and that board is
compared with the one the LiDAR saw, carried into the camera by the extrinsic.

- The image alone fits a flat board clearly worse than the used frames' images do: blur, a lens
  model that does not fit there (near the image edge: try ``--refine-intrinsics``), or a curled
  print.
- The image fits, but its board sits elsewhere than the LiDAR's: the board moved between the scan
  and the photo (sensors not synchronised), or the LiDAR's fit is off (its metric picture shows it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.init.upnp import upnp
from ilcc_graph.types import FrameResult

__all__ = ["ImageAlone", "dropped_frame_cause", "fit_image_alone"]

#: an image fits a flat board "clearly worse" above this multiple of the used frames' median
OWN_FIT_RATIO = 2.0
#: corners beyond this fraction of the half-diagonal from the image centre are "near the edge"
EDGE_RADIUS = 0.75


@dataclass(frozen=True)
class ImageAlone:
    """The board fitted to one image's corners alone.

    corners_cam: (K, 3) the fitted board's corners in the camera frame (m), index as the board's.
    rms_mrad: RMS angle between the measured bearings and the fitted corners' directions.
    """

    corners_cam: np.ndarray
    rms_mrad: float


def fit_image_alone(bearings: np.ndarray, corners_board: np.ndarray) -> ImageAlone:
    """Least-squares board pose from unit bearings (K, 3) of the board's corners (K, 3, board frame)."""
    T0 = upnp(corners_board, bearings, prefer_front=True, tie_rtol=np.inf)[0].T_cam_points
    x0 = np.concatenate([Rotation.from_matrix(T0[:3, :3]).as_rotvec(), T0[:3, 3]])

    def residual(x: np.ndarray) -> np.ndarray:
        p = corners_board @ Rotation.from_rotvec(x[:3]).as_matrix().T + x[3:]
        return np.cross(bearings, p / np.linalg.norm(p, axis=1, keepdims=True)).ravel()

    x = least_squares(residual, x0, method="lm").x
    p = corners_board @ Rotation.from_rotvec(x[:3]).as_matrix().T + x[3:]
    d = p / np.linalg.norm(p, axis=1, keepdims=True)
    angles = np.arctan2(np.linalg.norm(np.cross(bearings, d), axis=1), np.sum(bearings * d, axis=1))
    return ImageAlone(p, float(1e3 * np.sqrt(np.mean(angles**2))))


def _edge_fraction(camera: CameraModel, uv: np.ndarray) -> float:
    """Largest distance of the corners from the image centre, as a fraction of the half-diagonal."""
    centre = np.array([camera.width / 2.0, camera.height / 2.0])
    return float(np.max(np.linalg.norm(uv - centre, axis=1)) / np.hypot(*centre))


def dropped_frame_cause(
    frame: FrameResult, board: Board, camera: CameraModel, T_cam_lidar: np.ndarray, typical_mrad: float
) -> str:
    """One sentence on the likely cause of a dropped frame, or "" when its stages' results are missing.

    typical_mrad: the median ``fit_image_alone`` rms of the used frames' images.
    """
    if frame.board is None or frame.corners is None:
        return ""
    alone = fit_image_alone(frame.corners.bearings, board.corners_board())
    lidar = frame.board.corners_lidar @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]
    # order-free (the half turn): each image-fit corner to the nearest LiDAR corner
    gap = np.linalg.norm(alone.corners_cam[:, None, :] - lidar[None, :, :], axis=2).min(axis=1)
    gap_mm = float(1e3 * np.sqrt(np.mean(gap**2)))
    edge = _edge_fraction(camera, frame.corners.uv)
    if alone.rms_mrad > OWN_FIT_RATIO * typical_mrad:
        where = (
            f"near the image edge ({edge:.0%} of the half-diagonal), where the lens model fits worst: "
            "--refine-intrinsics may keep it"
            if edge > EDGE_RADIUS
            else "blur, a curled print, or a lens model that does not fit there"
        )
        return (
            f"likely cause: the image corners fit a flat board worse than the used frames' do "
            f"(alone: rms {alone.rms_mrad:.3f} mrad, used frames' median {typical_mrad:.3f}): {where}"
        )
    return (
        f"likely cause: the image alone fits a flat board as well as the used frames' do (rms "
        f"{alone.rms_mrad:.3f} mrad, median {typical_mrad:.3f}) but it sits "
        f"{gap_mm:.0f} mm (corner rms) from where the LiDAR saw it: the board moved between the scan and "
        "the photo (sensors not synchronised), or the LiDAR's pattern fit is off (see its metric picture)"
    )
