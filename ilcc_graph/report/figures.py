"""One frame's pictures for the report: corners, metric, points by range and on the edges, the whole.

The pictures are drawn on the views the image stage kept (``ImageCorners.views``, see
``image.previews``) when there are some, so a large picture is not decoded again; otherwise on
the image given. They are compressed (WebP by default) and small (600 px crops, a 1200 px whole
picture); ``FigureOptions.full_views`` adds the whole picture at full resolution (JPEG), and
coloured points (for the coloured clouds) need the image itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..board import Board
from ..cameras import CameraModel
from ..evaluation.frame_errors import eval_frame_with_scan
from ..evaluation.metric import EvalFrame, metric_points, transform_points
from ..image.previews import TIGHT, WHOLE_WIDTH, WIDE, Crop, CropSpec, downscale, spec_crop, view_crop
from ..types import FrameResult, Scan
from .overlays import (
    ColouredPoints,
    Visibility,
    colour_map,
    colour_points,
    colour_range,
    draw_metric,
    draw_points,
    draw_reprojection,
    edge_image,
    visible_points,
    with_colour_bar,
)

__all__ = ["FIGURES_DIR", "FigureOptions", "FrameFigures", "encode_image", "frame_figures"]

FIGURES_DIR = "figures"


@dataclass(frozen=True)
class FigureOptions:
    """How a frame's pictures are written: ``fmt`` ``webp`` / ``jpg`` / ``png`` at ``quality``
    (WebP, JPEG); ``full_views``: also the whole picture at full resolution with the points (needs
    the image); ``colours``: colour the scan's points by the image (needs the image)."""

    fmt: str = "webp"
    quality: int = 65
    full_views: bool = False
    colours: bool = False

    def __post_init__(self) -> None:
        if self.fmt not in ("webp", "jpg", "png"):
            raise ValueError(f"FigureOptions.fmt must be webp, jpg or png, got {self.fmt!r}")


@dataclass(frozen=True)
class FrameFigures:
    """One frame's pictures ({relative path: encoded bytes}, in display order with captions), its
    coloured points (None without the image), the full-resolution view's path (or None) and what
    the metric needs (board points rebuilt from the scan when the result lacks them)."""

    name: str
    files: dict[str, bytes]
    captions: dict[str, str]
    coloured: ColouredPoints | None
    eval_frame: EvalFrame | None = None
    full: str | None = None


def encode_image(image: np.ndarray, fmt: str = "webp", quality: int = 65) -> bytes:
    """A BGR or gray uint8 image as WebP, JPEG (``quality``) or PNG bytes.

    WebP through Pillow at its fast setting (``method=1``: a few times faster than OpenCV's
    encoder, which has no such setting, for files a few percent larger)."""
    img = np.ascontiguousarray(image)
    if fmt == "webp":
        import io

        from PIL import Image

        rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB) if img.ndim == 3 else img
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="WEBP", quality=int(quality), method=1)
        return buf.getvalue()
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)] if fmt == "jpg" else [cv2.IMWRITE_PNG_COMPRESSION, 6]
    ok, encoded = cv2.imencode(f".{fmt}", img, params)
    if not ok:
        raise ValueError(f"encode_image: OpenCV could not encode an image of shape {image.shape} as {fmt}")
    return encoded.tobytes()


def _crop(
    result: FrameResult | None,
    purpose: str,
    image: np.ndarray | None,
    camera: CameraModel,
    candidates: tuple[np.ndarray | None, ...],
    spec: CropSpec,
) -> Crop | None:
    """The image stage's view of ``purpose`` when kept, else the window around the first usable
    pixel set of ``candidates`` cut from ``image``."""
    if result is not None and result.corners is not None and result.corners.views:
        got = view_crop(result.corners.views, purpose)
        if got is not None:
            return got
    if image is None:
        return None
    for uv in candidates:
        if uv is not None and len(uv) and np.isfinite(uv).all(axis=1).any():
            return spec_crop(image, uv, camera, spec)
    return None


def _whole(
    result: FrameResult | None, image: np.ndarray | None, max_width: int
) -> tuple[np.ndarray, float] | None:
    if result is not None and result.corners is not None and result.corners.views:
        got = view_crop(result.corners.views, "whole")
        if got is not None:
            return got.image, got.zoom
    return None if image is None else downscale(image, max_width)


