"""Image reading and atomic writing with OpenCV (BGR, uint8)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from .files import atomic_write

__all__ = ["read_image", "write_image", "IMAGE_SUFFIXES"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def _decode(cv2, buf: np.ndarray) -> np.ndarray | None:  # noqa: ANN001 - the cv2 module
    """cv2.imdecode without OpenCV's own log lines on a damaged file (we say what is wrong)."""
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    if log is None:
        return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    level = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_SILENT)
    try:
        return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    finally:
        log.setLogLevel(level)


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as (H, W, 3) uint8 BGR.

    Gray images are promoted to three channels, an alpha channel is dropped, 16-bit images are
    scaled to 8 bits (value / 257). Missing, empty or undecodable files raise ``InputError``.
    """
    import cv2

    p = Path(path)
    try:
        buf = np.fromfile(p, dtype=np.uint8)
    except FileNotFoundError:
        raise InputError(f"{p}: image file not found") from None
    except OSError as e:
        raise InputError(f"{p}: cannot read image ({e})") from None
    if buf.size == 0:
        raise InputError(f"{p}: empty image file")
    img = _decode(cv2, buf)
    if img is None:
        raise InputError(f"{p}: cannot decode image (corrupt or not an image)")
    if img.dtype == np.uint16:
        img = np.round(img.astype(np.float64) / 257.0).astype(np.uint8)
    elif img.dtype in (np.float32, np.float64):
        img = np.clip(np.round(img * 255.0 if img.max() <= 1.0 else img), 0, 255).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise InputError(f"{p}: unsupported image pixel type {img.dtype}")
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    elif img.shape[2] == 1:
        img = cv2.cvtColor(img[:, :, 0], cv2.COLOR_GRAY2BGR)
    return np.ascontiguousarray(img)


def write_image(path: str | Path, img: np.ndarray) -> Path:
    """Encode ``img`` (BGR or gray, uint8/uint16) by the path's suffix and write it atomically."""
    import cv2

    p = Path(path)
    ext = p.suffix.lower() or ".png"
    try:
        ok, enc = cv2.imencode(ext, np.asarray(img))
    except cv2.error:
        ok = False
    if not ok:
        raise ValueError(f"{p}: OpenCV cannot encode an image as {ext!r}")
    return atomic_write(p, enc.tobytes())
