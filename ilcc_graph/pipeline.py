"""Runs the stages on a data set and solves for the extrinsic.

The only module besides ``cli`` that touches the disk: it reads the frames, runs the LiDAR and
image stages per frame (a ``FrameError`` skips the frame with its reason; an ``InputError``
propagates), orders corners consistently across frames, initialises with UPnP and refines with
the factor graph (or the paper's refinement).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcc_graph.config import Config, load_config
from ilcc_graph.errors import BoardColourMismatch, CalibrationImpossible, FrameError, InputError
from ilcc_graph.graph import GraphFrame, GraphOptions, solve
from ilcc_graph.image import detect_corners
from ilcc_graph.init import resolve_half_turns, upnp
from ilcc_graph.io import FramePaths, list_frames, read_image, read_scan
from ilcc_graph.lidar import estimate_board
from ilcc_graph.lidars import choose_model, measure_beams
from ilcc_graph.paper_refine import refine_paper
from ilcc_graph.types import BoardFit, Calibration, FrameResult, ImageCorners

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]
REFINE_METHODS = ("graph", "paper")


@dataclass(frozen=True)
class CalibrateOptions:
    """How to solve: ``refine`` is "graph" (ours, with covariance) or "paper" (baseline)."""

    refine: str = "graph"
    robust: str | None = None
    jobs: int = 1
    min_frames_warning: int = 4


# ----------------------------------------------------------------------------------------------
# Per-frame observation


def observe_lidar(paths: FramePaths, config: Config) -> BoardFit:
    """The LiDAR stage on one frame's scan; raises FrameError with the reason."""
    scan = read_scan(paths.scan, config.intensity_column)
    return estimate_board(scan, config.board, config.lidar, config.roi)


def resolve_lidar(frames: Sequence[FramePaths], config: Config, look: int = 3) -> Config:
    """The config with the beam table the scans show, warning once when it contradicts the config's.

    The first readable scan of the first ``look`` frames is measured (``lidars.measure_beams``:
    ring field, organised rows or elevation clusters) and checked against ``config.lidar`` (a named
    model or a calibration file); the measured table is used where they differ. With no model in
    the config the measured one is used silently. An unreadable scan is left to the LiDAR stage.
    """
    for paths in frames[:look]:
        if paths.scan is None:
            continue
        try:
            scan = read_scan(paths.scan, config.intensity_column)
        except InputError:
            continue
        name = f"{paths.scan.parent.name}/{paths.scan.name}"
        model, warning = choose_model(measure_beams(scan), config.lidar, name)
        if warning:
            log.warning("%s", warning)
        return dataclasses.replace(config, lidar=model)
    return config


def observe_image(paths: FramePaths, config: Config) -> ImageCorners:
    """The image stage on one frame's image; raises FrameError with the reason."""
    return detect_corners(read_image(paths.image), config.camera, config.board)


def observe_frame(paths: FramePaths, config: Config) -> FrameResult:
    """Both stages on one frame. A stage that fails leaves its field None and says why."""
    reasons: list[str] = []
    board = corners = None
    try:
        board = observe_lidar(paths, config)
    except FrameError as err:
        reasons.append(f"LiDAR: {err}")
    try:
        corners = observe_image(paths, config)
    except FrameError as err:
        reasons.append(f"image: {err}")
    return FrameResult(
        name=paths.name,
        used=not reasons,
        reason="; ".join(reasons) or None,
        board=board,
        corners=corners,
    )


def _map_frames(
    fn: Callable[[FramePaths, Config], object],
    frames: Sequence[FramePaths],
    config: Config,
    jobs: int,
    progress: Progress | None,
) -> list:
    """``fn`` over the frames, in order, on ``jobs`` processes."""
    results: list = []
    if jobs <= 1 or len(frames) <= 1:
        for i, paths in enumerate(frames):
            results.append(fn(paths, config))
            if progress:
                progress(i + 1, len(frames))
        return results
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(fn, paths, config) for paths in frames]
        for i, fut in enumerate(futures):
            results.append(fut.result())
            if progress:
                progress(i + 1, len(frames))
    return results