def frame_figures(
    name: str,
    scan: Scan,
    image: np.ndarray | None,
    camera: CameraModel,
    board: Board,
    T_cam_lidar: np.ndarray,
    result: FrameResult | None = None,
    max_width: int = WHOLE_WIDTH,
    options: FigureOptions = FigureOptions(),
) -> FrameFigures:
    """Pictures of one frame under ``T_cam_lidar`` (``image``: BGR, or None when the views kept with
    ``result``'s corners suffice).

    - ``<name>_corners``: detected corners numbered (0 green, last blue) and the LiDAR corners
      re-projected (cyan crosses), cropped around the board;
    - ``<name>_metric``: the board points as the intensity metric judges them;
    - ``<name>_range``: the scan's points the camera can see, on the image, coloured by range;
    - ``<name>_edges``: the same on the image's edges, coloured by intensity;
    - ``<name>_whole``: the whole picture scaled down, points by range;
    - with ``options.full_views`` and the image: ``<name>_full.jpg``, the whole picture at full size.
    Points hidden from the camera (behind the board, or behind nearer points) are left out.
    """
    T = np.asarray(T_cam_lidar, dtype=np.float64)
    bf = result.board if result is not None else None
    cr = result.corners if result is not None else None
    T_lb = None if bf is None or not np.all(np.isfinite(bf.T_lidar_board)) else bf.T_lidar_board
    bd = board if T_lb is not None else None
    coloured = None
    if image is not None and options.colours:
        coloured = colour_points(scan, image, camera, T, T_lb, bd)
        vis: Visibility = coloured.visibility
    else:
        vis = visible_points(scan.points, camera, T, T_lb, bd)
    rng_lidar = np.linalg.norm(scan.points, axis=1)
    out = _Pictures(name, options)
    uv_corners = None if cr is None else np.asarray(cr.uv, dtype=np.float64)
    uv_rep = None
    if bf is not None and len(bf.corners_lidar):
        uv_rep = camera.project(transform_points(T, bf.corners_lidar))
    ef = eval_frame_with_scan(result, scan, board) if result is not None else None
    uv_board = None
    if ef is not None and len(ef.points_lidar):
        uv_board = camera.project(transform_points(T, ef.points_lidar))
    where = (uv_corners, uv_board, uv_rep)
    tight = _crop(result, "tight", image, camera, where, TIGHT)
    crop = _crop(result, "wide", image, camera, where, WIDE)
    vis_idx = np.flatnonzero(vis.visible)
    far_first = vis_idx[np.argsort(-vis.depth[vis_idx])]
    if tight is not None and uv_corners is not None:
        out.put(
            "corners",
            draw_reprojection(tight, uv_corners, uv_rep),
            "Detected corners (0 green, last blue, joined in index order) and the LiDAR corners "
            "re-projected with the result (cyan crosses).",
        )
    if tight is not None and ef is not None and len(ef.points_lidar):
        mp = metric_points(ef, camera, board, T)
        out.put(
            "metric",
            draw_metric(tight, mp, ef.uv),
            "The intensity metric: board points inside the detected cells agreeing with the printed "
            "colour (green), disagreeing (red, larger = farther from the grid), in the gray zone "
            "(yellow), outside the cells (blue).",
        )
    if crop is not None:
        _range_and_edges(out, crop, vis.uv[far_first], far_first, rng_lidar, scan.intensity)
    lo, hi = colour_range(rng_lidar[far_first])
    colours = colour_map(rng_lidar[far_first], lo, hi, "turbo")
    whole = _whole(result, image, max_width)
    if whole is not None:
        small, f = whole
        uv_small = (vis.uv[far_first] + 0.5) * f - 0.5
        # 3x3 dots where points are sparse on the picture, single pixels where they would cover it
        sparse = small.shape[0] * small.shape[1] > 40 * max(len(far_first), 1)
        dots = draw_points(small, uv_small, colours, radius=int(sparse))
        out.put(
            "whole",
            with_colour_bar(dots, lo, hi, "turbo", "range (m)"),
            f"The whole picture (scaled by {f:.2f}) with every visible LiDAR point, coloured by range.",
        )
    full = None
    if options.full_views and image is not None:
        full = f"{FIGURES_DIR}/full/{name}_full.jpg"
        out.files[full] = encode_image(draw_points(image, vis.uv[far_first], colours, radius=1), "jpg", 90)
    return FrameFigures(name, out.files, out.captions, coloured, ef, full)


class _Pictures:
    """A frame's pictures as they are drawn: encoded files by relative path, and their captions."""

    def __init__(self, name: str, options: FigureOptions) -> None:
        self.name, self.options = name, options
        self.files: dict[str, bytes] = {}
        self.captions: dict[str, str] = {}

    def put(self, suffix: str, img: np.ndarray, caption: str) -> None:
        key = f"{FIGURES_DIR}/{self.name}_{suffix}.{self.options.fmt}"
        self.files[key] = encode_image(img, self.options.fmt, self.options.quality)
        self.captions[key] = caption


def _range_and_edges(
    out: _Pictures,
    crop: Crop,
    uv: np.ndarray,
    order: np.ndarray,
    rng_lidar: np.ndarray,
    intensity: np.ndarray | None,
) -> None:
    """The visible points (pixels ``uv`` of the points ``order``, far first) on the board's wide crop,
    coloured by range, and on the crop's edges, coloured by intensity (none without an intensity)."""
    uvc = crop.to_crop(uv)
    h, w = crop.image.shape[:2]
    inside = (uvc[:, 0] >= -0.5) & (uvc[:, 0] < w - 0.5) & (uvc[:, 1] >= -0.5) & (uvc[:, 1] < h - 0.5)
    sel, uvc = order[inside], uvc[inside]
    r = 2 if crop.zoom > 1 else None
    if not sel.size:
        return
    lo, hi = colour_range(rng_lidar[sel])
    dots = draw_points(crop.image, uvc, colour_map(rng_lidar[sel], lo, hi, "turbo"), radius=r)
    out.put(
        "range",
        with_colour_bar(dots, lo, hi, "turbo", "range (m)"),
        "Visible LiDAR points on the image, coloured by range (scale below the picture).",
    )
    if intensity is None:
        return
    lo, hi = colour_range(intensity[sel])
    dots = draw_points(edge_image(crop.image), uvc, colour_map(intensity[sel], lo, hi, "jet"), radius=r)
    out.put(
        "edges",
        with_colour_bar(dots, lo, hi, "jet", "intensity"),
        "Visible LiDAR points on the image's edges, coloured by intensity (scale below the picture).",
    )
