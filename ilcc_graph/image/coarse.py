"""The coarse search: where in the image is the board? (approximate corners, from any detector).

Candidates come lazily, cheapest first: the detector cascade (``detectors.py``) on the image
downscaled to a working width (a panorama also rolled by half its width, so that a board across
the seam is whole once), then on a ring of virtual pinhole views (``views.py``) around the
camera's field of view, the most distorted directions first. Every candidate is a sane grid
whose bearings fit a board-plane homography in a virtual pinhole (:func:`fit_in_view`).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..board import Board
from ..cameras import CameraModel
from .detectors import ContrastCache, grid_problem, run_attempt
from .views import (
    VirtualView,
    look_rotation,
    render_view,
    tangent_basis,
    view_around,
    view_to_image,
    wrap_image_u,
)


@dataclass(frozen=True)
class Candidate:
    """Where the coarse search saw the board (plain data for the fine pass)."""

    uv: np.ndarray  # (K, 2) approximate image pixels, row-major as the detector returned them
    attempt: str  # detector[+contrast] that found them
    stage: int  # 0 downscaled image, 1 ring of views
    width: int = 0  # columns of the downscaled copy searched (stage 0)


def fit_in_view(
    camera: CameraModel, uv: np.ndarray, board: Board, tol: float = 0.15, max_outliers: float = 0.1
) -> tuple[np.ndarray | None, str]:
    """Image corners (K, 2) checked (and repaired) as the board seen by ``camera``: (uv, "") or (None, why).

    Their bearings, seen by a virtual pinhole looking at them, must fit a board-plane homography
    (robust fit, LMedS) with no residual above ``tol`` squares (a coarse tolerance; the fine pass
    measures the noise), except at most ``max_outliers`` of the corners: those (a detector's
    corner stuck at the board's outer corner, say) are replaced by the homography's prediction,
    which the fine pass then refines like any other.
    """
    b = camera.bearing(uv)
    if not np.all(np.isfinite(b)):
        return None, "corners map to no bearing"
    try:
        view = view_around(camera, b, pad_px=0.0, max_size=10**6)
    except ValueError:
        return None, "corners span more than a hemisphere"
    xy = view.to_view(b)
    if grid_problem(xy, board) is not None:
        return None, "grid folded in the pinhole view"
    src = board.corners_board()[:, :2]
    H, _ = cv2.findHomography(src, xy, cv2.LMEDS)
    if H is None:  # cv2's stub types the result as never None; it is None when nothing fits
        return None, "corners fit no homography"  # type: ignore[unreachable]
    fit = cv2.perspectiveTransform(src[None], H)[0]
    sq = float(np.median(np.linalg.norm(np.diff(fit.reshape(*board.inner_shape, 2), axis=1), axis=-1)))
    bad = np.linalg.norm(xy - fit, axis=1) > tol * sq
    if bad.sum() > max_outliers * len(xy):
        return None, "corners do not fit a plane seen by a pinhole"
    if not bad.any():
        return uv, ""
    out = np.array(uv, dtype=np.float64, copy=True)
    out[bad] = view_to_image(view, camera, fit[bad])
    return (out, "") if np.all(np.isfinite(out)) else (None, "repaired corners outside the image")


def downscaled(gray: np.ndarray, width: int) -> np.ndarray:
    """``gray`` downscaled (area average) to about ``width`` columns; never upscaled.

    A reduction by 2 or more is rounded to a whole factor (8000 -> 1600 for 1500, say): OpenCV's
    area average over whole blocks of pixels is several times faster than over fractional ones."""
    H, W = gray.shape
    k = W / int(width)
    if k <= 1.0:
        return gray
    if k >= 2.0:
        k = float(round(k))
    return cv2.resize(gray, (max(1, round(W / k)), max(1, round(H / k))), interpolation=cv2.INTER_AREA)


def downscaled_candidates(
    gray: np.ndarray,
    camera: CameraModel,
    board: Board,
    plan: Sequence[tuple[str, int, bool]],
) -> Iterator[Candidate]:
    """Candidates from each step ``(attempt, width, roll)`` of ``plan`` in turn: the attempt on the
    image downscaled to ``width`` columns (never upscaled) and, with ``roll`` on a panorama, also
    rolled by half its width. Each downscaled copy (and its contrast variants) is made once; a step
    that repeats one already tried on the same copy is skipped (the cheap search's full-size copy
    of a small image is the coarse search's too)."""
    H, W = gray.shape
    copies: dict[tuple[int, int], ContrastCache] = {}  # (columns, shift) -> the copy's variants
    tried: set[tuple[str, int, int]] = set()
    smalls: dict[int, np.ndarray] = {}
    src = gray  # the unrolled steps' copies (the cheap search: always made) each from the next larger
    for width in sorted({int(w) for _, w, roll in plan if not roll}, reverse=True):
        smalls[width] = src = downscaled(src, width)
    for name, width, roll in plan:
        small = smalls[width] if width in smalls else smalls.setdefault(width, downscaled(gray, width))
        rows, cols = small.shape
        for shift in (0, cols // 2) if (roll and camera.periodic_u) else (0,):
            if (name, cols, shift) in tried:
                continue
            tried.add((name, cols, shift))
            if (cols, shift) not in copies:
                copies[(cols, shift)] = ContrastCache(np.roll(small, -shift, axis=1) if shift else small)
            c = run_attempt(name, copies[(cols, shift)], board)
            if c is None:
                continue
            c[:, 0] += shift
            sx, sy = cols / W, rows / H
            uv = wrap_image_u(
                camera, np.stack([(c[:, 0] + 0.5) / sx - 0.5, (c[:, 1] + 0.5) / sy - 0.5], axis=1)
            )
            fitted, _ = fit_in_view(camera, uv, board)
            if fitted is not None:
                yield Candidate(fitted, name, 0, cols)


def tile_directions(camera: CameraModel) -> np.ndarray:
    """(N, 3) camera-frame view directions inside the picture, the most distorted first.

    Rings at elevations 0, +-40 and +-72 deg (forward-left-up frame). The downscaled search already
    covers the mildly distorted part of the image, so directions are sorted by the anisotropy of
    the image there (ratio of the singular values of d uv / d angle): panorama poles, fisheye rim.
    """
    dirs = []
    for el_deg, n_az in ((0.0, 8), (40.0, 6), (-40.0, 6), (72.0, 3), (-72.0, 3)):
        el = np.deg2rad(el_deg)
        for az in np.arange(n_az) * (2 * np.pi / n_az):
            dirs.append([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    d_cam = np.asarray(dirs) @ camera.R_flu_cam  # rows: R_flu_cam.T @ d_flu
    d_cam = d_cam[camera.fov_contains(d_cam)]
    stretch = []
    for d in d_cam:
        sv = np.linalg.svd(camera.d_uv_d_point(d[None])[0] @ tangent_basis(d), compute_uv=False)
        stretch.append(sv[0] / max(sv[1], 1e-12))
    return d_cam[np.argsort(-np.asarray(stretch), kind="stable")]


def tile_candidates(
    gray: np.ndarray,
    camera: CameraModel,
    board: Board,
    cascade: tuple[str, ...],
    size_px: int = 640,
    fov_deg: float = 90.0,
) -> Iterator[Candidate]:
    """Candidates from the cascade on a ring of virtual views around the sphere.

    OpenCV's fast ``checkChessboard`` (milliseconds) on each contrast variant of a view gates the
    slow detectors.
    """
    n = int(size_px)
    f = 0.5 * n / np.tan(np.deg2rad(0.5 * fov_deg))
    pattern = (board.cols - 1, board.rows - 1)
    for d in tile_directions(camera):
        view = VirtualView(look_rotation(camera, d), f, (n - 1) / 2, (n - 1) / 2, n, n)
        images = ContrastCache(render_view(view, camera, gray))
        gate: dict[str, bool] = {}
        for name in cascade:
            con = name.partition("+")[2]
            if con not in gate:
                gate[con] = bool(cv2.checkChessboard(images.get(con), pattern))
            if not gate[con]:
                continue
            c = run_attempt(name, images, board)
            if c is None:
                continue
            uv = view_to_image(view, camera, c)
            fitted, _ = fit_in_view(camera, uv, board) if np.all(np.isfinite(uv)) else (None, "")
            if fitted is not None:
                yield Candidate(fitted, name, 1)
