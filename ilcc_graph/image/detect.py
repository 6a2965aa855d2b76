"""Chessboard inner corners in panoramic, fisheye and pinhole images (stage 3).

Two passes (docs/image_stage.md):

0. **cheap**: a few cheap attempts first (``ImageOptions.quick``: OpenCV's classic detector, gated
   by its fast check, on a copy about 1000 columns wide; the SB detector on one about 1500 wide);
   the board they find goes to the fine pass below like any other, which refines every corner at
   the source's full resolution and measures their noise there, so a cheap find costs no accuracy.
   Only when they find nothing that passes the fine pass does the search go on:
1. **coarse**: a cascade of detector attempts (``detectors.py``: OpenCV's SB and classic
   detectors, Geiger's libcbdetect, on the image and on contrast variants of it) on a copy of the
   image downscaled to about ``ImageOptions.coarse_width`` columns; a panorama is also tried
   rolled by half its width, so a board straddling the seam is found whole. When that fails, a
   ring of virtual pinhole views (``views.py``) covering the camera's field of view is searched
   the same way. Every grid must be a sane grid (``detectors.grid_problem``) whose bearings fit a
   board-plane homography in a virtual pinhole view.
2. **fine**: the neighbourhood of the coarse grid is resampled into a virtual pinhole view at the
   source's full angular resolution (undistorted, seam-free); the coarse corners (or, when they do
   not converge, the cascade run again in the view) seed one common refinement there
   (``cv2.cornerSubPix``), the grid is put in canonical order (``ordering.py``), its noise
   measured (``uncertainty.py``), and the corners are mapped back to image pixels and bearings
   through ``camera.project``. A coarse grid that fails the fine pass does not end the search:
   the next coarse candidate is tried. A refined grid that is not provably the whole printed
   pattern (``whole.py``: a part of a larger print, or a board leaving the picture) ends it with
   ``PartialPattern``: its corners' indices cannot be told.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from ..board import Board
from ..cameras import CameraModel
from ..errors import BLANK_IMAGE, BoardColourMismatch, CornersNotFound, PartialPattern
from ..types import ImageCorners
from .coarse import Candidate, downscaled_candidates, tile_candidates
from .detectors import ContrastCache, check_attempts, grid_problem, grid_spacing, run_attempt
from .ordering import Ordering, order_grid
from .uncertainty import homography_sigma, image_covariance
from .views import (
    VirtualView,
    render_view,
    view_around,
    view_jacobian,
    view_to_image,
)
from .whole import WholeCheck, check_whole_pattern

_SNAP_PX = 2.0  # lattice of the final fine view (view px), see _fine

DEFAULT_CASCADE = ("sb", "cbdetect", "classic", "sb+gamma", "cbdetect+gamma")
#: the cheap search (issue 37): (attempt, width px) tried in turn before the coarse search, unrolled
DEFAULT_QUICK = (("classic", 1000), ("sb", 1500))


@dataclass(frozen=True)
class ImageOptions:
    """Tuning of :func:`detect_corners`.

    quick: the cheap search, ``(attempt, width)`` pairs tried in turn on the image downscaled to
        ``width`` columns (never upscaled; a panorama not rolled) before the coarse search; each
        find is refined at full resolution by the fine pass; () searches as before issue 37.
    coarse_width: width (px) of the downscaled copy the coarse cascade searches.
    view_scale: focal length of the fine view relative to the source's angular resolution there.
    max_view_px: largest side of the fine view (px); a nearer board gets a coarser view.
    tile_views: search a ring of virtual views when the downscaled image shows no board.
    tile_size_px: side of each search view (px); tile_fov_deg: its field of view.
    floor_px: lower bound of the corner sigma in image pixels (covariance eigenvalue floor^2).
    cascade: detector attempts ``"<detector>[+<contrast>]"`` tried in turn, in the coarse search
        and in the fine view (``detectors.DETECTORS``, ``detectors.CONTRASTS``); the result's
        ``detector`` names the one whose corners seeded the final refinement.
    subpix: refine the corners in the fine view with ``cv2.cornerSubPix`` (the common refinement;
        off only for experiments).
    reuse_coarse: seed the fine view's refinement with the coarse corners; the cascade runs again
        in the view only when they do not converge to a grid that passes the checks.
    max_sigma_view_px: largest accepted homography-residual sigma of the refined grid (view px);
        a larger one means some corner converged off the board's saddle point.
    strict_colour: raise ``CornersNotFound`` when the print's corner colour contradicts
        ``board.lower_left`` (a misconfigured even x even board); False keeps the geometric
        order (z towards the camera), flags it half-turn ambiguous and reports ``colour_score`` < 0.
    """

    quick: tuple[tuple[str, int], ...] = DEFAULT_QUICK
    coarse_width: int = 2000
    view_scale: float = 1.0
    max_view_px: int = 3000
    tile_views: bool = True
    tile_size_px: int = 640
    tile_fov_deg: float = 90.0
    floor_px: float = 0.05
    cascade: tuple[str, ...] = DEFAULT_CASCADE
    subpix: bool = True
    reuse_coarse: bool = True
    max_sigma_view_px: float = 0.5
    strict_colour: bool = True

    def __post_init__(self) -> None:
        if int(self.coarse_width) < 200:
            raise ValueError(f"ImageOptions: coarse_width must be >= 200 px, got {self.coarse_width!r}")
        if not (0.25 <= float(self.view_scale) <= 4.0):
            raise ValueError(f"ImageOptions: view_scale must be in [0.25, 4], got {self.view_scale!r}")
        if int(self.max_view_px) < 200 or int(self.tile_size_px) < 200:
            raise ValueError("ImageOptions: max_view_px and tile_size_px must be >= 200 px")
        if not (20.0 <= float(self.tile_fov_deg) < 170.0):
            raise ValueError(f"ImageOptions: tile_fov_deg must be in [20, 170), got {self.tile_fov_deg!r}")
        given: object = self.cascade  # what a caller passed, which the field's type does not promise
        if isinstance(given, str):
            raise ValueError(
                f"ImageOptions: cascade must be a tuple of names, got the string {self.cascade!r}"
            )
        check_attempts(tuple(self.cascade))
        quick: object = self.quick  # as passed, likewise
        pairs: tuple[object, ...] = () if isinstance(quick, str) else tuple(self.quick)
        if isinstance(quick, str) or not all(
            isinstance(q, tuple) and len(q) == 2 and int(q[1]) >= 200 for q in pairs
        ):
            raise ValueError(
                f"ImageOptions: quick must be (attempt, width >= 200 px) pairs, got {self.quick!r}"
            )
        if self.quick:
            check_attempts(tuple(q[0] for q in self.quick))
        if not (np.isfinite(self.floor_px) and self.floor_px >= 0):
            raise ValueError(f"ImageOptions: floor_px must be finite and >= 0, got {self.floor_px!r}")
        if not (np.isfinite(self.max_sigma_view_px) and self.max_sigma_view_px > 0):
            raise ValueError(f"ImageOptions: max_sigma_view_px must be > 0, got {self.max_sigma_view_px!r}")


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


# ---------------------------------------------------------------------------- fine
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


def _refine(
    vgray: np.ndarray, xy0: np.ndarray, board: Board, opts: ImageOptions
) -> tuple[np.ndarray | None, str]:
    """The common refinement of seed corners (K, 2) in the fine view, checked; (corners, "") or (None, why).

    cornerSubPix (window 0.35 square) runs twice; accepted when the second run moves no corner by
    more than 0.02 px, the grid is sane, inside the view, and fits a board-plane homography with
    sigma <= ``max_sigma_view_px`` and no residual above 4 times that.
    """
    h, w = vgray.shape
    if (
        not np.all(np.isfinite(xy0))
        or np.any(xy0 < 2)
        or np.any(xy0[:, 0] > w - 3)
        or np.any(xy0[:, 1] > h - 3)
    ):
        return None, "corners at the view's border"
    xy = xy0
    if opts.subpix:
        sq = grid_spacing(xy0, board)
        xy1 = _subpix(vgray, xy0, sq)
        xy = _subpix(vgray, xy1, sq)
        if np.max(np.linalg.norm(xy - xy1, axis=1)) > 0.02:
            return None, "corner refinement did not converge"
    why = grid_problem(xy, board)
    if why is not None:
        return None, why
    sigma, r = homography_sigma(board.corners_board()[:, :2], xy)
    lim = float(opts.max_sigma_view_px)
    if sigma > lim or np.max(np.abs(r)) > 4 * lim:
        return None, f"refined corners do not fit a plane (sigma {sigma:.2f} px)"
    return xy, ""


def _fine_view(
    camera: CameraModel, b: np.ndarray, board: Board, opts: ImageOptions, snap_px: float = 0.0
) -> tuple[VirtualView, float]:
    """(view, square_px): a virtual pinhole at full angular resolution around the bearings ``b`` (K, 3),
    padded so that the outer squares and the margin fit; square_px is the grid's spacing there."""
    probe = view_around(camera, b, pad_px=0.0, scale=opts.view_scale, max_size=10**6)
    sq = grid_spacing(probe.to_view(b), board)
    margin_sq = max(board.margin_long, board.margin_short) / board.square_size
    view = view_around(
        camera,
        b,
        pad_px=(1.6 + min(margin_sq, 1.0)) * sq + 12.0,
        scale=opts.view_scale,
        max_size=int(opts.max_view_px),
        snap_px=snap_px,
    )
    return view, sq