def check_board_colour(
    frames: Sequence[FramePaths], config: Config, needed: int = 2, look: int = 6
) -> Config:
    """The config with ``board.lower_left`` as the images show it, warning when that differs.

    For a board that looks the same after a half turn (even squares on both sides), the colour of
    the lower-left square seen from the front is a property of the print, which the user may have
    mistyped. The image stage tells it with certainty; this looks at up to ``look`` frames until
    ``needed`` agree, and turns the setting when the images contradict it. Other boards: unchanged.
    """
    board = config.board
    if not board.half_turn_symmetric:
        return config
    agree = disagree = 0
    for paths in frames[:look]:
        if paths.image is None:
            continue
        try:
            observe_image(paths, config)
            agree += 1
        except BoardColourMismatch:
            disagree += 1
        except FrameError:
            continue
        if max(agree, disagree) >= needed:
            break
    if disagree <= agree:
        return config
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
    return dataclasses.replace(config, board=dataclasses.replace(board, lower_left=other))


def observe_frames(
    frames: Sequence[FramePaths], config: Config, jobs: int = 1, progress: Progress | None = None
) -> list[FrameResult]:
    """``observe_frame`` over all frames, in input order."""
    return _map_frames(observe_frame, frames, config, jobs, progress)


def _try(fn: Callable[[FramePaths, Config], object], paths: FramePaths, config: Config) -> object:
    try:
        return fn(paths, config)
    except FrameError as err:
        return err


def _try_lidar(paths: FramePaths, config: Config) -> BoardFit | FrameError:
    return _try(observe_lidar, paths, config)  # type: ignore[return-value]


def _try_image(paths: FramePaths, config: Config) -> ImageCorners | FrameError:
    return _try(observe_image, paths, config)  # type: ignore[return-value]


def run_lidar_stage(
    frames: Sequence[FramePaths], config: Config, jobs: int = 1, progress: Progress | None = None
) -> list[BoardFit | FrameError]:
    """The LiDAR stage alone: a BoardFit or the FrameError per frame."""
    return _map_frames(_try_lidar, frames, config, jobs, progress)


def run_image_stage(
    frames: Sequence[FramePaths], config: Config, jobs: int = 1, progress: Progress | None = None
) -> list[ImageCorners | FrameError]:
    """The image stage alone: ImageCorners or the FrameError per frame."""
    return _map_frames(_try_image, frames, config, jobs, progress)


# ----------------------------------------------------------------------------------------------
# From observations to the extrinsic


def _permute_corners(corners: ImageCorners, perm: np.ndarray) -> ImageCorners:
    """The same corners re-indexed: new corner k is old corner perm[k]."""
    return dataclasses.replace(
        corners, uv=corners.uv[perm], bearings=corners.bearings[perm], cov_px=corners.cov_px[perm]
    )


def _drop(results: dict[str, FrameResult], name: str, reason: str) -> None:
    results[name] = dataclasses.replace(results[name], used=False, reason=reason)


