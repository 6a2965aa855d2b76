"""The per-frame stages over a frame source: the LiDAR and image stages, the print-colour check.

``observe`` runs both stages on every frame of a source (a ``FrameError`` skips the frame with its
reason; a frame file that cannot be read is a ``DamagedFile``, which skips the frame too unless
``StageOptions.strict``; other ``InputError`` propagate), on ``StageOptions.jobs`` processes
(``workers.py``), after checking the images' size and the print's colour on the first images (their
image results are kept, not computed twice). The worker functions take plain, picklable arguments.
Only the source reads files.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ilcc_graph import signals, workers
from ilcc_graph.config import Config
from ilcc_graph.damage import check_image, check_image_size, read_frame_file, warn_damaged
from ilcc_graph.datasets import FrameRef, FrameSource
from ilcc_graph.errors import BoardColourMismatch, DamagedFile, FrameError, InputError
from ilcc_graph.image import ImageOptions, detect_corners
from ilcc_graph.image.previews import make_views
from ilcc_graph.init import upnp
from ilcc_graph.lidar import INTENSITY_UNUSABLE, LidarOptions, estimate_board
from ilcc_graph.lidars import choose_model, measure_beams
from ilcc_graph.pattern_check import KEYS as PATTERN_KEYS
from ilcc_graph.pattern_check import pattern_continues
from ilcc_graph.types import BoardFit, Calibration, ExpectedBoard, FrameResult, ImageCorners

log = logging.getLogger(__name__)

__all__ = [
    "Observation",
    "StageOptions",
    "check_board_colour",
    "look_again",
    "observe",
    "observe_frame",
    "observe_image",
    "observe_lidar",
    "resolve_lidar",
    "run_image_stage",
    "run_lidar_stage",
    "second_pass",
    "stage_alone",
    "warn_no_print",
]

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class StageOptions:
    """The per-frame stages' options and the number of processes they run on.

    strict: a frame file that cannot be read stops the run (``InputError``) instead of costing
    that frame (``DamagedFile``).
    """

    lidar: LidarOptions = LidarOptions()
    image: ImageOptions = ImageOptions()
    jobs: int = 1
    strict: bool = False


@dataclass(frozen=True)
class Observation:
    """A source observed: the config used (print colour checked) and every frame's stage results
    (frames without a partner come last, unused, with the reason)."""

    source: FrameSource
    config: Config
    frames: list[FrameResult]


def observe_lidar(
    source: FrameSource,
    ref: FrameRef,
    config: Config,
    options: LidarOptions,
    expected: ExpectedBoard | None = None,
    strict: bool = False,
) -> BoardFit:
    """The LiDAR stage on one frame's scan (near ``expected`` when given); FrameError says why not."""
    scan = read_frame_file(source.read_scan, ref, config, strict=strict)
    return estimate_board(scan, config.board, config.lidar, config.roi, options, expected)  # type: ignore[arg-type]


def observe_image(
    source: FrameSource,
    ref: FrameRef,
    config: Config,
    options: ImageOptions,
    strict: bool = False,
    views: bool = True,
) -> ImageCorners:
    """The image stage on one frame's image, with (``views``) the report's views of it
    (``image.previews``); raises FrameError with the reason (DamagedFile when the image cannot be
    read or has not the camera's size: judged from the file's header before decoding where the
    source can, so a forged size costs nothing)."""
    size = read_frame_file(source.header_size, ref, strict=strict)
    if size is not None:
        check_image(size, config, str(ref.image), strict)
    image = read_frame_file(source.read_image, ref, strict=strict)
    check_image(image, config, str(ref.image), strict)
    corners = detect_corners(image, config.camera, config.board, options)  # type: ignore[arg-type]
    extra = dict(zip(PATTERN_KEYS, pattern_continues(image, config, corners)))  # for setup_mistakes
    kept = make_views(image, corners.uv, config.camera) if views else corners.views
    return dataclasses.replace(corners, diagnostics={**corners.diagnostics, **extra}, views=kept)


def _attempt(fn: Callable, *args: object) -> object:
    try:
        return fn(*args)
    except FrameError as err:
        return err


