"""The second look: boards the LiDAR stage missed, searched where the image and an extrinsic put them.

``second_pass(observation, calibration, stages)`` gives the observation with the boards found near
their predicted place (``lidar.ExpectedBoard``), or None when none changed: clutter that won the first
search (a board-sized object, a pillar the board merged with) then no longer costs the frame.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence

import numpy as np

from ilcc_graph import workers
from ilcc_graph.cameras import CameraModel
from ilcc_graph.config import Config
from ilcc_graph.config.rig_config import solved_camera
from ilcc_graph.datasets import FrameSource
from ilcc_graph.errors import FrameError
from ilcc_graph.init import upnp
from ilcc_graph.lidar.stretch import correction_of, significant
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.stages import StageOptions, attempt, observe_lidar
from ilcc_graph.types import Calibration, ExpectedBoard, FrameResult, ImageCorners, RangeCorrection

log = logging.getLogger(__name__)

__all__ = ["look_again", "second_pass"]


def look_again(
    source: FrameSource, config: Config, frames: Sequence[FrameResult], expected: dict[str, ExpectedBoard],
    options: StageOptions = StageOptions(), correction: RangeCorrection | None = None,
) -> list[FrameResult]:  # fmt: skip
    """The frames again, the LiDAR stage searching near ``expected[name]`` for the frames named there
    (on the ranges corrected by ``correction`` when given, as ``range_refit`` fits the others).

    A frame whose board is then found gets it (with ``diagnostics["found_near_prediction"] = 1``);
    the others stay as they were. Frames are matched to the source's by name.
    """
    refs = {r.name: r for r in source.frames()}
    names = [n for n in expected if n in refs]
    items = [(observe_lidar, source, refs[n], config, options, expected[n], correction) for n in names]
    found = dict(zip(names, workers.map_processes(attempt, items, options.jobs, None), strict=True))
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


def _predicted_board(
    corners: ImageCorners, config: Config, T_cam_lidar: np.ndarray, camera: CameraModel | None = None
) -> np.ndarray | None:
    """(4, 4) ``T_lidar_board`` as the image and the extrinsic put it (UPnP of the corners; their
    bearings through ``camera`` when given, the extrinsic's refined one), or None."""
    b = corners.bearings if camera is None or corners.uv is None else camera.bearing(corners.uv)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    ok = np.all(np.isfinite(b), axis=1)
    if ok.sum() < 6:
        return None
    T_cam_board = upnp(config.board.corners_board()[ok], b[ok], prefer_front=True)[0].T_cam_points
    return np.linalg.inv(T_cam_lidar) @ T_cam_board


def second_pass(
    obs: Observation, cal: Calibration, stages: StageOptions, far_m: float = 0.15, refit: bool = True
) -> Observation | None:
    """The observation with the boards found near their predicted place, or None when none changed.

    Frames with image corners whose LiDAR board is missing, or lies more than ``far_m`` from where
    the image and ``cal``'s extrinsic put it (its corners through the camera as solved:
    ``cal.sensors["camera_intrinsics"]`` where the run refined them), are searched again near that
    place (on the ranges corrected by ``cal``'s estimate of the LiDAR's errors when ``refit`` and
    those are ``lidar.stretch.significant``). None too without a pair's source to read the scans
    from (``Observation.pair_source``).
    """
    source = obs.pair_source
    if source is None:
        return None
    refined = "camera_intrinsics" in cal.sensors  # the camera as solved, where it refined the lens
    camera = solved_camera(obs.pair_config.camera, cal.sensors) if refined else None
    expected: dict[str, ExpectedBoard] = {}
    centre = obs.config.board.corners_board().mean(axis=0)
    unused = {g.name for g in cal.frames if not g.used}
    for f in obs.frames:
        if f.corners is None or f.name not in unused:
            continue
        pred = _predicted_board(f.corners, obs.pair_config, cal.T_cam_lidar, camera)
        if pred is None:
            continue
        if f.board is not None:
            seen = f.board.T_lidar_board[:3, :3] @ centre + f.board.T_lidar_board[:3, 3]
            if np.linalg.norm(seen - (pred[:3, :3] @ centre + pred[:3, 3])) < far_m:
                continue  # the LiDAR saw it there: its drop has another reason
        expected[f.name] = ExpectedBoard(pred)
    if not expected:
        return None
    correction = correction_of(cal.sensors) if refit else None
    if not significant(obs.frames, correction, obs.config.board):
        correction = None
    frames = look_again(source, obs.pair_config, obs.frames, expected, stages, correction)
    found = [f.name for f, g in zip(frames, obs.frames, strict=True) if f is not g]
    if not found:
        return None
    log.info("second pass: the board found near its predicted place in %s", ", ".join(found))
    return dataclasses.replace(obs, frames=frames)
