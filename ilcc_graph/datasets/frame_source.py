"""The data-source seam: what every source of frames gives the pipeline.

A ``FrameSource`` yields the configuration and the frames of one data set and reads, per frame,
its scan and its image. The folder layout of interface.md is one source (``folder.py``); other
sources (bags, ...) plug in as one file each and are picked by :func:`ilcc_graph.datasets.open_source`.
A source must be picklable (the per-frame stages may run in worker processes): keep paths and
settings, open files lazily.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np

from ilcc_graph.config import Config
from ilcc_graph.types import Scan

__all__ = ["FrameRef", "FrameSource"]


@dataclass(frozen=True)
class FrameRef:
    """One frame of a source: its name and what the source needs to read it.

    scan / image: the source's own locators (a path, a time stamp, ...); None when the frame has no
    scan or no image (stage commands list such frames).
    """

    name: str
    scan: Any = None
    image: Any = None


class FrameSource(ABC):
    """One data set: config, frames, and per frame a scan (LiDAR frame) and an image (BGR uint8)."""

    #: short label for messages and session names (e.g. the folder's name)
    label: str = ""
    #: where it is, for messages and reports
    location: str = ""

    @abstractmethod
    def config(self) -> Config:
        """The data set's configuration (raises InputError naming the file and key)."""

    @abstractmethod
    def frames(self, require_scan: bool = True, require_image: bool = True) -> list[FrameRef]:
        """The frames in order; with a requirement False, frames lacking that part are listed too."""

    @abstractmethod
    def skipped(self) -> list[tuple[str, str]]:
        """(name, reason) of what could not become a frame (valid after ``frames``)."""

    @abstractmethod
    def read_scan(self, ref: FrameRef, config: Config) -> Scan:
        """The frame's scan; InputError naming the file and the problem."""

    @abstractmethod
    def read_image(self, ref: FrameRef) -> np.ndarray:
        """The frame's image, (H, W, 3) BGR uint8; InputError naming the file and the problem."""

    def image_location(self, ref: FrameRef) -> str:
        """Where the frame's image is, for messages (a file's path; a bag, topic and time)."""
        return str(ref.image)

    def header_size(self, ref: FrameRef) -> tuple[int, int] | None:
        """(width, height) of the frame's image from its header alone, nothing decoded; None where the
        source cannot tell without decoding (InputError naming the file when it is damaged)."""
        return None

    def image_size(self, ref: FrameRef) -> tuple[int, int]:
        """(width, height) of the frame's image in pixels: ``header_size``, else from ``read_image``."""
        if (size := self.header_size(ref)) is not None:
            return size
        h, w = self.read_image(ref).shape[:2]
        return int(w), int(h)

    def ground_truth(self) -> Any | None:
        """A simulated source's ``io.GroundTruth``, else None."""
        return None