def observe_frame(
    source: FrameSource,
    ref: FrameRef,
    config: Config,
    options: StageOptions = StageOptions(),
    image: object = None,
) -> FrameResult:
    """Both stages on one frame (``image``: the image stage's result when already known)."""
    board = _attempt(observe_lidar, source, ref, config, options.lidar, None, options.strict)
    corners = (
        image
        if image is not None
        else _attempt(observe_image, source, ref, config, options.image, options.strict)
    )
    reasons = [
        f"{what}: {r}" for what, r in (("LiDAR", board), ("image", corners)) if isinstance(r, FrameError)
    ]
    return FrameResult(
        name=ref.name,
        used=not reasons,
        reason="; ".join(reasons) or None,
        board=None if isinstance(board, FrameError) else board,  # type: ignore[arg-type]
        corners=None if isinstance(corners, FrameError) else corners,  # type: ignore[arg-type]
        damaged=any(isinstance(r, DamagedFile) for r in (board, corners)),
    )


def _map(fn: Callable, items: Sequence[tuple], jobs: int, progress: Progress | None) -> list:
    """``fn(*item)`` over ``items``, in order, on ``jobs`` processes (``workers.map_processes``)."""
    return workers.map_processes(fn, items, jobs, progress)


def resolve_lidar(source: FrameSource, refs: Sequence[FrameRef], config: Config, look: int = 3) -> Config:
    """The config with the beam table the scans show, warning once when it contradicts the config's.

    The first readable scan of the first ``look`` frames is measured (``lidars.measure_beams``:
    ring field, organised rows or elevation clusters) and checked against ``config.lidar`` (a named
    model or a calibration file); the measured table is used where they differ. With no model in
    the config the measured one is used silently. An unreadable scan is left to the LiDAR stage.
    """
    for ref in refs[:look]:
        if ref.scan is None:
            continue
        try:
            scan = source.read_scan(ref, config)
        except InputError:
            continue
        model, warning = choose_model(measure_beams(scan), config.lidar, scan.source or ref.name)
        if warning:
            log.warning("%s", warning)
        return dataclasses.replace(config, lidar=model)
    return config


def check_board_colour(
    source: FrameSource,
    refs: Sequence[FrameRef],
    config: Config,
    options: ImageOptions = ImageOptions(),
    needed: int = 2,
    look: int = 6,
    strict: bool = False,
) -> tuple[Config, dict[str, object]]:
    """The config with ``board.lower_left`` as the images show it, and the image results computed.

    For a board that looks the same after a half turn (even squares on both sides) the colour of the
    lower-left square seen from the front is a property of the print, which the user may have
    mistyped. The image stage tells it with certainty; this looks at up to ``look`` frames until
    ``needed`` agree and turns the setting (with a warning) when the images contradict it. Returns
    the image stage's results (ImageCorners or FrameError) of the frames looked at when they hold
    for the config returned, so that they need not be computed again.
    """
    board = config.board
    if not board.half_turn_symmetric:
        return config, {}
    agree = disagree = 0
    seen: dict[str, object] = {}
    for ref in refs[:look]:
        if ref.image is None:
            continue
        res = _attempt(observe_image, source, ref, config, options, strict)
        seen[ref.name] = res
        if isinstance(res, BoardColourMismatch):
            disagree += 1
        elif not isinstance(res, FrameError):
            agree += 1
        if max(agree, disagree) >= needed:
            break
    if disagree <= agree:
        return config, seen
    other = "white" if board.lower_left == "black" else "black"
    log.warning(
        "%s: board.lower_left is %s, but the print's lower-left square (seen from the front, long side "
        "horizontal) is %s in %d of %d images checked; using %s",
        config.source,
        board.lower_left,
        other,
        disagree,
        agree + disagree,
        other,
    )
    return dataclasses.replace(config, board=dataclasses.replace(board, lower_left=other)), {}


def _colour_verdict(
    frames: Sequence[FrameResult], errors: dict[str, object], needed: int = 2, look: int = 6
) -> bool:
    """Whether the images contradict ``board.lower_left``: as ``check_board_colour`` decides, from the
    image stage's results of the first ``look`` frames (until ``needed`` agree either way)."""
    agree = disagree = 0
    for f in frames[:look]:
        err = errors.get(f.name)
        if isinstance(err, BoardColourMismatch):
            disagree += 1
        elif f.corners is not None:
            agree += 1
        if max(agree, disagree) >= needed:
            break
    return disagree > agree


