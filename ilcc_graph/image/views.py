"""Virtual pinhole views: resample any camera's image around a direction as an ideal pinhole.

A :class:`VirtualView` is a distortion-free pinhole (focal ``f`` px, principal point ``(cx, cy)``,
size ``width`` x ``height``) whose frame (OpenCV axes: x right, y down, z forward) is turned by
``R_cam_view`` from the source camera's frame. A view pixel maps to a bearing
``R_cam_view @ normalise([(x - cx) / f, (y - cy) / f, 1])`` in the camera frame and on to the source
image with ``camera.project``. Pixels follow OpenCV (centres at integers) in both images.
Equirectangular panoramas are sampled with ``BORDER_WRAP`` so a view may straddle the seam.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from ..cameras import CameraModel

_INTERP = cv2.INTER_LINEAR


@dataclass(frozen=True)
class VirtualView:
    """An ideal pinhole looking along ``R_cam_view[:, 2]`` of the source camera's frame.

    R_cam_view: (3, 3) rotation, view frame -> camera frame.
    f: focal length, view pixels. cx, cy: principal point, view pixels. width, height: view size.
    """

    R_cam_view: np.ndarray
    f: float
    cx: float
    cy: float
    width: int
    height: int

    def rays(self, xy: np.ndarray) -> np.ndarray:
        """Unit bearings (..., 3) in the camera frame of view pixels (..., 2)."""
        xy = np.asarray(xy, dtype=np.float64)
        d = np.stack(
            [(xy[..., 0] - self.cx) / self.f, (xy[..., 1] - self.cy) / self.f, np.ones(xy.shape[:-1])],
            axis=-1,
        )
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return d @ self.R_cam_view.T

    def to_view(self, b_cam: np.ndarray) -> np.ndarray:
        """View pixels (..., 2) of camera-frame directions (..., 3); NaN behind the view."""
        p = np.asarray(b_cam, dtype=np.float64) @ self.R_cam_view
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(p[..., 2] > 1e-9, p[..., 2], np.nan)
            return np.stack([self.f * p[..., 0] / z + self.cx, self.f * p[..., 1] / z + self.cy], axis=-1)


def wrap_image_u(camera: CameraModel, uv: np.ndarray) -> np.ndarray:
    """Pixels with the column wrapped across the panorama seam (a no-op for cameras without a seam)."""
    if not camera.periodic_u:
        return uv
    out = np.array(uv, dtype=np.float64, copy=True)
    out[..., 0] = camera.wrap_u(out[..., 0])
    return out


def view_to_image(view: VirtualView, camera: CameraModel, xy: np.ndarray) -> np.ndarray:
    """Source-image pixels (..., 2) of view pixels (..., 2), wrapped into [-0.5, W-0.5) on a panorama."""
    return wrap_image_u(camera, camera.project(view.rays(xy)))


def view_jacobian(view: VirtualView, camera: CameraModel, xy: np.ndarray, h: float = 0.5) -> np.ndarray:
    """(N, 2, 2) d(image pixel) / d(view pixel) at view pixels (N, 2), central differences."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    J = np.empty((len(xy), 2, 2))
    for a in range(2):
        step = np.zeros(2)
        step[a] = h
        d = camera.project(view.rays(xy + step)) - camera.project(view.rays(xy - step))
        d[:, 0] = camera.wrap_du(d[:, 0])
        J[:, :, a] = d / (2 * h)
    return J


def tangent_basis(b: np.ndarray) -> np.ndarray:
    """(3, 2) an orthonormal basis of the plane orthogonal to the unit vector ``b`` (3,)."""
    a = np.array([1.0, 0.0, 0.0]) if abs(b[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(b, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(b, e1)], axis=1)


def pixels_per_radian(camera: CameraModel, b_cam: np.ndarray) -> float:
    """Angular resolution (px/rad) of ``camera`` at direction ``b_cam`` (3,): sqrt |det| of d uv / d angle."""
    b = np.asarray(b_cam, dtype=np.float64)
    b = b / np.linalg.norm(b)
    Jt = camera.d_uv_d_point(b[None])[0] @ tangent_basis(b)
    return float(np.sqrt(abs(np.linalg.det(Jt))))


def look_rotation(camera: CameraModel, centre_cam: np.ndarray) -> np.ndarray:
    """R_cam_view for a view looking along ``centre_cam`` (3,) with its y axis towards the world's down.

    "Up" is the camera's forward-left-up z axis (``R_flu_cam``), so a level board appears upright.
    """
    z = np.asarray(centre_cam, dtype=np.float64)
    z = z / np.linalg.norm(z)
    up = camera.R_flu_cam.T @ np.array([0.0, 0.0, 1.0])
    if abs(up @ z) > 0.95:  # looking near the zenith/nadir: any reference will do
        up = camera.R_flu_cam.T @ np.array([1.0, 0.0, 0.0])
    y = -(up - (up @ z) * z)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=1)


