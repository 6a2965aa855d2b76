"""Small views of a picture: windows around pixels (across a panorama's seam) and the whole picture
scaled down, as the report draws on them.

``make_views`` keeps, while the image is in memory anyway (the image stage), the windows the report
needs around the detected corners and the scaled-down picture as JPEG bytes (``types.ImageView``),
so that the report never decodes a large picture a second time; ``view_crop`` turns one back into a
:class:`Crop`. Pure: arrays in, arrays and bytes out.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..cameras import CameraModel
from ..types import ImageView

__all__ = [
    "TIGHT",
    "WHOLE_WIDTH",
    "WIDE",
    "Crop",
    "CropSpec",
    "circular_mean_u",
    "crop_around",
    "downscale",
    "make_views",
    "spec_crop",
    "view_crop",
]


def circular_mean_u(u: np.ndarray, width: int) -> float:
    """Mean panorama column of ``u`` on the circle of period ``width`` (right across the seam)."""
    a = 2.0 * np.pi * (np.asarray(u, dtype=np.float64) + 0.5) / width
    a = a[np.isfinite(a)]
    if a.size == 0:
        return float("nan")
    m = np.arctan2(np.mean(np.sin(a)), np.mean(np.cos(a)))
    return float(np.mod(m, 2.0 * np.pi) * width / (2.0 * np.pi) - 0.5)


@dataclass(frozen=True)
class Crop:
    """A window of an image: ``image`` (h, w, 3) and the map from full-image pixels into it.

    Full pixel (u, v) is at ``zoom * ((u - x0) mod W_full, v - y0)`` for panoramas that wrap
    (``wrap``), else at ``zoom * (u - x0, v - y0)`` (pixel centres scale about -0.5).
    """

    image: np.ndarray
    x0: int
    y0: int
    width_full: int
    wrap: bool
    zoom: float = 1.0

    def to_crop(self, uv: np.ndarray) -> np.ndarray:
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        out = uv - np.array([self.x0, self.y0])
        if self.wrap:
            out[:, 0] = np.mod(out[:, 0] + 0.5, self.width_full) - 0.5
        return (out + 0.5) * self.zoom - 0.5

    def zoomed(self, min_size: int = 600, max_zoom: int = 4, max_size: int | None = None) -> Crop:
        """The same window enlarged by an integer factor (nearest neighbour) until its longer side
        reaches ``min_size`` pixels (at most ``max_zoom`` times, never past ``max_size``), so small
        boards stay legible; or shrunk (area averaging) to ``max_size`` pixels when larger, so the
        report stays light."""
        side = max(self.image.shape[:2]) if self.image.size else 0
        if max_size is not None and side > max_size:
            f = max_size / side
            size = (max(1, round(self.image.shape[1] * f)), max(1, round(self.image.shape[0] * f)))
            img = cv2.resize(self.image, size, interpolation=cv2.INTER_AREA)
            f_eff = img.shape[1] / self.image.shape[1]
            return Crop(img, self.x0, self.y0, self.width_full, self.wrap, self.zoom * f_eff)
        z = int(min(max_zoom, max(1, np.ceil(min_size / max(side, 1)))))
        if max_size is not None:
            z = max(1, min(z, max_size // max(side, 1)))  # never past max_size
        if z == 1:
            return self
        img = cv2.resize(self.image, None, fx=z, fy=z, interpolation=cv2.INTER_NEAREST)
        return Crop(img, self.x0, self.y0, self.width_full, self.wrap, self.zoom * z)


def crop_around(
    image: np.ndarray,
    uv: np.ndarray,
    camera: CameraModel | None = None,
    pad: float = 0.6,
    min_size: int = 240,
) -> Crop:
    """A crop around pixels ``uv`` (N, 2) padded by ``pad`` of their extent on every side.

    For a ``camera`` whose columns wrap (a panorama) the window may cross the seam.
    """
    H, W = image.shape[:2]
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    uv = uv[np.all(np.isfinite(uv), axis=1)]
    wrap = camera is not None and camera.periodic_u
    if uv.size == 0:
        return Crop(np.ascontiguousarray(image[:0, :0]), 0, 0, W, wrap)
    if wrap:
        ref = circular_mean_u(uv[:, 0], W)
        u = ref + (np.mod(uv[:, 0] - ref + W / 2, W) - W / 2)
        uv = np.column_stack([u, uv[:, 1]])
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    size = np.maximum(hi - lo, min_size)
    c = (lo + hi) / 2
    half = size * (0.5 + pad)
    x0, y0 = (int(v) for v in np.floor(c - half))
    x1, y1 = (int(v) for v in np.ceil(c + half))
    y0, y1 = max(y0, 0), min(y1, H)
    if wrap:
        if x1 - x0 >= W:
            x0, x1 = 0, W
        if 0 <= x0 and x1 <= W:
            img = np.ascontiguousarray(image[y0:y1, x0:x1])
        else:
            img = np.ascontiguousarray(image[y0:y1][:, np.mod(np.arange(x0, x1), W)])
        return Crop(img, int(np.mod(x0, W)), y0, W, True)
    x0, x1 = max(x0, 0), min(x1, W)
    return Crop(np.ascontiguousarray(image[y0:y1, x0:x1]).copy(), x0, y0, W, False)


def downscale(image: np.ndarray, max_width: int = 1600) -> tuple[np.ndarray, float]:
    """(image no wider than ``max_width``, factor applied to pixel coordinates)."""
    W = image.shape[1]
    if W <= max_width:
        return image.copy(), 1.0
    f = max_width / W
    size = (max_width, max(1, int(round(image.shape[0] * f))))
    # area averaging by the largest whole factor that divides the size first (OpenCV's fast path)
    k = next((k for k in range(int(W // max_width), 1, -1) if W % k == 0 and image.shape[0] % k == 0), 1)
    if k > 1:
        image = cv2.resize(image, (W // k, image.shape[0] // k), interpolation=cv2.INTER_AREA)
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA), f


# ---------------------------------------------------------------------- the report's views
@dataclass(frozen=True)
class CropSpec:
    """How a report window is cut: ``pad`` of the pixels' extent on each side, at least
    ``min_size`` pixels, then enlarged towards ``zoom_to`` (at most ``max_zoom`` times) or shrunk to
    ``max_size`` (``Crop.zoomed``)."""

    pad: float
    min_size: int
    zoom_to: int
    max_zoom: int
    max_size: int


#: the corners and the metric, close up
TIGHT = CropSpec(pad=0.2, min_size=40, zoom_to=600, max_zoom=8, max_size=600)
#: the points on the picture around the board
WIDE = CropSpec(pad=0.9, min_size=120, zoom_to=600, max_zoom=4, max_size=600)
#: the whole picture scaled down to this width
WHOLE_WIDTH = 1200


def spec_crop(image: np.ndarray, uv: np.ndarray, camera: CameraModel, spec: CropSpec) -> Crop | None:
    """The window ``spec`` cuts around ``uv`` (enlarged or shrunk), or None when it is empty."""
    crop = crop_around(image, uv, camera, pad=spec.pad, min_size=spec.min_size)
    return crop.zoomed(spec.zoom_to, spec.max_zoom, spec.max_size) if crop.image.size else None


def _view(purpose: str, crop: Crop, quality: int) -> ImageView:
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(crop.image), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError(f"make_views: OpenCV could not encode a view of shape {crop.image.shape}")
    return ImageView(purpose, buf.tobytes(), crop.x0, crop.y0, crop.width_full, crop.wrap, crop.zoom)


def make_views(
    image: np.ndarray, uv: np.ndarray, camera: CameraModel, quality: int = 95
) -> tuple[ImageView, ...]:
    """The report's windows around pixels ``uv`` (the detected corners: ``TIGHT`` and ``WIDE``,
    shrunk but not enlarged) and the whole picture at ``WHOLE_WIDTH``, JPEG at ``quality``."""
    out = []
    for purpose, spec in (("tight", TIGHT), ("wide", WIDE)):
        crop = crop_around(image, uv, camera, pad=spec.pad, min_size=spec.min_size)
        if crop.image.size:
            if max(crop.image.shape[:2]) > spec.max_size:
                crop = crop.zoomed(spec.zoom_to, spec.max_zoom, spec.max_size)
            out.append(_view(purpose, crop, quality))
    small, f = downscale(image, WHOLE_WIDTH)
    out.append(_view("whole", Crop(small, 0, 0, image.shape[1], False, f), quality))
    return tuple(out)


def view_crop(views: tuple[ImageView, ...], purpose: str) -> Crop | None:
    """The view of ``purpose`` decoded (enlarged as its ``CropSpec`` says), or None when absent."""
    v = next((v for v in views if v.purpose == purpose), None)
    if v is None:
        return None
    img = cv2.imdecode(np.frombuffer(v.jpeg, np.uint8), cv2.IMREAD_COLOR)
    if img is None:  # the view's JPEG is our own encoding: it always decodes
        raise ValueError(f"the {purpose!r} view's JPEG does not decode")
    crop = Crop(img, v.x0, v.y0, v.width_full, v.wrap, v.zoom)
    spec = {"tight": TIGHT, "wide": WIDE}.get(purpose)
    return crop if spec is None else crop.zoomed(spec.zoom_to, spec.max_zoom, spec.max_size)
