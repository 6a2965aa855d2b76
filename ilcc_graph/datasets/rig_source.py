"""A rig data set (several cameras and LiDARs, docs/rig.md) as a source of moments.

Layouts: a folder per sensor, ``DATA/<sensor folder>/<stem>.<ext>`` (equal stems across sensors are
one moment; a moment may lack some sensors), or the topics of one ROS bag paired by time
(``rig_bag.py``). A single-pair data set (a folder with ``config.yaml``, a bag) opens as the rig of
one LiDAR and one camera (``config.rig_from_config``: sensors ``lidar`` in ``pcd/``, ``camera`` in
``img/``). Files are read with the single-pair sources' readers, so a damaged file raises the same
``InputError`` naming the file (``run.stages.read_frame_file`` turns it into a skipped view).
:meth:`RigSource.pair` views one camera and one LiDAR as a single-pair :class:`FrameSource`.
A source is picklable and opens files lazily.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ilcc_graph.config import Config, RigConfig, load_rig_config
from ilcc_graph.datasets.folder import FolderSource
from ilcc_graph.datasets.frame_source import FrameRef, FrameSource
from ilcc_graph.errors import InputError
from ilcc_graph.io import (
    IMAGE_SUFFIXES,
    GroundTruth,
    natural_key,
    read_image,
    read_scan,
    supported_scan_suffixes,
)
from ilcc_graph.io.frame_pairs import PREFERENCE
from ilcc_graph.io.results import GROUND_TRUTH_FILE
from ilcc_graph.io.rig_truth import RIG_GROUND_TRUTH_FILE, RigGroundTruth, read_rig_ground_truth
from ilcc_graph.types import Scan

__all__ = ["RIG_FILE", "Moment", "RigPair", "RigSource", "is_rig_source"]

log = logging.getLogger(__name__)

#: the rig file a rig data-set folder holds
RIG_FILE = "rig.yaml"


@dataclass(frozen=True, eq=False)
class Moment:
    """One moment: the files the sensors took at the same time.

    name: the shared file stem (folders) or the anchor's bag time ``t0012.345`` (bags).
    files: {sensor: locator}, a Path (folders) or (topic, bag time ns) (bags), in the rig's order.
    missing: {sensor: why it has no file at this moment}.
    """

    name: str
    files: Mapping[str, Any]
    missing: Mapping[str, str] = field(default_factory=dict)

    @property
    def sensors(self) -> tuple[str, ...]:
        return tuple(self.files)

    def has(self, sensor: str) -> bool:
        return sensor in self.files


def is_rig_source(path: Path) -> bool:
    """A rig file (``*.yaml`` with a ``sensors`` key) or a folder holding ``rig.yaml``."""
    if path.is_dir():
        return (path / RIG_FILE).is_file()
    if not (path.is_file() and path.suffix.lower() in (".yaml", ".yml")):
        return False
    try:
        head = path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return False
    return any(line.startswith("sensors:") for line in head.splitlines())


class RigSource:
    """A rig data set: its :class:`RigConfig`, moments, and per moment each sensor's scan or image.

    path: a rig file, or a folder holding ``rig.yaml``. rig: an already resolved rig (then ``path``
    only names the data set), e.g. ``rig_from_config`` of a single-pair data set.
    """

    def __init__(self, path: str | Path, rig: RigConfig | None = None) -> None:
        p = Path(path)
        self.path = p / RIG_FILE if rig is None and p.is_dir() else p
        self.label = (p if p.is_dir() else p.parent).resolve().name or str(p)
        self.location = str(p)
        self._rig = rig
        self._moments: list[Moment] | None = None
        self._all: list[Moment] = []
        self._files_skipped: list[tuple[str, str]] = []
        self._skipped: list[tuple[str, str]] = []
        self._bag: Any = None

    def config(self) -> RigConfig:
        """The rig (read once; InputError naming the file, key, value and what was expected)."""
        if self._rig is None:
            self._rig = load_rig_config(self.path)
        return self._rig

    # -- moments ---------------------------------------------------------------------------------
    def _load(self) -> None:
        """List the moments once (folders or the bag); the ones of fewer than two sensors are skipped."""
        if self._moments is not None:
            return
        rig = self.config()
        found = self._bag_reader().moments() if rig.data.bag is not None else self._folder_moments(rig)
        self._all, self._files_skipped = found[0], list(found[1])
        self._moments = [m for m in self._all if len(m.files) >= 2]
        self._skipped = list(self._files_skipped)
        for m in self._all:
            if len(m.files) < 2:
                only = f"only {m.sensors[0]} has a file" if m.files else "no sensor has a file"
                self._skipped.append((m.name, f"{only} at this moment; a moment relates two or more sensors"))

    def moments(self) -> list[Moment]:
        """The moments with files of at least two sensors, in order (the others are ``skipped``);
        InputError when there is none."""
        self._load()
        if not self._moments:
            detail = "; ".join(f"{n}: {r}" for n, r in self._skipped[:4]) or "no files"
            raise InputError(f"{self.location}: no moment with files of two or more sensors ({detail})")
        return list(self._moments)

    def all_moments(self) -> list[Moment]:
        """Every moment, also those with one sensor's file only (a LiDAR-only or camera-only look)."""
        self._load()
        return list(self._all)

    def skipped(self) -> list[tuple[str, str]]:
        """(name, reason) of files and moments that could not be used (valid after ``moments``)."""
        return list(self._skipped)

    def skipped_files(self) -> list[tuple[str, str]]:
        """(name, reason) of files (bag: messages, pauses) that could not become part of a moment."""
        self._load()
        return list(self._files_skipped)

    def moment(self, name: str) -> Moment:
        for m in self.all_moments():
            if m.name == name:
                return m
        raise KeyError(f"{self.location}: no moment {name!r}")

    def _folder_moments(self, rig: RigConfig) -> tuple[list[Moment], list[tuple[str, str]]]:
        skipped: list[tuple[str, str]] = []
        by_sensor = {s.name: self._stems(rig, s.name, skipped) for s in rig.sensors}
        stems = sorted(set().union(*by_sensor.values()), key=natural_key)
        moments = []
        for stem in stems:
            files = {n: f[stem] for n, f in by_sensor.items() if stem in f}
            missing = {n: f"no file {rig.sensor(n).folder}/{stem}.*" for n in by_sensor if n not in files}
            moments.append(Moment(stem, files, missing))
        return moments, skipped

    @staticmethod
    def _stems(rig: RigConfig, name: str, skipped: list[tuple[str, str]]) -> dict[str, Path]:
        """stem -> the sensor's file of that stem (the preferred format when there are several)."""
        folder, sensor = rig.folder(name), rig.sensor(name)
        if not folder.is_dir():
            raise InputError(
                f"{folder}: no folder for sensor {name} (sensors.{name}.folder in {rig.source}; "
                f"expected its {'images' if sensor.kind == 'camera' else 'scans'} as <stem>.<ext>)"
            )
        suffixes = IMAGE_SUFFIXES if sensor.kind == "camera" else tuple(supported_scan_suffixes())
        out: dict[str, list[Path]] = {}
        for f in folder.iterdir():
            if f.name.startswith(".") or not f.is_file():
                continue
            if f.suffix.lower() not in suffixes:
                skipped.append((f.stem, f"{sensor.folder}/{f.name}: unsupported file type {f.suffix!r}"))
            else:
                out.setdefault(f.stem, []).append(f)
        rank = {s: i for i, s in enumerate(PREFERENCE)}
        chosen = {}
        for stem, files in out.items():
            files.sort(key=lambda p: (rank.get(p.suffix.lower(), len(rank)), p.name))
            chosen[stem] = files[0]
            if len(files) > 1:
                log.warning("%s: %s has %d files (%s); using %s", folder, stem, len(files),
                            ", ".join(p.name for p in files), files[0].name)  # fmt: skip
        return chosen

    # -- reading ---------------------------------------------------------------------------------
    def _bag_reader(self) -> Any:
        if self._bag is None:
            from ilcc_graph.datasets.rig_bag import RigBag

            self._bag = RigBag(self.config())
        return self._bag

    def _locator(self, moment: Moment | str, sensor: str, kind: str) -> tuple[str, Any]:
        m = self.moment(moment) if isinstance(moment, str) else moment
        s = self.config().sensor(sensor)
        if s.kind != kind:
            raise ValueError(f"{sensor} is a {s.kind}, not a {kind}")
        if sensor not in m.files:
            raise InputError(
                f"{self.location}: moment {m.name} has no file of {sensor} ({m.missing.get(sensor)})"
            )
        return m.name, m.files[sensor]

    def read_scan(self, moment: Moment | str, lidar: str) -> Scan:
        """The scan of LiDAR ``lidar`` at ``moment``: points (N, 3) in that LiDAR's frame, metres.

        InputError naming the file (or bag, topic and time) and the problem."""
        name, loc = self._locator(moment, lidar, "lidar")
        if self.config().data.bag is not None:
            return self._bag_reader().read_scan(FrameRef(name, loc), None)
        return read_scan(loc, self.config().sensor(lidar).intensity_column)

    def read_image(self, moment: Moment | str, camera: str) -> np.ndarray:
        """The image of camera ``camera`` at ``moment``, (H, W, 3) BGR uint8; InputError as ``read_scan``."""
        name, loc = self._locator(moment, camera, "camera")
        if self.config().data.bag is not None:
            return self._bag_reader().read_image(FrameRef(name, None, loc))
        return read_image(loc)

    def image_size(self, moment: Moment | str, camera: str) -> tuple[int, int]:
        """(width, height) px of the camera's image at ``moment`` (from the file header where it can)."""
        name, loc = self._locator(moment, camera, "camera")
        reader = (
            self._bag_reader() if self.config().data.bag is not None else FolderSource(self.config().base_dir)
        )
        return reader.image_size(FrameRef(name, None, loc))

    def pair(self, camera: str, lidar: str) -> RigPair:
        """Camera ``camera`` and LiDAR ``lidar`` as a single-pair frame source (their shared moments)."""
        return RigPair(self, camera, lidar)

    def ground_truth(self) -> RigGroundTruth | None:
        """A simulated rig's truth (``rig_ground_truth.yaml`` beside the rig file; a single-pair set's
        ``ground_truth.yaml`` as the rig of ``lidar`` and ``camera``), else None."""
        rig = self.config()
        if (rig.base_dir / RIG_GROUND_TRUTH_FILE).is_file():
            return read_rig_ground_truth(rig.base_dir / RIG_GROUND_TRUTH_FILE)
        pair = self._pair_truth_file(rig)
        if pair is None:
            return None
        from ilcc_graph.io import read_ground_truth

        gt = read_ground_truth(pair)
        T = {"lidar": np.eye(4), "camera": np.linalg.inv(gt.T_cam_lidar)}
        return RigGroundTruth("lidar", T, dict(gt.T_lidar_board), {}, dict(gt.extra))

    def _pair_truth_file(self, rig: RigConfig) -> Path | None:
        if rig.names != ("lidar", "camera"):
            return None
        bag = rig.bag_path()
        if bag is None:
            p = rig.base_dir / GROUND_TRUTH_FILE
        else:
            stem = bag.with_suffix("") if bag.is_file() else bag
            p = stem.parent / f"{stem.name}.ground_truth.yaml"
        return p if p.is_file() else None