def view_around(
    camera: CameraModel,
    b_cam: np.ndarray,
    pad_px: float,
    scale: float = 1.0,
    max_size: int = 4000,
    snap_px: float = 0.0,
) -> VirtualView:
    """A view centred on the directions ``b_cam`` (N, 3) that holds them all with ``pad_px`` around.

    Its focal length matches the source camera's angular resolution at the centre times ``scale``.
    With ``snap_px`` > 0 the view is put on a lattice: its axis is rounded to a grid of about
    ``snap_px`` view pixels in azimuth and elevation (camera's forward-left-up frame) and its
    principal point to whole pixels, so that directions that differ by much less than that get
    the identical view (the same resampling of the image).
    """
    b = np.asarray(b_cam, dtype=np.float64).reshape(-1, 3)
    c = b.mean(axis=0)
    c /= np.linalg.norm(c)
    if snap_px > 0:
        # the lattice's angular step must not move with c itself: the resolution there rounded to
        # a power of two, so the step is snap_px view pixels within a factor of sqrt(2)
        step = snap_px / 2.0 ** np.round(np.log2(scale * pixels_per_radian(camera, c)))
        d = camera.R_flu_cam @ c
        az, el = (
            np.round(np.arctan2(d[1], d[0]) / step) * step,
            np.round(np.arcsin(np.clip(d[2], -1, 1)) / step) * step,
        )
        c = camera.R_flu_cam.T @ np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    R = look_rotation(camera, c)
    f = scale * pixels_per_radian(camera, c)
    probe = VirtualView(R, f, 0.0, 0.0, 1, 1).to_view(b)
    if not np.all(np.isfinite(probe)):
        raise ValueError("view_around: directions span more than a hemisphere")
    lo = probe.min(axis=0) - pad_px
    hi = probe.max(axis=0) + pad_px
    if snap_px > 0:
        lo = np.floor(lo)
    size = np.ceil(hi - lo).astype(int) + 1
    if np.any(size > max_size):  # shrink the focal length so the view fits
        k = max_size / float(size.max())
        f, lo, hi = f * k, lo * k, hi * k
        size = np.minimum(np.ceil(hi - lo).astype(int) + 1, max_size)
    return VirtualView(R, float(f), float(-lo[0]), float(-lo[1]), int(size[0]), int(size[1]))


def _view_maps(view: VirtualView, camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap's float32 maps (view pixel -> image pixel) of ``view``; outside the picture -> -10.

    Every pixel's ray as ``VirtualView.rays`` gives it (the same arithmetic, bit for bit), the grid's
    rows and columns worked out once each."""
    x = (np.arange(view.width, dtype=np.float64) - view.cx) / view.f
    y = (np.arange(view.height, dtype=np.float64) - view.cy) / view.f
    norm = np.sqrt((x * x)[None, :] + (y * y)[:, None] + 1.0)
    d = np.empty((view.height, view.width, 3))
    d[..., 0] = x[None, :] / norm
    d[..., 1] = y[:, None] / norm
    d[..., 2] = 1.0 / norm
    uv = camera.project(d @ view.R_cam_view.T)
    u, v = uv[..., 0], uv[..., 1]
    outside = ~(np.isfinite(u) & np.isfinite(v))
    map_x, map_y = u.astype(np.float32), v.astype(np.float32)
    map_x[outside] = -10.0
    map_y[outside] = -10.0
    return map_x, map_y


@functools.lru_cache(maxsize=64)
def _cached_maps(camera: CameraModel, key: tuple) -> tuple[np.ndarray, np.ndarray]:
    R, f, cx, cy, w, h = key
    return _view_maps(VirtualView(np.frombuffer(R).reshape(3, 3), f, cx, cy, w, h), camera)


def render_view(view: VirtualView, camera: CameraModel, image: np.ndarray) -> np.ndarray:
    """Resample ``image`` (H, W[, C]) of ``camera`` into ``view`` (bilinear); black outside the picture.

    The maps of small views (the search tiles, the same for every image of a camera) are cached.
    """
    if view.width * view.height <= _CACHE_MAX_PX:
        key = (
            np.ascontiguousarray(view.R_cam_view, dtype=np.float64).tobytes(),
            float(view.f),
            float(view.cx),
            float(view.cy),
            int(view.width),
            int(view.height),
        )
        map_x, map_y = _cached_maps(camera, key)
    else:
        map_x, map_y = _view_maps(view, camera)
    border = cv2.BORDER_WRAP if camera.periodic_u else cv2.BORDER_CONSTANT
    return cv2.remap(image, map_x, map_y, _INTERP, borderMode=border)


_CACHE_MAX_PX = 1024 * 1024
