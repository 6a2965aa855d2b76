"""A source opened for a run: config -> frames -> LiDAR model -> image size -> print colour.

``open_run`` is the one start of every run (batch, incremental, sessions, a stage alone, ``check``):
the config's mistakes first, then the folders', the beam table the scans show
(``resolve_lidar``), the images' size against the camera's (``check_image_size``: every image of
another size is the config's mistake, said once; one odd image is a damaged frame), and, when asked
``now``, the print's colour from the first images (``colour.check_board_colour``; the batch pass
decides it from the first frames' results instead, so that no frame waits for it).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

from ilcc_graph.config import Config
from ilcc_graph.datasets import FrameRef, FrameSource
from ilcc_graph.errors import InputError
from ilcc_graph.lidars import LidarModel, choose_model, measure_beams
from ilcc_graph.run.colour import check_board_colour
from ilcc_graph.run.stages import StageOptions, size_problem
from ilcc_graph.types import Scan

log = logging.getLogger(__name__)

__all__ = [
    "Opened",
    "check_image_size",
    "open_run",
    "resolve_beams",
    "resolve_lidar",
]


@dataclass(frozen=True)
class Opened:
    """A source ready for the stages: the config as checked, its frames, and the image stage's
    results computed on the way (the colour check's; valid for that config)."""

    source: FrameSource
    config: Config
    refs: list[FrameRef]
    seen: dict[str, object] = field(default_factory=dict)


def open_run(
    source: FrameSource,
    stages: StageOptions = StageOptions(),
    *,
    colour: str = "later",
    sizes: bool = True,
    refs: Sequence[FrameRef] | None = None,
    config: Config | None = None,
    require_scan: bool = True,
    require_image: bool = True,
) -> Opened:
    """Open ``source`` for a run (module docstring). colour: ``now`` (checked on the first images),
    ``later`` (the observation pass decides it) or ``never``; sizes: check the images' size;
    refs / config: the frames and config already known (``check`` opens frame by frame).
    Raises InputError naming the file and the problem."""
    config = source.config() if config is None else config  # the config's mistakes first
    if refs is None:
        refs = source.frames(require_scan=require_scan, require_image=require_image)
    refs = list(refs)
    config = resolve_lidar(source, refs, config)
    if sizes:
        check_image_size(source, refs, config)
    seen: dict[str, object] = {}
    if colour == "now":
        config, seen = check_board_colour(source, refs, config, stages)
    return Opened(source, config, refs, seen)


def resolve_lidar(source: FrameSource, refs: Sequence[FrameRef], config: Config, look: int = 3) -> Config:
    """The config with the beam table the scans show (``resolve_beams`` on the first readable scan of
    the first ``look`` frames); an unreadable scan is left to the LiDAR stage."""

    def scans() -> Iterator[tuple[Scan, str]]:
        for ref in refs[:look]:
            if ref.scan is None:
                continue
            try:
                yield source.read_scan(ref, config), ref.name
            except InputError:
                continue

    return dataclasses.replace(config, lidar=resolve_beams(scans(), config.lidar))


def resolve_beams(scans: Iterable[tuple[Scan, str]], given: LidarModel | None) -> LidarModel | None:
    """The beam table the first of ``scans`` ((scan, where) pairs) shows, warning once when it
    contradicts ``given`` (a named model or a calibration file; ``lidars.measure_beams``: ring
    field, organised rows or elevation clusters; the measured table is used where they differ).
    With no ``given`` the measured one is used silently; ``given`` when there is no scan. The one
    rule of every run's start: a pair's (``resolve_lidar``) and each LiDAR of a rig's."""
    for scan, where in scans:
        model, warning = choose_model(measure_beams(scan), given, scan.source or where)
        if warning:
            log.warning("%s", warning)
        return model
    return given


def check_image_size(source: FrameSource, refs: Sequence[FrameRef], config: Config, look: int = 3) -> None:
    """Raise InputError when the first readable images (up to ``look``) all differ from the camera's size.

    One odd image is a damaged frame (skipped); every image of another size is the config's mistake
    (or the images were scaled), said once, naming an image and the config keys.
    """
    problems = []
    for ref in [r for r in refs if r.image is not None][:look]:
        try:
            w, h = source.image_size(ref)
        except InputError:
            continue  # a damaged image: the stage says so for its frame
        problem = size_problem((w, h), config, source.image_location(ref))
        if problem is None:
            return
        problems.append(problem)
    if problems:
        more = f" (so are the other {len(problems) - 1} image(s) looked at)" if len(problems) > 1 else ""
        raise InputError(problems[0] + more)
