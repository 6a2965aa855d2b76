"""Chessboard inner corners in panoramic, fisheye and pinhole images (stage 3).

Two passes (docs/image_stage.md):

1. **coarse**: ``cv2.findChessboardCornersSB`` on a copy of the image downscaled to about
   ``ImageOptions.coarse_width`` columns; a panorama is also tried rolled by half its width, so a
   board straddling the seam is found whole. When that fails, a ring of virtual pinhole views
   (``views.py``) covering the camera's field of view is searched the same way.
2. **fine**: the neighbourhood of the coarse grid is resampled into a virtual pinhole view at the
   source's full angular resolution (undistorted, seam-free), the grid is detected there again,
   put in canonical order (``ordering.py``), its noise measured (``uncertainty.py``), and the
   corners are mapped back to image pixels and bearings through ``camera.project``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from ..board import Board
from ..cameras import CameraModel
from ..errors import CornersNotFound
from ..types import ImageCorners
from .ordering import order_grid
from .uncertainty import homography_sigma, image_covariance
from .views import (
    VirtualView,
    look_rotation,
    render_view,
    tangent_basis,
    view_around,
    view_jacobian,
    view_to_image,
    wrap_image_u,
)

_SB_COARSE = cv2.CALIB_CB_NORMALIZE_IMAGE
_SB_TILES = (0, cv2.CALIB_CB_NORMALIZE_IMAGE)  # histogram equalisation hurts on a near-uniform view
_SB_FINE = (  # tried in turn (success varies with these on real images); cornerSubPix refines after
    cv2.CALIB_CB_NORMALIZE_IMAGE,
    0,
    cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_ACCURACY,
    cv2.CALIB_CB_ACCURACY,
    cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE,
    cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE,
)


@dataclass(frozen=True)
class ImageOptions:
    """Tuning of :func:`detect_corners`.

    coarse_width: width (px) of the downscaled copy searched first (never upscaled).
    view_scale: focal length of the fine view relative to the source's angular resolution there.
    max_view_px: largest side of the fine view (px); a nearer board gets a coarser view.
    tile_views: search a ring of virtual views when the downscaled image shows no board.
    tile_size_px: side of each search view (px); tile_fov_deg: its field of view.
    floor_px: lower bound of the corner sigma in image pixels (covariance eigenvalue floor^2).
    subpix: refine the fine view's corners with ``cv2.cornerSubPix`` (removes the detector's
        outward bias at the outer corners).
    backend: detector in the fine view: ``"sb"`` (OpenCV's findChessboardCornersSB), ``"cbdetect"``
        (Geiger's detector, libcbdetect) or ``"auto"`` (the refined coarse corners, then SB, then
        cbdetect). ``diagnostics["backend"]``: 0 SB, 1 cbdetect, 2 refined coarse corners.
    reuse_coarse: with ``backend="auto"``, first move the coarse corners into the fine view, refine
        them there by cornerSubPix and keep them when a board-plane homography fits them (sigma <=
        0.15 view px); the detectors run again only otherwise (saves ~0.1-0.5 s per image).
    strict_colour: raise ``CornersNotFound`` when the print's corner colour contradicts
        ``board.lower_left`` (a misconfigured even x even board); False keeps the geometric
        order (z towards the camera), flags it half-turn ambiguous and reports ``colour_score`` < 0.
    """

    coarse_width: int = 2000
    view_scale: float = 1.0
    max_view_px: int = 3000
    tile_views: bool = True
    tile_size_px: int = 640
    tile_fov_deg: float = 90.0
    floor_px: float = 0.05
    strict_colour: bool = True
    subpix: bool = True
    backend: str = "auto"
    reuse_coarse: bool = True

    def __post_init__(self) -> None:
        if int(self.coarse_width) < 200:
            raise ValueError(f"ImageOptions: coarse_width must be >= 200 px, got {self.coarse_width!r}")
        if not (0.25 <= float(self.view_scale) <= 4.0):
            raise ValueError(f"ImageOptions: view_scale must be in [0.25, 4], got {self.view_scale!r}")
        if int(self.max_view_px) < 200 or int(self.tile_size_px) < 200:
            raise ValueError("ImageOptions: max_view_px and tile_size_px must be >= 200 px")
        if not (20.0 <= float(self.tile_fov_deg) < 170.0):
            raise ValueError(f"ImageOptions: tile_fov_deg must be in [20, 170), got {self.tile_fov_deg!r}")
        if self.backend not in ("auto", "sb", "cbdetect"):
            raise ValueError(
                f"ImageOptions: backend must be 'auto', 'sb' or 'cbdetect', got {self.backend!r}"
            )
        if not (np.isfinite(self.floor_px) and self.floor_px >= 0):
            raise ValueError(f"ImageOptions: floor_px must be finite and >= 0, got {self.floor_px!r}")


# --------------------------------------------------------------------------- input
def to_gray(image: np.ndarray, camera: CameraModel) -> np.ndarray:
    """(H, W) uint8 grey image of a BGR/BGRA/grey array that matches ``camera``'s size.

    Raises ValueError for anything that is not such an image.
    """
    if not isinstance(image, np.ndarray):
        raise ValueError(f"image must be a numpy array (H, W[, 1|3|4]), got {type(image).__name__}")
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3, 4)):
        raise ValueError(f"image must have shape (H, W) or (H, W, 1|3|4), got {image.shape}")
    if image.dtype == bool or not (
        np.issubdtype(image.dtype, np.integer) or np.issubdtype(image.dtype, np.floating)
    ):
        raise ValueError(f"image must hold real numbers (uint8 preferred), got dtype {image.dtype}")
    if image.shape[:2] != (camera.height, camera.width):
        raise ValueError(
            f"image is {image.shape[1]}x{image.shape[0]} px but the camera model is "
            f"{camera.width}x{camera.height}"
        )
    img = image
    if img.dtype != np.uint8:
        f = img.astype(np.float64)
        if not np.all(np.isfinite(f)):
            raise ValueError("image holds NaN or infinite values")
        if np.issubdtype(img.dtype, np.integer):
            hi = float(np.iinfo(img.dtype).max)
        else:  # floats: [0, 1] or [0, 255]
            hi = 1.0 if f.max() <= 1.0 else 255.0
        img = np.clip(np.rint(f * (255.0 / hi)), 0, 255).astype(np.uint8)
    if img.ndim == 3:
        img = {
            1: lambda a: a[:, :, 0],
            3: lambda a: cv2.cvtColor(a, cv2.COLOR_BGR2GRAY),
            4: lambda a: cv2.cvtColor(a, cv2.COLOR_BGRA2GRAY),
        }[img.shape[2]](img)
    return np.ascontiguousarray(img)


def _cbdetect(gray: np.ndarray, board: Board) -> np.ndarray | None:
    """(K, 2) corners from Geiger's detector (libcbdetect), row-major with cols-1 per row, or None.

    Accepted only when it returns exactly the board's (rows-1) x (cols-1) grid (either way round).
    """
    try:
        from libCBDetect import Checkerboard
    except ImportError:  # optional back end
        return None
    det = Checkerboard()
    det.norm = True
    det.show_processing = False
    det.show_debug_image = False
    det.array_norm_to_image(gray.astype(np.float64) / 255.0, gray.shape[0], gray.shape[1])
    det.find_corners()
    det.find_board_from_corners()
    r, c = int(det.rows), int(det.cols)
    n_i, n_j = board.inner_shape
    if r * c != n_i * n_j or {r, c} != {n_i, n_j}:
        return None
    u, v = np.zeros(r * c), np.zeros(r * c)
    det.get_board_corners(u, v)
    g = np.stack([u, v], axis=1).reshape(r, c, 2)
    if (r, c) != (n_i, n_j):
        g = g.transpose(1, 0, 2)
    g = g.reshape(-1, 2)
    return g if np.all(np.isfinite(g)) else None


# -------------------------------------------------------------------------- coarse
def _sb(gray: np.ndarray, board: Board, flags: int) -> np.ndarray | None:
    """(K, 2) corners from findChessboardCornersSB (row-major, cols-1 per row), or None."""
    ok, c = cv2.findChessboardCornersSB(gray, (board.cols - 1, board.rows - 1), flags=flags)
    return c.reshape(-1, 2).astype(np.float64) if ok else None


def _coarse_downscaled(gray: np.ndarray, camera: CameraModel, board: Board, width: int) -> np.ndarray | None:
    """Approximate corner pixels (K, 2) of the full image from a downscaled search, or None."""
    H, W = gray.shape
    s = min(1.0, width / W)
    small = gray if s == 1.0 else cv2.resize(gray, (round(W * s), round(H * s)), interpolation=cv2.INTER_AREA)
    sx, sy = small.shape[1] / W, small.shape[0] / H
    for shift in (0, small.shape[1] // 2) if camera.periodic_u else (0,):
        c = _sb(np.roll(small, -shift, axis=1) if shift else small, board, _SB_COARSE)
        if c is not None:
            c[:, 0] += shift
            uv = np.stack([(c[:, 0] + 0.5) / sx - 0.5, (c[:, 1] + 0.5) / sy - 0.5], axis=1)
            return wrap_image_u(camera, uv)
    return None


def _tile_directions(camera: CameraModel) -> np.ndarray:
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


def _coarse_tiles(
    gray: np.ndarray, camera: CameraModel, board: Board, opts: ImageOptions
) -> np.ndarray | None:
    """Approximate corner pixels (K, 2) from a search of virtual views around the sphere, or None."""
    n = int(opts.tile_size_px)
    f = 0.5 * n / np.tan(np.deg2rad(0.5 * opts.tile_fov_deg))
    for d in _tile_directions(camera):
        view = VirtualView(look_rotation(camera, d), f, (n - 1) / 2, (n - 1) / 2, n, n)
        tile = render_view(view, camera, gray)
        if not cv2.checkChessboard(tile, (board.cols - 1, board.rows - 1)):
            continue  # OpenCV's fast test (milliseconds) before the slow detector
        for flags in _SB_TILES:
            c = _sb(tile, board, flags)
            if c is not None:
                return view_to_image(view, camera, c)
    return None


# ---------------------------------------------------------------------------- fine
def _refine_coarse(
    vgray: np.ndarray, xy0: np.ndarray, board: Board, max_sigma: float = 0.15
) -> np.ndarray | None:
    """The coarse corners (K, 2), moved into the fine view, refined there by cornerSubPix; or None.

    Saves the second detector run. Accepted only when every corner converged (cornerSubPix run
    twice agrees within 0.02 px) and the refined grid fits a board-plane homography with
    sigma <= ``max_sigma`` view px and no residual above 4 sigma_max; else the caller detects anew.
    """
    if not np.all(np.isfinite(xy0)):
        return None
    sq = _spacing(xy0, board)
    h, w = vgray.shape
    if np.any(xy0 < 2) or np.any(xy0[:, 0] > w - 3) or np.any(xy0[:, 1] > h - 3):
        return None
    xy1 = _subpix(vgray, xy0, sq)
    xy2 = _subpix(vgray, xy1, sq)
    if np.max(np.linalg.norm(xy2 - xy1, axis=1)) > 0.02:
        return None
    sigma, r = homography_sigma(board.corners_board()[:, :2], xy2)
    if sigma > max_sigma or np.max(np.abs(r)) > 4 * max_sigma:
        return None
    return xy2


def _subpix(gray: np.ndarray, xy: np.ndarray, square_px: float) -> np.ndarray:
    """Saddle-point refinement (cv2.cornerSubPix) in a window of ~0.35 square; no-op when square_px is 0."""
    if square_px <= 0:
        return xy
    half = int(max(2, min(15, round(0.35 * square_px))))
    pts = xy.astype(np.float32).reshape(-1, 1, 2).copy()
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    out = cv2.cornerSubPix(gray, pts, (half, half), (-1, -1), crit).reshape(-1, 2).astype(np.float64)
    moved = np.linalg.norm(out - xy, axis=1)
    return np.where((moved < 0.25 * square_px)[:, None], out, xy)


def _spacing(xy: np.ndarray, board: Board) -> float:
    """Largest distance (px) between neighbouring corners of a row-major grid (K, 2)."""
    g = xy.reshape(board.rows - 1, board.cols - 1, 2)
    d1 = np.linalg.norm(np.diff(g, axis=0), axis=-1).max()
    d2 = np.linalg.norm(np.diff(g, axis=1), axis=-1).max()
    return float(max(d1, d2))


def _fine(
    gray: np.ndarray, camera: CameraModel, board: Board, uv0: np.ndarray, opts: ImageOptions
) -> tuple[ImageCorners, dict[str, float]]:
    b0 = camera.bearing(uv0)
    if not np.all(np.isfinite(b0)):
        raise CornersNotFound("coarse corners map to no bearing")
    # one view at full angular resolution; pad so the outer squares and the margin fit
    probe = view_around(camera, b0, pad_px=0.0, scale=opts.view_scale, max_size=10**6)
    sq = _spacing(probe.to_view(b0), board)
    margin_sq = max(board.margin_long, board.margin_short) / board.square_size
    view = view_around(
        camera,
        b0,
        pad_px=(1.6 + min(margin_sq, 1.0)) * sq + 12.0,
        scale=opts.view_scale,
        max_size=int(opts.max_view_px),
    )
    vgray = render_view(view, camera, gray)
    xy, backend = None, 0.0
    if opts.reuse_coarse and opts.subpix and opts.backend == "auto":
        xy = _refine_coarse(vgray, view.to_view(b0), board)
        backend = 0.0 if xy is None else 2.0
    if xy is None and opts.backend in ("auto", "sb"):
        for flags in _SB_FINE:
            xy = _sb(vgray, board, flags)
            if xy is not None:
                break
    if xy is None and opts.backend in ("auto", "cbdetect"):
        xy, backend = _cbdetect(vgray, board), 1.0
    if xy is None:
        raise CornersNotFound(
            "board seen in the coarse search but its corners were not found in the fine view "
            "(blurred, occluded or cut by the image border?)"
        )
    if backend != 2.0:
        xy = _subpix(vgray, xy, _spacing(xy, board) if opts.subpix else 0.0)
    order = order_grid(xy, board, vgray, view.f, view.cx, view.cy, opts.strict_colour)
    xy = order.corners
    sigma, _ = homography_sigma(board.corners_board()[:, :2], xy)
    uv = view_to_image(view, camera, xy)
    if not np.all(np.isfinite(uv)) or not np.all(camera.in_image(uv)):
        raise CornersNotFound("some corners map outside the image")
    cov = image_covariance(sigma, view_jacobian(view, camera, xy), opts.floor_px)
    diag = {
        "sigma_view_px": sigma,
        "colour_score": order.colour_score,
        "view_f_px": view.f,
        "view_width_px": float(view.width),
        "view_height_px": float(view.height),
        "square_px": sq,
        "backend": backend,
    }
    corners = ImageCorners(
        uv=uv,
        bearings=camera.bearing(uv),
        cov_px=cov,
        half_turn_ambiguous=order.half_turn_ambiguous,
        diagnostics=diag,
    )
    return corners, diag


# --------------------------------------------------------------------------- entry
def detect_corners(
    image: np.ndarray, camera: CameraModel, board: Board, options: ImageOptions | None = None
) -> ImageCorners:
    """Inner chessboard corners of one image, in the board's canonical order.

    Parameters
    ----------
    image : (H, W, 3) BGR uint8 (or grey (H, W)), the size of ``camera``.
    camera : its camera model (any kind).
    board : the printed board.
    options : tuning, :class:`ImageOptions`.

    Returns
    -------
    ImageCorners with ``uv`` (K, 2) pixels, ``bearings`` (K, 3) camera frame, ``cov_px`` (K, 2, 2)
    px^2, corner k = i*(cols-1)+j at board ((j+1)s, (i+1)s, 0); ``half_turn_ambiguous`` when the
    board is half-turn symmetric (the order is then right up to ``board.half_turn_permutation``).

    Raises
    ------
    ValueError : ``image`` is not an image of the camera's size.
    CornersNotFound : no chessboard of this size in the image.
    """
    opts = ImageOptions() if options is None else options
    if min(board.inner_shape) < 2 or board.n_corners < 6:
        raise ValueError(f"detect_corners: a {board.rows}x{board.cols}-square board is too small to detect")
    t0 = time.perf_counter()
    gray = to_gray(image, camera)
    uv0 = _coarse_downscaled(gray, camera, board, int(opts.coarse_width))
    stage = 0.0
    if uv0 is None and opts.tile_views:
        uv0 = _coarse_tiles(gray, camera, board, opts)
        stage = 1.0
    if uv0 is None:
        raise CornersNotFound(
            f"no {board.rows}x{board.cols}-square chessboard "
            f"({board.rows - 1}x{board.cols - 1} inner corners) found in the image"
        )
    t1 = time.perf_counter()
    corners, diag = _fine(gray, camera, board, uv0, opts)
    diag.update(coarse_stage=stage, time_coarse_s=t1 - t0, time_s=time.perf_counter() - t0)
    return corners
