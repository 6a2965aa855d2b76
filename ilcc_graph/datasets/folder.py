"""The folder layout of interface.md as a frame source: ``DATA/config.yaml``, ``DATA/pcd``, ``DATA/img``.

Frames pair by file stem (``io.list_frames``), or, when some scan has no image of its name and every
name is a time, by those times (within ``TIME_TOLERANCE_S``); scans are read by extension
(``io.read_scan``).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ilcc_graph.config import Config, load_config
from ilcc_graph.datasets.frame_source import FrameRef, FrameSource
from ilcc_graph.datasets.timeline import nearest, pair_by_time
from ilcc_graph.errors import InputError
from ilcc_graph.io import GroundTruth, list_frames, read_ground_truth, read_image, read_scan
from ilcc_graph.io.files import broken_link
from ilcc_graph.io.images import image_size
from ilcc_graph.io.results import GROUND_TRUTH_FILE
from ilcc_graph.types import Scan

__all__ = ["FolderSource", "is_folder_source"]

log = logging.getLogger(__name__)

#: scans and images named by their times pair when that far apart at most (s; a bag's default
#: ``sync_tolerance``): the board is held still, the sensors need not be triggered together
TIME_TOLERANCE_S = 0.05


def _by_time(ts: np.ndarray, ti: np.ndarray) -> tuple[dict[int, int], np.ndarray, np.ndarray]:
    """``io.TimePairing``: scans paired with images within ``TIME_TOLERANCE_S``, each scan's gap (s) to
    its nearest image and that image's index."""
    near = nearest(ti, ts)
    return pair_by_time(ts, ti, TIME_TOLERANCE_S), np.abs(ti[near] - ts), near


def is_folder_source(path: Path) -> bool:
    """A folder holding ``config.yaml``."""
    return path.is_dir() and (path / "config.yaml").is_file()


class FolderSource(FrameSource):
    """A data set on disk in the layout of interface.md."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise InputError(
                f"{self.path}: not a directory (expected a data set with config.yaml, pcd/ and img/)"
            )
        self.label = self.path.resolve().name or str(self.path)
        self.location = str(self.path)
        self._skipped: list[tuple[str, str]] = []
        self._noted: set[str] = set()  # notes already said (frames() is called more than once)

    def config(self) -> Config:
        return load_config(self.path / "config.yaml")

    def frames(self, require_scan: bool = True, require_image: bool = True) -> list[FrameRef]:
        frames, self._skipped = list_frames(
            self.path, require_image=require_image, require_scan=require_scan, by_time=_by_time
        )
        for f in frames:
            if f.note and f.note not in self._noted:
                log.warning("%s: %s", self.path, f.note)
                self._noted.add(f.note)
        return [FrameRef(f.name, f.scan, f.image) for f in frames]

    def skipped(self) -> list[tuple[str, str]]:
        return list(self._skipped)

    def read_scan(self, ref: FrameRef, config: Config) -> Scan:
        if why := broken_link(ref.scan):
            raise InputError(why)
        return read_scan(ref.scan, config.intensity_column)

    def read_image(self, ref: FrameRef) -> np.ndarray:
        return read_image(ref.image)

    def header_size(self, ref: FrameRef) -> tuple[int, int]:
        """(width, height) from the image file's header (``io.image_size``: no pixel is decoded)."""
        return image_size(ref.image)

    def ground_truth(self) -> GroundTruth | None:
        """A simulated set's truth (``ground_truth.yaml`` in the folder), else None."""
        return read_ground_truth(self.path) if (self.path / GROUND_TRUTH_FILE).is_file() else None