def solve_extrinsic(
    observed: Sequence[FrameResult], config: Config, options: CalibrateOptions = CalibrateOptions()
) -> Calibration:
    """Order corners across frames, initialise with UPnP, refine; returns every frame's fate.

    Raises CalibrationImpossible when no frame has the board in both sensors.
    """
    if options.refine not in REFINE_METHODS:
        raise ValueError(f"refine must be one of {REFINE_METHODS}, got {options.refine!r}")
    results = {r.name: r for r in observed}
    usable = [r for r in observed if r.used and r.board is not None and r.corners is not None]
    if not usable:
        reasons = "; ".join(f"{r.name}: {r.reason}" for r in observed) or "no frames"
        raise CalibrationImpossible(f"no frame has the board in both the scan and the image ({reasons})")

    board = config.board
    perm = board.half_turn_permutation() if board.half_turn_symmetric else None
    order = resolve_half_turns(
        [r.board.corners_lidar for r in usable],  # type: ignore[union-attr]
        [r.corners.bearings for r in usable],  # type: ignore[union-attr]
        perm,
        [r.name for r in usable],
    )
    if order.ambiguous:
        raise CalibrationImpossible(
            f"the corner order between image and scan cannot be decided: {order.ambiguous}"
        )
    for name, reason in order.dropped:
        _drop(results, name, reason)
    kept: list[FrameResult] = []
    for r in usable:
        if not results[r.name].used:
            continue
        if perm is not None and order.flip.get(r.name, False):
            r = dataclasses.replace(r, corners=_permute_corners(r.corners, perm))  # type: ignore[arg-type]
            results[r.name] = r
        kept.append(r)
    if not kept:
        raise CalibrationImpossible(
            "no frame left after ordering the corners: "
            + "; ".join(f"{n}: {why}" for n, why in order.dropped)
        )

    points = np.vstack([r.board.corners_lidar for r in kept])  # type: ignore[union-attr]
    bearings = np.vstack([r.corners.bearings for r in kept])  # type: ignore[union-attr]
    T_init = upnp(points, bearings, prefer_front=True)[0].T_cam_points  # corners lie ahead along their rays

    graph_frames = [
        GraphFrame(
            name=r.name,
            T_lidar_board=r.board.T_lidar_board,  # type: ignore[union-attr]
            board_cov=r.board.covariance,  # type: ignore[union-attr]
            points_board=board.corners_board(),
            bearings=r.corners.bearings,  # type: ignore[union-attr]
            cov_px=r.corners.cov_px,  # type: ignore[union-attr]
        )
        for r in kept
    ]
    if options.refine == "paper":
        T = refine_paper(graph_frames, T_init, R_pano_cam=config.camera.R_flu_cam)
        cov = np.full((6, 6), np.nan)
        rms = {f.name: _rms_bearing_mrad(T, f) for f in graph_frames}
        dropped: list[tuple[str, str]] = []
        diagnostics: dict[str, float] = {}
    else:
        sol = solve(graph_frames, config.camera, T_init, GraphOptions(robust=options.robust))
        T, cov, dropped = sol.T_cam_lidar, sol.covariance, list(sol.dropped)
        rms = {name: s.rms_bearing_error_mrad for name, s in sol.per_frame.items()}
        diagnostics = {
            "iterations": float(sol.iterations),
            "variance_factor": sol.variance_factor,
            "variance_component_board": sol.variance_components[0],
            "variance_component_bearing": sol.variance_components[1],
        }
    for name, reason in dropped:
        _drop(results, name, reason)
    n_used = sum(1 for r in results.values() if r.used)
    if options.refine == "paper" and n_used < options.min_frames_warning:  # the graph warns itself
        log.warning("only %d usable frame(s); at least %d are advised", n_used, options.min_frames_warning)
    frames = tuple(
        dataclasses.replace(r, rms_bearing_error_mrad=rms.get(r.name)) if r.used else r
        for r in (results[o.name] for o in observed)
    )
    diagnostics["upnp_rotation_deg"] = _rotation_angle_deg(T_init[:3, :3].T @ T[:3, :3])
    return Calibration(
        T_cam_lidar=T, covariance=cov, frames=frames, method=options.refine, diagnostics=diagnostics
    )


def _rotation_angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _rms_bearing_mrad(T_cam_lidar: np.ndarray, f: GraphFrame) -> float:
    """RMS angle (mrad) between measured bearings and the corners predicted through T."""
    T = T_cam_lidar @ f.T_lidar_board
    p = f.points_board @ T[:3, :3].T + T[:3, 3]
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    ang = np.arctan2(np.linalg.norm(np.cross(p, f.bearings), axis=1), np.sum(p * f.bearings, axis=1))
    return float(1e3 * np.sqrt(np.mean(ang**2)))


# ----------------------------------------------------------------------------------------------
# The public API


def observe_dataset(
    data_dir: Path | str, jobs: int = 1, progress: Progress | None = None
) -> tuple[Config, list[FramePaths], list[FrameResult]]:
    """Read a data set's config, pair its frames, check the print's colour, run both stages.

    Returns the config used, the paired frames, and every frame's observation (stems without a
    partner come last, unused, with the reason).
    """
    data_dir = Path(data_dir)
    config = load_config(data_dir / "config.yaml")
    frames, unpaired = list_frames(data_dir)
    config = resolve_lidar(frames, config)
    config = check_board_colour(frames, config)
    observed = observe_frames(frames, config, jobs, progress)
    observed += [FrameResult(name=stem, used=False, reason=why) for stem, why in unpaired]
    return config, frames, observed


def calibrate_dataset(
    data_dir: Path | str,
    options: CalibrateOptions = CalibrateOptions(),
    progress: Progress | None = None,
) -> tuple[Config, Calibration]:
    """Calibrate one data set (interface.md layout). Returns the config used and the result."""
    config, _, observed = observe_dataset(data_dir, options.jobs, progress)
    return config, solve_extrinsic(observed, config, options)


def calibrate(data_dir: Path | str, options: CalibrateOptions = CalibrateOptions()):  # -> (Pose3, cov)
    """Python API: the extrinsic as ``gtsam.Pose3`` (T_cam_lidar) and its 6x6 covariance."""
    import gtsam

    _, cal = calibrate_dataset(data_dir, options)
    return gtsam.Pose3(cal.T_cam_lidar), cal.covariance
