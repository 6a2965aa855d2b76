"""Pictures drawn on images: corners numbered, LiDAR points projected, occlusion, coloured clouds.

Windows of a picture (``Crop``, ``crop_around``, ``downscale``) are ``image.previews``'s.

Images are (H, W, 3) uint8 BGR (OpenCV's order); pixels follow interface.md (centres at integers).
Everything here is pure: arrays in, new arrays out; nothing is read or written.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..board import Board
from ..cameras import CameraModel
from ..evaluation.metric import MetricPoints, transform_points
from ..image.previews import Crop, crop_around, downscale  # re-exported: the report's windows
from ..types import Scan

#: a colour as OpenCV draws it: (blue, green, red), 0..255
BGR = tuple[int, int, int]

__all__ = [
    "crop_box",
    "draw_corners",
    "Crop",
    "crop_around",
    "downscale",
    "encode_png",
    "colour_map",
    "colour_range",
    "with_colour_bar",
    "edge_image",
    "splat",
    "Visibility",
    "visible_points",
    "ColouredPoints",
    "colour_points",
    "draw_reprojection",
    "draw_points",
    "draw_metric",
    "OCCLUDED_RGB",
    "OUTSIDE_RGB",
]

#: Colour (R, G, B) given in coloured clouds to points the camera cannot see (hidden behind something).
OCCLUDED_RGB = (255, 0, 255)
#: Colour (R, G, B) of points outside the picture.
OUTSIDE_RGB = (128, 128, 128)


def crop_box(
    uv: np.ndarray, shape: tuple[int, ...], pad: float = 0.25, min_size: int = 200
) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) pixel box around points ``uv`` (N,2), padded by ``pad`` of its size."""
    lo, hi = np.nanmin(uv, axis=0), np.nanmax(uv, axis=0)
    size = np.maximum(hi - lo, min_size)
    c = (lo + hi) / 2
    half = size * (0.5 + pad)
    x0, y0 = np.floor(c - half).astype(int)
    x1, y1 = np.ceil(c + half).astype(int)
    h, w = shape[:2]
    return max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)


def _scale_for(shape: tuple[int, ...]) -> float:
    return max(1.0, max(shape[:2]) / 800.0)


def draw_corners(
    image: np.ndarray, uv: np.ndarray, crop: bool = True, colour: BGR = (0, 0, 255)
) -> np.ndarray:
    """Corners ``uv`` (K,2, pixels) drawn and numbered on a copy of ``image`` (BGR).

    Corner 0 is ringed green, the last one blue, the rest red, joined in index order. With
    ``crop`` the result is cut to the board's neighbourhood (large panoramas stay small).
    """
    x0, y0, x1, y1 = crop_box(uv, image.shape) if crop else (0, 0, image.shape[1], image.shape[0])
    out = np.ascontiguousarray(image[y0:y1, x0:x1]).copy()
    if out.ndim == 2:
        out = cv2.cvtColor(out, cv2.COLOR_GRAY2BGR)
    _draw_numbered(out, uv - np.array([x0, y0]), colour)
    return out


def _draw_numbered(
    out: np.ndarray, p: np.ndarray, colour: BGR = (0, 0, 255), line: BGR = (0, 200, 255)
) -> None:
    """Corners p (K, 2) in ``out``'s pixels, joined, numbered; 0 green, last blue (in place)."""
    scale = _scale_for(out.shape)
    r, th = int(round(4 * scale)), max(1, int(round(scale)))
    ok = np.all(np.isfinite(p), axis=1)
    pts = np.round(np.where(ok[:, None], p, 0)).astype(np.int32)
    if ok.all():
        cv2.polylines(out, [pts.reshape(-1, 1, 2)], False, line, th, cv2.LINE_AA)
    for k, (x, y) in enumerate(pts):
        if not ok[k]:
            continue
        c = (0, 200, 0) if k == 0 else (255, 80, 0) if k == len(pts) - 1 else colour
        cv2.circle(out, (int(x), int(y)), r * (2 if k in (0, len(pts) - 1) else 1), c, th, cv2.LINE_AA)
        org = (int(x) + r + 1, int(y) - r - 1)
        font, size = cv2.FONT_HERSHEY_SIMPLEX, 0.4 * scale
        cv2.putText(out, str(k), org, font, size, (255, 255, 255), th + 2, cv2.LINE_AA)  # halo
        cv2.putText(out, str(k), org, font, size, c, th, cv2.LINE_AA)


