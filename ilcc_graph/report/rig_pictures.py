"""A LiDAR's board points on a camera's image and their share on the detected board (the rig report).

docs/rig.md, "The rig's report".

``board_share`` is the check in one number: the share of a LiDAR's board points, projected into a
camera with the calibrated pose, that land on the board the camera detected (the convex hull of its
inner corners, grown outward by a square and the board's margin). Near 1 on a right calibration
(98-100 % on simulated and recorded data); a LiDAR turned by 5 degrees moves a third or more of
its points off the board. ``board_picture`` draws the same: the points
coloured by intensity and the detected corners on a window of the image around the board.
Pure: arrays in, arrays out (images BGR uint8, pixels as interface.md's).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from ..board import Board
from ..cameras import CameraModel
from ..evaluation.metric import transform_points
from ..image.previews import CropSpec, circular_mean_u, spec_crop
from ..types import BoardFit, ImageCorners
from .overlays import colour_map, colour_range, draw_points, draw_reprojection, with_colour_bar

__all__ = [
    "BOARD_VIEW",
    "BoardPicture",
    "board_outline_px",
    "board_picture",
    "board_share",
    "share_of_points",
]

#: the window around the board: its pixels padded by 40 % of their extent on every side (at least 40
#: px), enlarged towards 600 px (at most 8 times) or shrunk to 600 px (``image.previews.CropSpec``)
BOARD_VIEW = CropSpec(pad=0.4, min_size=40, zoom_to=600, max_zoom=8, max_size=600)


def board_outline_px(
    uv_corners: np.ndarray, inner_shape: tuple[int, int], grow: tuple[float, float]
) -> np.ndarray:
    """(M, 2) convex polygon (pixels, in order) around a detected board: its inner-corner grid
    ``uv_corners`` (K, 2), index k = i * inner_shape[1] + j (or half-turned), extended outward by
    ``grow`` = (squares across the short side's rows, squares along the long side) by linear
    extrapolation of the grid's outer rows and columns. Needs at least 2 x 2 corners."""
    ni, nj = inner_shape
    G = np.asarray(uv_corners, dtype=np.float64).reshape(ni, nj, 2)
    gi, gj = grow

    def out_j(row: np.ndarray) -> np.ndarray:
        return np.vstack([row[0] + gj * (row[0] - row[1]), row, row[-1] + gj * (row[-1] - row[-2])])

    edges = np.vstack([out_j(G[0] + gi * (G[0] - G[1])), out_j(G[-1] + gi * (G[-1] - G[-2]))])
    return cv2.convexHull(edges.astype(np.float32))[:, 0].astype(np.float64)


def share_of_points(uv: np.ndarray, polygon: np.ndarray) -> float:
    """Share of the pixels ``uv`` (N, 2) inside the convex ``polygon`` (M, 2, in order); a pixel that
    is not finite (not imaged) counts as outside. NaN without pixels."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if not len(uv):
        return float("nan")
    p = np.asarray(polygon, dtype=np.float64)
    e = np.roll(p, -1, axis=0) - p
    with np.errstate(invalid="ignore"):
        cross = e[None, :, 0] * (uv[:, None, 1] - p[None, :, 1]) - e[None, :, 1] * (
            uv[:, None, 0] - p[None, :, 0]
        )
        inside = np.all(cross >= 0, axis=1) | np.all(cross <= 0, axis=1)
    return float(np.mean(inside & np.all(np.isfinite(uv), axis=1)))


def _unwrap(u: np.ndarray, ref: float, period: float) -> np.ndarray:
    return ref + np.mod(u - ref + period / 2, period) - period / 2


def board_share(
    uv_points: np.ndarray,
    uv_corners: np.ndarray,
    board: Board,
    period: float | None = None,
) -> float:
    """Share of a LiDAR's board points, projected to pixels ``uv_points`` (N, 2), inside the board
    the camera detected (``uv_corners`` (K, 2) its inner corners): the corners' hull grown by one
    square plus the board's margin on every side (``board_outline_px``). ``period``: the image
    width of a panorama whose columns wrap (both unwrapped about the corners first), else None."""
    uv = np.array(uv_points, dtype=np.float64).reshape(-1, 2)
    c = np.array(uv_corners, dtype=np.float64).reshape(-1, 2)
    if not np.all(np.isfinite(c)) or min(board.inner_shape) < 2:
        return float("nan")
    if period is not None:
        ref = circular_mean_u(c[:, 0], int(period))
        c[:, 0], uv[:, 0] = _unwrap(c[:, 0], ref, period), _unwrap(uv[:, 0], ref, period)
    s = board.square_size
    grow = (1.0 + board.margin_short / s, 1.0 + board.margin_long / s)
    return share_of_points(uv, board_outline_px(c, board.inner_shape, grow))


@dataclass(frozen=True)
class BoardPicture:
    """One LiDAR's board on one camera's image: the drawn window (BGR), its scale (window pixels per
    image pixel), the board's points and how many were imaged, their share on the detected board
    (``board_share``; NaN without detected corners)."""

    image: np.ndarray
    zoom: float
    n_points: int
    n_imaged: int
    share: float


def board_picture(
    image: np.ndarray,
    camera: CameraModel,
    board: Board,
    T_cam_lidar: np.ndarray,
    fit: BoardFit,
    corners: ImageCorners | None,
) -> BoardPicture | None:
    """The LiDAR's board points (``fit.points_lidar``, LiDAR frame, metres) projected with
    ``T_cam_lidar`` (4, 4) into ``camera``'s ``image``, coloured by intensity (scale below), with
    the detected ``corners`` numbered (0 green, last blue), on a window around the board
    (``BOARD_VIEW``). None without detected corners when fewer than half the points are imaged
    (the board was not in the camera's view)."""
    pts = np.asarray(fit.points_lidar, dtype=np.float64).reshape(-1, 3)
    uv = (
        camera.project(transform_points(np.asarray(T_cam_lidar, dtype=np.float64), pts))
        if len(pts)
        else np.zeros((0, 2))
    )
    imaged = camera.in_image(uv) if len(uv) else np.zeros(0, dtype=bool)
    uv_c = None if corners is None else np.asarray(corners.uv, dtype=np.float64)
    if uv_c is None and not (imaged.any() and 2 * imaged.sum() >= len(pts)):
        return None
    share = float("nan")
    if uv_c is not None:
        share = board_share(uv, uv_c, board, camera.width if camera.periodic_u else None)
    where = uv[imaged] if uv_c is None else np.vstack([uv[imaged], uv_c])
    crop = spec_crop(image, where, camera, BOARD_VIEW)
    if crop is None:
        return None
    inten = np.asarray(fit.intensity, dtype=np.float64)[imaged]
    lo, hi = colour_range(inten)
    radius = 2 if crop.zoom > 1 else 1
    dots = draw_points(crop.image, crop.to_crop(uv[imaged]), colour_map(inten, lo, hi, "jet"), radius=radius)
    if uv_c is not None:
        dots = draw_reprojection(dataclasses.replace(crop, image=dots), uv_c, None)
    drawn = with_colour_bar(dots, lo, hi, "jet", "intensity")
    return BoardPicture(drawn, crop.zoom, len(pts), int(imaged.sum()), share)
