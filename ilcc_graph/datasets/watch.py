"""A data-set folder that is still being filled (by a recorder): frames as they become complete.

``GrowingFolder`` is a :class:`FolderSource` whose :meth:`~GrowingFolder.poll` lists the frames that
became complete since the last call. A frame is complete when its scan (``pcd/<stem>.*``) and its
image (``img/<stem>.*``; or the folders of another common name, ``io.data_folders``) both exist,
are not empty, and neither has changed size or modification time for ``settle_s`` seconds (a writer
that streams a file is still writing it). Hidden files and files with other suffixes
(``0001.pcd.part``) are ignored. A stem with two scans or two images waits until one of them goes.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

from ilcc_graph.datasets.folder import FolderSource
from ilcc_graph.datasets.frame_source import FrameRef
from ilcc_graph.io import IMAGE_SUFFIXES, data_folders, natural_key, supported_scan_suffixes

__all__ = ["Arrival", "GrowingFolder"]


@dataclass(frozen=True)
class Arrival:
    """A frame that became complete: ``arrived`` is the wall-clock time (``time.time()``) its last
    file was last written (its modification time), ``seen`` when this process saw it complete."""

    ref: FrameRef
    arrived: float
    seen: float


@dataclass
class _FileState:
    size: int
    mtime_ns: int
    changed: float  # time.monotonic() of the last change seen


class GrowingFolder(FolderSource):
    """A folder in interface.md's layout that may still grow; ``config.yaml`` must exist to read it."""

    def __init__(self, path: str | Path, settle_s: float = 0.3) -> None:
        self.path = Path(path)
        self.label = self.path.resolve().name or str(self.path)
        self.location = str(self.path)
        self._skipped: list[tuple[str, str]] = []
        self.settle_s = float(settle_s)
        self._files: dict[Path, _FileState] = {}
        self._done: set[str] = set()
        self._scan_suffixes = tuple(supported_scan_suffixes())

    def has_config(self) -> bool:
        return (self.path / "config.yaml").is_file()

    def _scan_dir(self, sub: str, suffixes: tuple[str, ...], now: float) -> dict[str, list[Path]]:
        out: dict[str, list[Path]] = {}
        try:
            entries = list(os.scandir(self.path / sub))
        except FileNotFoundError:
            return out
        for e in entries:
            if e.name.startswith(".") or not e.is_file():
                continue
            p = Path(e.path)
            if p.suffix.lower() not in suffixes:
                continue
            try:
                st = e.stat()
            except FileNotFoundError:
                continue
            old = self._files.get(p)
            if old is None or old.size != st.st_size or old.mtime_ns != st.st_mtime_ns:
                self._files[p] = _FileState(st.st_size, st.st_mtime_ns, now)
            out.setdefault(p.stem, []).append(p)
        return out

    def _settled(self, p: Path, now: float) -> bool:
        s = self._files[p]
        return s.size > 0 and now - s.changed >= self.settle_s

    def poll(self) -> list[Arrival]:
        """The frames that became complete since the last call, in natural stem order."""
        now = time.monotonic()
        scan_dir, image_dir = data_folders(self.path) if self.path.is_dir() else (None, None)
        scans = self._scan_dir(scan_dir or "pcd", self._scan_suffixes, now)
        images = self._scan_dir(image_dir or "img", IMAGE_SUFFIXES, now)
        ready = []
        for stem in sorted(scans.keys() & images.keys() - self._done, key=natural_key):
            if len(scans[stem]) != 1 or len(images[stem]) != 1:
                continue
            scan, image = scans[stem][0], images[stem][0]
            if not (self._settled(scan, now) and self._settled(image, now)):
                continue
            self._done.add(stem)
            arrived = max(self._files[scan].mtime_ns, self._files[image].mtime_ns) * 1e-9
            ready.append(Arrival(FrameRef(stem, scan, image), arrived, time.time()))
        return ready