def _observe_frame_errors(source: FrameSource, ref: FrameRef, config: Config, options: StageOptions,
                          image: object = None) -> tuple[FrameResult, object]:  # fmt: skip
    """``observe_frame`` and the image stage's error (or None), for the colour verdict."""
    res = image
    if res is None:
        res = _attempt(observe_image, source, ref, config, options.image, options.strict)
    fr = observe_frame(source, ref, config, options, res)
    return fr, res if isinstance(res, FrameError) else None


def observe(
    source: FrameSource, options: StageOptions = StageOptions(), progress: Progress | None = None
) -> Observation:
    """Read a source's config, list its frames, check the images' size, run both stages per frame
    (damaged frames skipped with a warning, or InputError with ``strict``), check the print's colour.

    The colour check judges the first frames' image results as they come from the run over every
    frame, so no frame waits for it; when the images contradict the config's ``board.lower_left``,
    the stages run again on every frame with the other colour.
    """
    if options.jobs > 1:
        workers.prestart()  # the fork server imports the stages while this process checks the config
    config = source.config()  # the config's mistakes first, then the folders'
    refs = source.frames()
    config = resolve_lidar(source, refs, config)
    check_image_size(source, refs, config)
    signals.check()
    items = [(source, r, config, options) for r in refs]
    done = _map(_observe_frame_errors, items, options.jobs, progress)
    frames = [fr for fr, _ in done]
    if config.board.half_turn_symmetric and _colour_verdict(frames, {fr.name: e for fr, e in done}):
        board = config.board
        other = "white" if board.lower_left == "black" else "black"
        log.warning(
            "%s: board.lower_left is %s, but the print's lower-left square (seen from the front, long "
            "side horizontal) is %s in the images checked; using %s", config.source, board.lower_left, other,
            other,
        )  # fmt: skip
        config = dataclasses.replace(config, board=dataclasses.replace(board, lower_left=other))
        frames = _map(observe_frame, [(source, r, config, options) for r in refs], options.jobs, progress)
    warn_damaged(frames)
    warn_no_print(frames, config)
    frames += [FrameResult(name=n, used=False, reason=why) for n, why in source.skipped()]
    return Observation(source, config, frames)


def warn_no_print(frames: Sequence[FrameResult], config: Config) -> str | None:
    """One warning for the whole run when boards were found without a print the LiDAR shows (their
    in-plane pose from the board's outline), saying why; returns it (None when every board shows it)."""
    boards = [f.board for f in frames if f.board is not None]
    plain = [b for b in boards if b.diagnostics.get("no_contrast")]
    if not plain:
        return None
    codes = sorted({b.diagnostics.get("intensity_unusable", 0.0) for b in plain} - {0.0})
    why = "; ".join(INTENSITY_UNUSABLE.get(c, "") for c in codes) or "no black/white contrast on the board"
    if codes:
        why += "; for CSV scans check lidar.intensity_column"
    msg = (
        f"{config.source}: {len(plain)} of {len(boards)} boards show no print in the LiDAR intensity "
        f"({why}); their position in their plane comes from the board's outline (its size and margin as "
        "configured)"
    )
    log.warning("%s", msg)
    return msg


def _stage(fn: Callable, source: FrameSource, ref: FrameRef, config: Config, opts: object,
           strict: bool = False) -> object:  # fmt: skip
    if fn is observe_lidar:
        return _attempt(fn, source, ref, config, opts, None, strict)
    return _attempt(fn, source, ref, config, opts, strict)


def run_lidar_stage(
    source: FrameSource,
    refs: Sequence[FrameRef],
    config: Config,
    options: StageOptions,
    progress: Progress | None = None,
) -> list[BoardFit | FrameError]:
    """The LiDAR stage alone: a BoardFit or the FrameError per frame."""
    items = [(observe_lidar, source, r, config, options.lidar, options.strict) for r in refs]
    return _map(_stage, items, options.jobs, progress)


def run_image_stage(
    source: FrameSource,
    refs: Sequence[FrameRef],
    config: Config,
    options: StageOptions,
    progress: Progress | None = None,
) -> list[ImageCorners | FrameError]:
    """The image stage alone: ImageCorners or the FrameError per frame."""
    items = [(observe_image, source, r, config, options.image, options.strict) for r in refs]
    return _map(_stage, items, options.jobs, progress)


