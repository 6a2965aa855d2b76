"""A rig's per-moment stages (issue 24): the LiDAR stage on every LiDAR's scan, the image stage on
every camera's image, each with that sensor's own settings; failures kept per (moment, sensor).

``observe_moment`` is pure (scans and images in memory, e.g. the simulator's ``RigMoment``);
``observe_source_moment`` reads one moment through a ``RigSource`` first (picklable arguments, for
``workers.map_processes`` as the single-pair pass runs ``observe.observe_frame``); ``observe_rig``
runs it over every moment of a source after the start a pair's run has too (``open_rig``: each
LiDAR's beam table from its scans; the print's colour from the first images). A LiDAR's stage config
is the rig's board, its beam table and its ROI (``RigConfig.pair_config``'s LiDAR half); a camera's
is the board and its model.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ilcc_graph import workers
from ilcc_graph.config import RigConfig
from ilcc_graph.datasets.rig_source import Moment, RigSource
from ilcc_graph.errors import BoardColourMismatch, DamagedFile, FrameError, InputError
from ilcc_graph.image import detect_corners
from ilcc_graph.run.colour import colour_votes, colour_warning
from ilcc_graph.run.source import resolve_beams
from ilcc_graph.run.stages import StageOptions, kept, lidar_stage, read_frame_file, warn_margin, warn_no_print
from ilcc_graph.types import BoardFit, ImageCorners, MomentResult, Scan

__all__ = ["RigObservation", "observe_moment", "observe_rig", "observe_source_moment", "open_rig"]


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
    return lidar_stage(options, scan, rig.board, s.lidar, s.roi)


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
    return kept(options, "corners", detect_corners, image, cam, rig.board, options.image)


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
    contradicted: list[str] = []

    def failed(sensor: str, err: FrameError) -> None:
        failures[sensor] = str(err)
        if isinstance(err, DamagedFile):
            damaged.append(sensor)
        if isinstance(err, BoardColourMismatch):
            contradicted.append(sensor)

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
    return MomentResult(name, boards, corners, failures, tuple(damaged), tuple(contradicted))


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
    return dataclasses.replace(res, damaged=(*res.damaged, *failed))


def observe_rig(
    source: RigSource,
    options: StageOptions = StageOptions(),
    progress: Callable[[int, int], None] | None = None,
) -> RigObservation:
    """Every moment of a ``datasets.RigSource`` through the stages, on ``options.jobs`` processes,
    after the start every run has (``open_rig``: each LiDAR's beam table from its scans); the print's
    colour decided on the first moments' camera results as a pair's pass decides it
    (``colour.colour_votes``), the moments observed again with the other colour when they contradict
    the board's ``lower_left``."""
    if options.jobs > 1:
        workers.prestart()
    moments = source.moments()
    rig = open_rig(source, moments)
    done = _observe_moments(source, moments, rig, options, progress)
    agree, disagree = colour_votes(_colour_results(done[:6], rig))
    if rig.board.half_turn_symmetric and disagree > agree:
        rig = colour_warning(rig, "images checked")
        done = _observe_moments(source, moments, rig, options, progress)
    for lidar in rig.lidars:  # what each LiDAR's boards showed, said as a pair's pass says it
        boards = [m.boards[lidar] for m in done if lidar in m.boards]
        where = f"{rig.source} ({lidar})"
        warn_no_print(boards, where)
        warn_margin(boards, rig.board, where, Path(rig.source).name)
    return RigObservation(rig, done, list(source.skipped()))


def open_rig(source: RigSource, moments: Sequence[Moment], look: int = 3) -> RigConfig:
    """The rig's config with every LiDAR's beam table as its scans show it (``source.resolve_beams``
    on the first readable of its first ``look`` scans, as a pair's run starts)."""
    rig = source.config()

    def scans(lidar: str) -> Iterator[tuple[Scan, str]]:
        for m in [m for m in moments if m.has(lidar)][:look]:
            try:
                yield source.read_scan(m, lidar), f"{m.name}/{lidar}"
            except InputError:
                continue  # a damaged scan: its stage says so for its moment

    sensors = tuple(
        dataclasses.replace(s, lidar=resolve_beams(scans(s.name), s.lidar)) if s.kind == "lidar" else s
        for s in rig.sensors
    )
    return dataclasses.replace(rig, sensors=sensors)


def _observe_moments(
    source: RigSource, moments: Sequence[Moment], rig: RigConfig, options: StageOptions,
    progress: Callable[[int, int], None] | None,
) -> list[MomentResult]:  # fmt: skip
    items = [(source, m, rig, options) for m in moments]
    return workers.map_processes(observe_source_moment, items, options.jobs, progress)


def _colour_results(moments: Sequence[MomentResult], rig: RigConfig) -> Iterator[object]:
    """Each camera's image result for ``colour.colour_votes``, moment by moment: its corners, a
    ``BoardColourMismatch`` where the print contradicted ``lower_left``, None otherwise."""
    for m in moments:
        for cam in rig.cameras:
            if cam in m.contradicted:
                yield BoardColourMismatch(m.failures.get(cam, ""))
            else:
                yield m.corners.get(cam)
