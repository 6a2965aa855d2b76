"""Pictures drawn on images: corners numbered, first and last marked."""

from __future__ import annotations

import cv2
import numpy as np


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


def draw_corners(image: np.ndarray, uv: np.ndarray, crop: bool = True, colour=(0, 0, 255)) -> np.ndarray:
    """Corners ``uv`` (K,2, pixels) drawn and numbered on a copy of ``image`` (BGR).

    Corner 0 is ringed green, the last one blue, the rest red, joined in index order. With
    ``crop`` the result is cut to the board's neighbourhood (large panoramas stay small).
    """
    x0, y0, x1, y1 = crop_box(uv, image.shape) if crop else (0, 0, image.shape[1], image.shape[0])
    out = np.ascontiguousarray(image[y0:y1, x0:x1]).copy()
    if out.ndim == 2:
        out = cv2.cvtColor(out, cv2.COLOR_GRAY2BGR)
    p = uv - np.array([x0, y0])
    scale = max(1.0, max(out.shape[:2]) / 800.0)
    r, th = int(round(4 * scale)), max(1, int(round(scale)))
    pts = np.round(p).astype(np.int32)
    cv2.polylines(out, [pts.reshape(-1, 1, 2)], False, (0, 200, 255), th, cv2.LINE_AA)
    for k, (x, y) in enumerate(pts):
        c = (0, 200, 0) if k == 0 else (255, 80, 0) if k == len(pts) - 1 else colour
        cv2.circle(out, (int(x), int(y)), r * (2 if k in (0, len(pts) - 1) else 1), c, th, cv2.LINE_AA)
        cv2.putText(
            out,
            str(k),
            (int(x) + r + 1, int(y) - r - 1),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.4 * scale,
            c,
            th,
            cv2.LINE_AA,
        )
    return out
