"""A rig's per-moment stages (issue 24): the LiDAR stage on every LiDAR's scan, the image stage on
every camera's image, each with that sensor's own settings; failures kept per (moment, sensor).

``observe_moment`` is pure (scans and images in memory, e.g. the simulator's ``RigMoment``);
``observe_source_moment`` reads one moment through a ``RigSource`` first (picklable arguments, for
``workers.map_processes`` as the single-pair pass runs ``observe.observe_frame``); ``observe_rig``
runs it over every moment of a source. A LiDAR's stage config is the rig's board, its beam table
(None: measured from the scan) and its ROI (``RigConfig.pair_config``'s LiDAR half); a camera's is
the board and its model.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ilcc_graph import workers
from ilcc_graph.config import RigConfig
from ilcc_graph.datasets.rig import Moment, RigSource
from ilcc_graph.errors import DamagedFile, FrameError
from ilcc_graph.image import detect_corners
from ilcc_graph.lidar import estimate_board
from ilcc_graph.run.stages import StageOptions, read_frame_file
from ilcc_graph.types import BoardFit, ImageCorners, MomentResult, Scan

__all__ = ["RigObservation", "observe_moment", "observe_rig", "observe_source_moment"]


@dataclass(frozen=True)
class RigObservation:
    """A rig observed: its config and per moment what the stages found (``types.MomentResult``);
    skipped: ``(moment, reason)`` of moments the source could not use (fewer than two sensors)."""

    rig: RigConfig
    moments: list[MomentResult]
    skipped: list[tuple[str, str]] = field(default_factory=list)

    def seen(self, sensor: str) -> list[str]:
        """The moments at which ``sensor`` saw the board."""
        return [m.name for m in self.moments if sensor in m.boards or sensor in m.corners]


def _lidar(scan: Scan, rig: RigConfig, name: str, options: StageOptions) -> BoardFit:
    s = rig.sensor(name)
    return estimate_board(scan, rig.board, s.lidar, s.roi, options.lidar)


def _camera(image: np.ndarray, rig: RigConfig, name: str, options: StageOptions, where: str) -> ImageCorners:
    cam = rig.sensor(name).camera
    if cam is None:
        raise ValueError(f"sensor {name!r} is not a camera")
    h, w = np.asarray(image).shape[:2]
    if (w, h) != (cam.width, cam.height):
        raise DamagedFile(
            f"{where}: image is {w}x{h} px, but camera {name!r} in {rig.source or 'the rig'} is "
            f"{cam.width}x{cam.height}"
        )
    return detect_corners(image, cam, rig.board, options.image)


def observe_moment(
    name: str,
    scans: Mapping[str, Scan],
    images: Mapping[str, np.ndarray],
    rig: RigConfig,
    options: StageOptions = StageOptions(),
) -> MomentResult:
    """The stages on one moment's data: ``scans`` {LiDAR: Scan}, ``images`` {camera: (H, W, 3) BGR}.

    A sensor whose stage raises ``FrameError`` (no board, no corners, a damaged file) is recorded in
    ``failures`` with the reason; other errors propagate. Sensors not in the rig are a ValueError.
    """
    unknown = [n for n in (*scans, *images) if n not in rig.names]
    if unknown:
        raise ValueError(f"moment {name}: sensors {unknown} are not in the rig {list(rig.names)}")
    boards: dict[str, BoardFit] = {}
    corners: dict[str, ImageCorners] = {}
    failures: dict[str, str] = {}
    damaged: list[str] = []

    def failed(sensor: str, err: FrameError) -> None:
        failures[sensor] = str(err)
        if isinstance(err, DamagedFile):
            damaged.append(sensor)

    for lid in (x for x in rig.lidars if x in scans):
        try:
            boards[lid] = _lidar(scans[lid], rig, lid, options)
        except FrameError as err:
            failed(lid, err)
    for cam in (x for x in rig.cameras if x in images):
        try:
            corners[cam] = _camera(images[cam], rig, cam, options, f"{name}/{cam}")
        except FrameError as err:
            failed(cam, err)
    return MomentResult(name, boards, corners, failures, tuple(damaged))


def observe_source_moment(
    source: RigSource,
    moment: Moment,
    rig: RigConfig,
    options: StageOptions = StageOptions(),
) -> MomentResult:
    """One moment of a ``datasets.RigSource`` (``moment``: a ``Moment`` of ``source.moments()``):
    each sensor's file read through the source (a file that cannot be read costs that sensor's view,
    as a ``DamagedFile``, unless ``options.strict``), then ``observe_moment``."""
    scans: dict[str, Scan] = {}
    images: dict[str, np.ndarray] = {}
    failed: dict[str, str] = {}
    for s in rig.names:
        if not moment.has(s):
            continue
        read = source.read_scan if s in rig.lidars else source.read_image
        try:
            data = read_frame_file(read, moment, s, strict=options.strict)
        except DamagedFile as err:
            failed[s] = str(err)
            continue
        (scans if s in rig.lidars else images)[s] = data
    res = observe_moment(moment.name, scans, images, rig, options)
    res.failures.update(failed)
    return MomentResult(res.name, res.boards, res.corners, res.failures, (*res.damaged, *failed))


def observe_rig(
    source: RigSource,
    options: StageOptions = StageOptions(),
    progress: Callable[[int, int], None] | None = None,
) -> RigObservation:
    """Every moment of a ``datasets.RigSource`` through the stages, on ``options.jobs`` processes."""
    rig = source.config()
    moments = source.moments()
    items = [(source, m, rig, options) for m in moments]
    done = workers.map_processes(observe_source_moment, items, options.jobs, progress)
    return RigObservation(rig, done, list(source.skipped()))
