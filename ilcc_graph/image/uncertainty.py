"""Per-corner pixel covariance, measured from the detection itself.

In a virtual pinhole view the printed board is a plane seen by an ideal pinhole, so its corners
obey a homography of the board plane exactly. Fitting one (8 parameters) to the K detected
corners leaves residuals whose RMS, with the dof correction ``sigma^2 = sum |r|^2 / (2K - 8)``,
measures the detector's noise in view pixels (isotropic). The view -> image mapping's local
Jacobian J carries it to the source image, ``cov_img = sigma^2 J J^T``; its eigenvalues are floored
at ``floor_px^2`` so that no corner is trusted beyond what sub-pixel detection can deliver.
"""

from __future__ import annotations

import cv2
import numpy as np


def homography_sigma(board_xy: np.ndarray, view_xy: np.ndarray) -> tuple[float, np.ndarray]:
    """(sigma, residuals): isotropic per-axis noise (view px) of corners (K, 2) about a fitted homography.

    board_xy: (K, 2) board-plane coordinates (any unit); view_xy: (K, 2) their view pixels.
    residuals: (K, 2) view pixels, detected minus fitted.
    """
    src = np.asarray(board_xy, dtype=np.float64).reshape(-1, 2)
    dst = np.asarray(view_xy, dtype=np.float64).reshape(-1, 2)
    K = len(src)
    if K < 5:
        raise ValueError(f"homography_sigma: need at least 5 corners, got {K}")
    H, _ = cv2.findHomography(src, dst, 0)
    if H is None:
        raise ValueError("homography_sigma: degenerate corner set")
    fit = cv2.perspectiveTransform(src[None], H)[0]
    r = dst - fit
    sigma = float(np.sqrt(np.sum(r * r) / (2 * K - 8)))
    return sigma, r


def image_covariance(sigma_view: float, J: np.ndarray, floor_px: float) -> np.ndarray:
    """(N, 2, 2) image-pixel covariance from isotropic view noise ``sigma_view`` and Jacobians J (N, 2, 2).

    Eigenvalues below ``floor_px**2`` are raised to it.
    """
    cov = (sigma_view**2) * (J @ np.swapaxes(J, 1, 2))
    w, V = np.linalg.eigh(cov)
    w = np.maximum(w, floor_px**2)
    return (V * w[:, None, :]) @ np.swapaxes(V, 1, 2)
