"""The per-frame stages on one frame of a source, and a frame file that cannot be read.

``observe_lidar`` / ``observe_image`` run the LiDAR and image stages on one frame (the source reads
the files); ``observe_frame`` both. A scan or image whose read raises ``InputError`` (truncated PCD,
undecodable PNG, a .bin of the wrong length, ...) or an image of another size than the camera's
becomes a ``DamagedFile``: the frame is skipped with the file and the problem as its reason; with
``StageOptions.strict`` the ``InputError`` stops the run instead. The functions take plain,
picklable arguments (they run on the worker processes, ``workers.py``).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.config import Config, Roi
from ilcc_graph.datasets import FrameRef, FrameSource
from ilcc_graph.errors import DamagedFile, FrameError, InputError
from ilcc_graph.evaluation.pattern_check import KEYS as PATTERN_KEYS
from ilcc_graph.evaluation.pattern_check import pattern_continues
from ilcc_graph.image import ImageOptions, detect_corners
from ilcc_graph.image.previews import make_views
from ilcc_graph.io.result_store import MISSING, load_result, result_key, store_result
from ilcc_graph.lidar import INTENSITY_UNUSABLE, LidarOptions, estimate_board
from ilcc_graph.lidar.margin import margin_summary, margin_words
from ilcc_graph.lidars import LidarModel
from ilcc_graph.types import BoardFit, ExpectedBoard, FrameResult, ImageCorners, RangeCorrection, Scan

__all__ = [
    "StageOptions",
    "attempt",
    "check_image",
    "frame_result",
    "kept",
    "lidar_stage",
    "observe_frame",
    "observe_image",
    "observe_lidar",
    "read_frame_file",
    "size_problem",
    "warn_margin",
    "warn_no_print",
]

log = logging.getLogger(__name__)

T = TypeVar("T")


@dataclass(frozen=True)
class StageOptions:
    """The per-frame stages' options and the number of processes they run on.

    strict: a frame file that cannot be read stops the run (``InputError``) instead of costing
    that frame (``DamagedFile``). cache: a folder (``io.result_store.open_store``) where each stage's
    result on a scan or image is kept and found again when the same data is observed with the same
    settings by the same program (``kept``), or None.
    """

    lidar: LidarOptions = LidarOptions()
    image: ImageOptions = ImageOptions()
    jobs: int = 1
    strict: bool = False
    cache: Path | None = None


def kept(options: StageOptions, stage: str, fn: Callable[..., T], *args: object) -> T:
    """``fn(*args)``, a stage's computation on data in memory; with ``options.cache`` its result (or
    the ``FrameError`` it raised, raised again) as kept there by an earlier call on equal arguments,
    else computed and kept (``io.result_store``)."""
    if options.cache is None:
        return fn(*args)
    key = result_key(stage, args)
    hit = load_result(options.cache, key)
    if isinstance(hit, FrameError):
        raise hit
    if hit is not MISSING:
        return hit  # type: ignore[return-value]
    try:
        value = fn(*args)
    except FrameError as err:
        store_result(options.cache, key, err)
        raise
    store_result(options.cache, key, value)
    return value


def read_frame_file(fn: Callable[..., Any], *args: object, strict: bool = False) -> Any:
    """``fn(*args)``, a source's read; its InputError (the file and the problem) becomes a DamagedFile
    that costs the frame, or stays an InputError that stops the run with ``strict``."""
    try:
        return fn(*args)
    except InputError as err:
        if strict:
            raise
        raise DamagedFile(f"damaged file: {err}") from None


def size_problem(size: tuple[int, int], config: Config, where: str) -> str | None:
    """Why an image of ``size`` (width, height) px cannot be of the config's camera, or None."""
    w, h = size
    cam = config.camera
    if (w, h) == (cam.width, cam.height):
        return None
    hint = ""
    if w * cam.height == h * cam.width and cam.intrinsic_names:
        hint = (
            f"; the images look scaled by {w / cam.width:g} from the size the intrinsics are for: "
            "scale fx, fy, cx, cy with width and height"
        )
    return (
        f"{where}: image is {w}x{h} px, but the camera in {config.source} is {cam.width}x{cam.height} "
        f"(camera.width x camera.height; ILCC's image_res){hint}"
    )


def check_image(
    image: np.ndarray | tuple[int, int], config: Config, where: str, strict: bool = False
) -> None:
    """DamagedFile (InputError with ``strict``) when the image, or an image of size (width, height)
    read from its header, has not the camera's size."""
    size = image if isinstance(image, tuple) else (image.shape[1], image.shape[0])
    problem = size_problem(size, config, where)
    if problem is None:
        return
    if strict:
        raise InputError(problem)
    raise DamagedFile(f"damaged file: {problem}")


def attempt(fn: Callable, *args: object) -> object:
    """``fn(*args)``, or the FrameError it raised."""
    try:
        return fn(*args)
    except FrameError as err:
        return err


def observe_lidar(
    source: FrameSource,
    ref: FrameRef,
    config: Config,
    options: StageOptions,
    expected: ExpectedBoard | None = None,
    correction: RangeCorrection | None = None,
) -> BoardFit:
    """The LiDAR stage on one frame's scan (near ``expected`` when given, on the ranges corrected by
    ``correction`` when given); FrameError says why not."""
    scan = read_frame_file(source.read_scan, ref, config, strict=options.strict)
    return lidar_stage(options, scan, config.board, config.lidar, config.roi, expected, correction)