def stage_alone(
    source: FrameSource, stage: str, options: StageOptions, progress: Progress | None = None
) -> tuple[Config, list[FrameRef], list]:
    """One stage (``lidar`` or ``image``) over every frame that has its file: (config used, refs,
    per frame the stage's answer or its FrameError). The config is checked as for a calibration."""
    if options.jobs > 1:
        workers.prestart()
    config = source.config()
    refs = source.frames(require_image=stage == "image", require_scan=stage == "lidar")
    config = resolve_lidar(source, refs, config)  # the beam table the scans show
    if stage == "image":
        check_image_size(source, refs, config)
    config, _ = check_board_colour(source, refs, config, strict=options.strict)  # images where any
    signals.check()
    fn = run_lidar_stage if stage == "lidar" else run_image_stage
    return config, refs, fn(source, refs, config, options, progress)


def _expected_lidar(source: FrameSource, ref: FrameRef, config: Config, options: LidarOptions,
                    expected: ExpectedBoard) -> object:  # fmt: skip
    return _attempt(observe_lidar, source, ref, config, options, expected)


def look_again(
    source: FrameSource, config: Config, frames: Sequence[FrameResult], expected: dict[str, ExpectedBoard],
    options: StageOptions = StageOptions(),
) -> list[FrameResult]:  # fmt: skip
    """The frames again, the LiDAR stage searching near ``expected[name]`` for the frames named there.

    A frame whose board is then found gets it (with ``diagnostics["found_near_prediction"] = 1``);
    the others stay as they were. Frames are matched to the source's by name.
    """
    refs = {r.name: r for r in source.frames()}
    names = [n for n in expected if n in refs]
    items = [(source, refs[n], config, options.lidar, expected[n]) for n in names]
    found = dict(zip(names, _map(_expected_lidar, items, options.jobs, None), strict=True))
    out = []
    for f in frames:
        res = found.get(f.name)
        if res is None or isinstance(res, FrameError):
            out.append(f)
            continue
        res.diagnostics["found_near_prediction"] = 1.0
        image_reason = [r for r in (f.reason or "").split("; ") if r.startswith("image:")]
        out.append(dataclasses.replace(f, board=res, used=f.corners is not None,
                                       reason="; ".join(image_reason) or None))  # fmt: skip
    return out


def _predicted_board(corners: ImageCorners, config: Config, T_cam_lidar: np.ndarray) -> np.ndarray | None:
    """(4, 4) ``T_lidar_board`` as the image and the extrinsic put it (UPnP of the corners), or None."""
    b = corners.bearings / np.linalg.norm(corners.bearings, axis=1, keepdims=True)
    ok = np.all(np.isfinite(b), axis=1)
    if ok.sum() < 6:
        return None
    T_cam_board = upnp(config.board.corners_board()[ok], b[ok], prefer_front=True)[0].T_cam_points
    return np.linalg.inv(T_cam_lidar) @ T_cam_board


def second_pass(
    obs: Observation, cal: Calibration, stages: StageOptions, far_m: float = 0.15
) -> Observation | None:
    """The observation with the boards found near their predicted place, or None when none changed.

    Frames with image corners whose LiDAR board is missing, or lies more than ``far_m`` from where
    the image and ``cal``'s extrinsic put it, are searched again near that place
    (``lidar.ExpectedBoard``): clutter that won the first search (a board-sized object, a pillar the
    board merged with) then no longer costs the frame.
    """
    expected: dict[str, ExpectedBoard] = {}
    centre = obs.config.board.corners_board().mean(axis=0)
    unused = {g.name for g in cal.frames if not g.used}
    for f in obs.frames:
        if f.corners is None or f.name not in unused:
            continue
        pred = _predicted_board(f.corners, obs.config, cal.T_cam_lidar)
        if pred is None:
            continue
        if f.board is not None:
            seen = f.board.T_lidar_board[:3, :3] @ centre + f.board.T_lidar_board[:3, 3]
            if np.linalg.norm(seen - (pred[:3, :3] @ centre + pred[:3, 3])) < far_m:
                continue  # the LiDAR saw it there: its drop has another reason
        expected[f.name] = ExpectedBoard(pred)
    if not expected:
        return None
    frames = look_again(obs.source, obs.config, obs.frames, expected, stages)
    found = [f.name for f, g in zip(frames, obs.frames, strict=True) if f is not g]
    if not found:
        return None
    log.info("second pass: the board found near its predicted place in %s", ", ".join(found))
    return Observation(obs.source, obs.config, frames)