def _order_whole(
    gray: np.ndarray,
    camera: CameraModel,
    view: VirtualView,
    vgray: np.ndarray,
    xy: np.ndarray,
    board: Board,
    opts: ImageOptions,
) -> tuple[Ordering, WholeCheck]:
    """The refined grid xy (K, 2; view px) in canonical order, checked to be the whole pattern.

    Raises PartialPattern when it is not (``whole.py``), also when the colours fail too but the
    pattern is seen to go on beyond the grid (a part of a larger print shifted by a square has
    the other colours), else what ``order_grid`` raises (a false grid: the search goes on).
    """
    whole = check_whole_pattern(gray, camera, view, xy, board)
    try:
        order = order_grid(xy, board, vgray, view.f, view.cx, view.cy, opts.strict_colour)
    except CornersNotFound:
        if whole.continues:
            raise PartialPattern(whole.reason) from None
        raise
    if whole.reason is not None:
        raise PartialPattern(whole.reason)
    return order, whole


def _fine(
    gray: np.ndarray, camera: CameraModel, board: Board, cand: Candidate, opts: ImageOptions
) -> ImageCorners:
    b0 = camera.bearing(cand.uv)
    view, sq = _fine_view(camera, b0, board, opts)
    vgray = render_view(view, camera, gray)
    xy, detector, redetected, why = None, cand.attempt, 0.0, []
    if opts.reuse_coarse:
        xy, reason = _refine(vgray, view.to_view(b0), board, opts)
        why.append(reason)
    if xy is None:
        images = ContrastCache(vgray)
        for name in opts.cascade:
            seed = run_attempt(name, images, board)
            if seed is None:
                continue
            xy, reason = _refine(vgray, seed, board, opts)
            why.append(reason)
            if xy is not None:
                detector, redetected = name, 1.0
                break
    if xy is None:
        reasons = "; ".join(sorted({w for w in why if w})) or "no detector found the grid there"
        raise CornersNotFound(
            f"board seen in the coarse search ({cand.attempt}) but its corners were not found in the "
            f"fine view: {reasons} (blurred, occluded or cut by the image border?)"
        )
    # the view was placed by the seed; place it again by the refined corners and refine there, so
    # that the result (resampling included) no longer depends on which detector seeded it
    b1 = view.rays(xy)
    view1, sq = _fine_view(camera, b1, board, opts, snap_px=_SNAP_PX)
    vgray1 = render_view(view1, camera, gray)
    xy1, _ = _refine(vgray1, view1.to_view(b1), board, opts)
    if xy1 is not None:
        view, vgray, xy = view1, vgray1, xy1
    order, whole = _order_whole(gray, camera, view, vgray, xy, board, opts)
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
        "coarse_stage": float(cand.stage),
        "coarse_width_px": float(cand.width),
        "fine_redetected": redetected,
        "alternating_beyond": whole.alternating_beyond,
        "border_matching": whole.border_matching,
    }
    return ImageCorners(
        uv=uv,
        bearings=camera.bearing(uv),
        cov_px=cov,
        half_turn_ambiguous=order.half_turn_ambiguous,
        diagnostics=diag,
        detector=detector,
    )


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
    board is half-turn symmetric (the order is then right up to ``board.half_turn_permutation``);
    ``detector`` the attempt (``detector[+contrast]``) whose corners seeded the refinement.

    Raises
    ------
    ValueError : ``image`` is not an image of the camera's size.
    CornersNotFound : no chessboard of this size in the image (``BoardColourMismatch`` when the
        print's colours contradict ``board.lower_left``; ``PartialPattern`` when the grid found is
        not provably the whole pattern; ``errors.BLANK_IMAGE`` when every pixel has one grey level:
        a covered lens, a driver's placeholder frame; said at once, not searched).
    """
    opts = ImageOptions() if options is None else options
    if min(board.inner_shape) < 2 or board.n_corners < 6:
        raise ValueError(f"detect_corners: a {board.rows}x{board.cols}-square board is too small to detect")
    t0 = time.perf_counter()
    gray = to_gray(image, camera)
    lo, hi = cv2.minMaxLoc(gray)[:2]
    if lo == hi:
        raise CornersNotFound(f"{BLANK_IMAGE} (every pixel grey level {lo:.0f}): the camera gave no picture")
    cascade = tuple(opts.cascade)
    plan = [(name, int(w), False) for name, w in opts.quick]
    plan += [(name, int(opts.coarse_width), True) for name in cascade]
    candidates: Iterator[Candidate] = downscaled_candidates(gray, camera, board, plan)
    if opts.tile_views:
        tiles = tile_candidates(
            gray, camera, board, cascade, int(opts.tile_size_px), float(opts.tile_fov_deg)
        )
        candidates = itertools.chain(candidates, tiles)
    first_error: CornersNotFound | None = None
    for cand in candidates:
        t1 = time.perf_counter()
        try:
            res = _fine(gray, camera, board, cand, opts)
        except (BoardColourMismatch, PartialPattern):
            raise  # a clean grid whose colours or extent say the configuration or the view is wrong
        except CornersNotFound as exc:  # a false or unusable grid: the next candidate may be the board
            first_error = first_error or exc
            continue
        res.diagnostics.update(time_coarse_s=t1 - t0, time_s=time.perf_counter() - t0)
        return res
    if first_error is not None:
        raise first_error
    raise CornersNotFound(
        f"no {board.rows}x{board.cols}-square chessboard "
        f"({board.rows - 1}x{board.cols - 1} inner corners) found in the image"
    )