def lidar_stage(
    options: StageOptions,
    scan: Scan,
    board: Board,
    lidar: LidarModel | None,
    roi: Roi | None,
    expected: ExpectedBoard | None = None,
    correction: RangeCorrection | None = None,
) -> BoardFit:
    """The LiDAR stage on a scan in memory (``lidar.estimate_board`` with ``options.lidar``), its result
    kept in ``options.cache`` (``kept``): one key for a pair's frame and a rig's LiDAR alike."""
    args = (scan, board, lidar, roi, options.lidar, expected, correction)
    return kept(options, "lidar", estimate_board, *args)


def observe_image(
    source: FrameSource, ref: FrameRef, config: Config, options: StageOptions, views: bool = True
) -> ImageCorners:
    """The image stage on one frame's image, with (``views``) the report's views of it
    (``image.previews``); raises FrameError with the reason (DamagedFile when the image cannot be
    read or has not the camera's size: judged from the file's header before decoding where the
    source can, so a forged size costs nothing)."""
    where, strict = source.image_location(ref), options.strict
    size = read_frame_file(source.header_size, ref, strict=strict)
    if size is not None:
        check_image(size, config, where, strict)
    image = read_frame_file(source.read_image, ref, strict=strict)
    check_image(image, config, where, strict)
    return kept(options, "image", _image_stage, image, config.camera, config.board, options.image, views)


def _image_stage(
    image: np.ndarray, camera: CameraModel, board: Board, options: ImageOptions, views: bool
) -> ImageCorners:
    """The corners, whether the pattern goes on beyond them (for ``setup_mistakes``) and, with
    ``views``, the report's views of the image."""
    corners = detect_corners(image, camera, board, options)
    extra = dict(zip(PATTERN_KEYS, pattern_continues(image, board, camera, corners)))
    shown = make_views(image, corners.uv, camera) if views else corners.views
    return dataclasses.replace(corners, diagnostics={**corners.diagnostics, **extra}, views=shown)


def observe_frame(
    source: FrameSource,
    ref: FrameRef,
    config: Config,
    options: StageOptions = StageOptions(),
    image: object = None,
) -> FrameResult:
    """Both stages on one frame (``image``: the image stage's result when already known)."""
    board = attempt(observe_lidar, source, ref, config, options)
    corners = image if image is not None else attempt(observe_image, source, ref, config, options)
    return frame_result(ref.name, board, corners)


def frame_result(name: str, board: object, corners: object) -> FrameResult:
    """A frame's stage results (each a result or its ``FrameError``) as the observation records them:
    unused with both reasons when a stage failed, ``damaged`` when a file could not be read."""
    reasons = [
        f"{what}: {r}" for what, r in (("LiDAR", board), ("image", corners)) if isinstance(r, FrameError)
    ]
    return FrameResult(
        name=name,
        used=not reasons,
        reason="; ".join(reasons) or None,
        board=None if isinstance(board, FrameError) else board,  # type: ignore[arg-type]
        corners=None if isinstance(corners, FrameError) else corners,  # type: ignore[arg-type]
        damaged=any(isinstance(r, DamagedFile) for r in (board, corners)),
    )


def warn_no_print(boards: Sequence[BoardFit], where: str) -> str | None:
    """One warning for the whole run (``where``: the config file, and the LiDAR of a rig) when of the
    ``boards`` found some show no print in the LiDAR's intensity (their in-plane pose from the board's
    outline), saying why; returns it (None when every board shows it)."""
    plain = [b for b in boards if b.diagnostics.get("no_contrast")]
    if not plain:
        return None
    codes = sorted({b.diagnostics.get("intensity_unusable", 0.0) for b in plain} - {0.0})
    why = "; ".join(INTENSITY_UNUSABLE.get(c, "") for c in codes) or "no black/white contrast on the board"
    if unreadable := sum(1 for b in plain if b.diagnostics.get("print_unreadable")):
        unread = f"in {unreadable} a print shows, but too few returns lie clear of its squares' edges to read"
        why = unread if unreadable == len(plain) else f"{why}; {unread}"
    if codes:
        why += "; for CSV scans check lidar.intensity_column"
    msg = (
        f"{where}: {len(plain)} of {len(boards)} boards show no print in the LiDAR intensity "
        f"({why}); their position in their plane comes from the board's outline (its size and margin as "
        "configured)"
    )
    log.warning("%s", msg)
    return msg


def warn_margin(
    boards: Sequence[BoardFit], board: Board, where: str, file: str = "config.yaml"
) -> str | None:
    """One warning for the whole run (``where``: the config file, and the LiDAR of a rig) when the
    ``boards`` found whose print the LiDAR shows contradict the configured ``board``'s margin
    (``lidar.margin``: measured from their outlines), with the measured one to set in ``file``;
    returns it (None when they agree or cannot tell)."""
    summary = margin_summary([b.diagnostics for b in boards], board)
    if not summary:
        return None
    msg = f"{where}: {margin_words(summary, file)}"
    log.warning("%s", msg)
    return msg