# ------------------------------------------------------------------------------ encoding
def encode_png(image: np.ndarray, bits: int = 8) -> bytes:
    """PNG bytes of a BGR or gray uint8 image, keeping the top ``bits`` of each channel.

    Photographs with sensor noise barely compress; 6 bits halves the file with no visible change.
    """
    img = np.ascontiguousarray(image)
    if bits < 8:
        img = img & np.uint8((0xFF << (8 - bits)) & 0xFF)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ValueError(f"encode_png: OpenCV could not encode an image of shape {image.shape}")
    return buf.tobytes()


# ------------------------------------------------------------------------------ colours
def colour_map(
    values: np.ndarray,
    lo: float | None = None,
    hi: float | None = None,
    name: str = "jet",
    span: tuple[float, float] = (0.1, 0.92),
) -> np.ndarray:
    """(N, 3) uint8 BGR colours of ``values`` on matplotlib's colormap ``name`` over [lo, hi].

    lo/hi default to the 2nd and 98th percentiles; ``span`` is the part of the colormap used
    (its darkest ends vanish on black print); NaN maps to gray.
    """
    from matplotlib import colormaps

    v = np.asarray(values, dtype=np.float64).ravel()
    fin = np.isfinite(v)
    if lo is None or hi is None:
        q = np.percentile(v[fin], [2, 98]) if fin.any() else np.array([0.0, 1.0])
        lo = float(q[0]) if lo is None else lo
        hi = float(q[1]) if hi is None else hi
    t = np.clip((v - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    t = span[0] + (span[1] - span[0]) * t
    rgba = colormaps[name](np.where(fin, t, 0.0))
    bgr = (255 * rgba[:, [2, 1, 0]]).astype(np.uint8)
    bgr[~fin] = 128
    return bgr


def colour_range(values: np.ndarray) -> tuple[float, float]:
    """The values ``colour_map`` spans by default: their 2nd and 98th percentiles ((0, 1) without any)."""
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if not v.size:
        return 0.0, 1.0
    lo, hi = np.percentile(v, [2, 98])
    return float(lo), float(hi)


def with_colour_bar(
    image: np.ndarray, lo: float, hi: float, name: str, label: str, span: tuple[float, float] = (0.1, 0.92)
) -> np.ndarray:
    """``image`` with its colour scale below it: ``colour_map``'s colours from ``lo`` to ``hi`` (values
    beyond take the end colours) and the values at both ends and the middle, ``label`` before them."""
    h, w = image.shape[:2]
    scale = max(w / 600.0, 0.5)
    bar_h, text_h = int(round(24 * scale)), int(round(34 * scale))
    strip = np.full((bar_h + text_h, w, 3), 255, np.uint8)
    x0, x1 = int(0.25 * w), int(0.97 * w)
    ramp = colour_map(np.linspace(lo, hi, max(x1 - x0, 2)), lo, hi, name, span)
    strip[4:bar_h, x0:x1] = ramp[None, : x1 - x0]
    font, size, thick = cv2.FONT_HERSHEY_SIMPLEX, 0.8 * scale, max(1, int(round(1.5 * scale)))
    y = bar_h + int(0.8 * text_h)
    cv2.putText(
        strip, label, (int(0.02 * w), int(0.75 * bar_h) + 4), font, size, (0, 0, 0), thick, cv2.LINE_AA
    )
    for frac in (0.0, 0.5, 1.0):
        text = f"{lo + frac * (hi - lo):.3g}"
        (tw, _), _ = cv2.getTextSize(text, font, size, thick)
        x = int(np.clip(x0 + frac * (x1 - x0) - tw / 2, 0, w - tw))
        cv2.putText(strip, text, (x, y), font, size, (0, 0, 0), thick, cv2.LINE_AA)
    base = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    return np.vstack([base, strip])


def edge_image(image: np.ndarray, low: int = 50, high: int = 150) -> np.ndarray:
    """BGR picture of the image's Canny edges: white edges on a dark copy of the image."""
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    edges = cv2.Canny(cv2.GaussianBlur(gray, (3, 3), 0), low, high)
    out = (0.25 * cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)).astype(np.uint8)
    out[edges > 0] = 255
    return out


def splat(image: np.ndarray, uv: np.ndarray, bgr: np.ndarray, radius: int = 1) -> np.ndarray:
    """Square dots of side 2*radius+1 at pixels ``uv`` (N, 2) with colours ``bgr`` (N, 3), in place.

    Later points paint over earlier ones (pass them far to near to see the near ones).
    """
    H, W = image.shape[:2]
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    ok = np.all(np.isfinite(uv), axis=1)
    ij = np.round(uv[ok]).astype(np.int64)
    col = np.asarray(bgr).reshape(-1, 3)[ok]
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            x, y = ij[:, 0] + dx, ij[:, 1] + dy
            m = (x >= 0) & (x < W) & (y >= 0) & (y < H)
            image[y[m], x[m]] = col[m]
    return image


# --------------------------------------------------------------------------- occlusion
@dataclass(frozen=True)
class Visibility:
    """Which LiDAR points the camera sees.

    uv: (N, 2) pixels (NaN when not imaged). in_image: (N,) imaged inside the picture.
    occluded: (N,) in the picture but hidden from the camera (behind the board or behind a
    nearer surface in the coarse depth map). depth: (N,) distance from the camera centre, metres.
    """

    uv: np.ndarray
    in_image: np.ndarray
    occluded: np.ndarray
    depth: np.ndarray

    @property
    def visible(self) -> np.ndarray:
        return self.in_image & ~self.occluded


def _pixels_per_radian(camera: CameraModel) -> float:
    c = np.array([[(camera.width - 1) / 2.0, (camera.height - 1) / 2.0]])
    b = camera.bearing(c)
    J = camera.d_uv_d_point(b)[0]
    val = float(np.mean(np.linalg.norm(J, axis=1)))
    return val if np.isfinite(val) and val > 0 else camera.width / (2 * np.pi)


def visible_points(
    points_lidar: np.ndarray,
    camera: CameraModel,
    T_cam_lidar: np.ndarray,
    T_lidar_board: np.ndarray | None = None,
    board: Board | None = None,
    cell_deg: float = 0.5,
    tolerance_m: float = 0.15,
    tolerance_rel: float = 0.05,
) -> Visibility:
    """Project LiDAR points and leave out the ones the camera cannot see.

    Two z-buffer tests:
    - against the board (when ``T_lidar_board`` and ``board`` are given): a point whose ray from
      the camera crosses the physical board nearer than the point (by ``tolerance_m``) is hidden;
    - against a coarse depth map of all points (cells of ``cell_deg`` degrees): a point farther than
      the cell's nearest point by ``tolerance_m + tolerance_rel * depth`` is hidden.
    The LiDAR sees from another place than the camera, so points it saw may be out of the camera's
    sight; these are the ones left out.
    """
    p_cam = transform_points(T_cam_lidar, points_lidar)
    uv = camera.project(p_cam) if len(p_cam) else np.zeros((0, 2))
    in_img = camera.in_image(uv) if len(p_cam) else np.zeros(0, dtype=bool)
    depth = np.linalg.norm(p_cam, axis=1)
    occluded = np.zeros(len(p_cam), dtype=bool)
    if T_lidar_board is not None and board is not None and len(p_cam):
        T_cam_board = np.asarray(T_cam_lidar, dtype=np.float64) @ np.asarray(T_lidar_board, dtype=np.float64)
        n = T_cam_board[:3, 2]
        c = float(n @ T_cam_board[:3, 3])
        with np.errstate(divide="ignore", invalid="ignore"):
            d = p_cam / depth[:, None]
            t = c / (d @ n)
        hit = np.isfinite(t) & (t > 0) & (t < depth - tolerance_m)
        if hit.any():
            x = t[hit, None] * d[hit]
            q = transform_points(np.linalg.inv(T_cam_board), x)
            x0, x1, y0, y1 = board.extent()
            on = (q[:, 0] >= x0) & (q[:, 0] <= x1) & (q[:, 1] >= y0) & (q[:, 1] <= y1)
            idx = np.flatnonzero(hit)[on]
            occluded[idx] = True
    m = in_img & np.isfinite(depth)
    if m.any():
        cell = max(1.0, np.radians(cell_deg) * _pixels_per_radian(camera))
        ij = np.floor((uv[m] + 0.5) / cell).astype(np.int64)
        ncol = int(np.ceil(camera.width / cell)) + 1
        key = ij[:, 1] * ncol + ij[:, 0]
        uniq, inv = np.unique(key, return_inverse=True)
        nearest = np.full(len(uniq), np.inf)
        np.minimum.at(nearest, inv, depth[m])
        hidden = depth[m] > nearest[inv] + tolerance_m + tolerance_rel * nearest[inv]
        occluded[np.flatnonzero(m)[hidden]] = True
    occluded &= in_img
    return Visibility(uv=uv, in_image=in_img, occluded=occluded, depth=depth)


@dataclass(frozen=True)
class ColouredPoints:
    """Each LiDAR point with the colour of its pixel.

    rgb: (N, 3) uint8 (red, green, blue; ``io.write_ply``'s order). Points outside the picture get
    :data:`OUTSIDE_RGB`, points hidden from the camera :data:`OCCLUDED_RGB`.
    visibility: the :class:`Visibility` behind it.
    """

    rgb: np.ndarray
    visibility: Visibility


def colour_points(
    scan: Scan,
    image: np.ndarray,
    camera: CameraModel,
    T_cam_lidar: np.ndarray,
    T_lidar_board: np.ndarray | None = None,
    board: Board | None = None,
) -> ColouredPoints:
    """Colour every point of ``scan`` by its pixel in ``image`` (BGR), occluded points marked."""
    vis = visible_points(scan.points, camera, T_cam_lidar, T_lidar_board, board)
    rgb = np.empty((len(scan), 3), dtype=np.uint8)
    rgb[:] = OUTSIDE_RGB
    rgb[vis.occluded] = OCCLUDED_RGB
    ok = vis.visible
    if ok.any():
        H, W = image.shape[:2]
        ij = np.round(vis.uv[ok]).astype(np.int64)
        x, y = np.clip(ij[:, 0], 0, W - 1), np.clip(ij[:, 1], 0, H - 1)
        pix = image[y, x] if image.ndim == 3 else np.repeat(image[y, x][:, None], 3, axis=1)
        rgb[ok] = pix[:, ::-1]
    return ColouredPoints(rgb=rgb, visibility=vis)


# ---------------------------------------------------------------------------- overlays
def draw_reprojection(crop: Crop, detected_uv: np.ndarray, reprojected_uv: np.ndarray | None) -> np.ndarray:
    """Detected corners (numbered: 0 green, last blue) and re-projected LiDAR corners (cyan
    crosses, joined to their detected corner) on a copy of the crop."""
    out = crop.image.copy()
    det = crop.to_crop(detected_uv)
    _draw_numbered(out, det)
    if reprojected_uv is not None:
        scale = _scale_for(out.shape)
        th = max(1, int(round(scale)))
        rep = crop.to_crop(reprojected_uv)
        for (x, y), (a, b) in zip(rep, det):
            if not (np.isfinite(x) and np.isfinite(y)):
                continue
            p = (int(round(x)), int(round(y)))
            cv2.line(out, (int(round(a)), int(round(b))), p, (255, 255, 0), th, cv2.LINE_AA)
            cv2.drawMarker(out, p, (255, 255, 0), cv2.MARKER_CROSS, int(round(14 * scale)), th, cv2.LINE_AA)
    return out


def draw_points(
    base: np.ndarray,
    uv: np.ndarray,
    bgr: np.ndarray,
    order: np.ndarray | None = None,
    radius: int | None = None,
) -> np.ndarray:
    """Coloured dots at ``uv`` (N, 2, ``base``'s pixels) on a copy of ``base``; ``order`` sorts them
    (draw far points first, e.g. ``np.argsort(-depth)``)."""
    out = base.copy()
    if order is not None:
        uv, bgr = uv[order], bgr[order]
    r = radius if radius is not None else (1 if max(out.shape[:2]) < 1200 else 2)
    return splat(out, uv, bgr, r)


def draw_metric(crop: Crop, mp: MetricPoints, corners_uv: np.ndarray) -> np.ndarray:
    """The intensity metric at work: each board point on the crop, dimmed picture underneath.

    Green: inside a detected cell and its intensity colour agrees with the pattern; red: it
    disagrees (dot grows with f_d); yellow: gray zone; blue: outside the detected cells.
    """
    out = (0.6 * crop.image).astype(np.uint8)
    _draw_numbered(out, crop.to_crop(corners_uv), colour=(200, 200, 200), line=(120, 120, 120))
    uv = crop.to_crop(mp.uv)
    cols = np.empty((len(uv), 3), dtype=np.uint8)
    cols[:] = (255, 128, 0)  # outside: blue
    cols[mp.inside] = (0, 200, 0)
    cols[mp.inside & (mp.colour < 0)] = (0, 220, 255)
    cols[mp.mismatch] = (0, 0, 255)
    r = 1 if max(out.shape[:2]) < 1200 else 2
    agree = ~mp.mismatch
    splat(out, uv[agree], cols[agree], r)
    if mp.mismatch.any():
        s = max(1e-9, float(np.max(mp.f_d)))
        for (x, y), fd in zip(uv[mp.mismatch], mp.f_d[mp.mismatch]):
            if np.isfinite(x) and np.isfinite(y):
                rad = int(round(r + 1 + 3 * r * fd / s))
                cv2.circle(out, (int(round(x)), int(round(y))), rad, (0, 0, 255), -1, cv2.LINE_AA)
    return out