class RigPair(FrameSource):
    """One camera and one LiDAR of a rig as a single-pair frame source over their moments (names kept),
    so the single-pair stages and strategies run on any pair of a rig."""

    def __init__(self, rig: RigSource, camera: str, lidar: str) -> None:
        self.rig, self.camera, self.lidar = rig, camera, lidar
        self.label = f"{rig.label}:{camera}+{lidar}"
        self.location = rig.location
        self._config = rig.config().pair_config(camera, lidar)  # ValueError: not a camera and a LiDAR
        self._skipped: list[tuple[str, str]] = []

    def config(self) -> Config:
        return self._config

    def frames(self, require_scan: bool = True, require_image: bool = True) -> list[FrameRef]:
        refs, self._skipped = [], []
        for m in self.rig.all_moments():
            scan, image = m.files.get(self.lidar), m.files.get(self.camera)
            parts = ((self.lidar, require_scan, scan), (self.camera, require_image, image))
            lacking = [s for s, need, loc in parts if need and loc is None]
            if lacking:
                self._skipped.append(
                    (m.name, "; ".join(f"{s}: {m.missing.get(s, 'no file')}" for s in lacking))
                )
            elif scan is not None or image is not None:
                refs.append(FrameRef(m.name, scan, image))
        if not refs:
            detail = "; ".join(f"{n}: {r}" for n, r in self._skipped[:3]) or "no files"
            raise InputError(
                f"{self.rig.location}: no moment has files of {self.camera} and {self.lidar} ({detail})"
            )
        return refs

    def skipped(self) -> list[tuple[str, str]]:
        return self.rig.skipped_files() + self._skipped

    def read_scan(self, ref: FrameRef, config: Config) -> Scan:
        return self.rig.read_scan(self.rig.moment(ref.name), self.lidar)

    def read_image(self, ref: FrameRef) -> np.ndarray:
        return self.rig.read_image(self.rig.moment(ref.name), self.camera)

    def image_size(self, ref: FrameRef) -> tuple[int, int]:
        return self.rig.image_size(self.rig.moment(ref.name), self.camera)

    def ground_truth(self) -> GroundTruth | None:
        """The pair's truth from the rig's: ``T_cam_lidar`` and the boards in the LiDAR's frame."""
        gt = self.rig.ground_truth()
        if gt is None:
            return None
        boards = {m: gt.T_sensor_board(self.lidar, m) for m in gt.T_ref_board}
        return GroundTruth(gt.T_a_b(self.camera, self.lidar), boards, {"rig": self.rig.location})
