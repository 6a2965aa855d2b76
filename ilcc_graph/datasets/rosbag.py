"""ROS 1 and ROS 2 bags as a frame source, read with ``rosbags`` (no ROS install needed).

A bag is a ROS 1 ``.bag`` file, a ROS 2 bag folder (``metadata.yaml``) or one ``.db3`` / ``.mcap``
file. Frames come from one ``sensor_msgs/PointCloud2`` topic and one ``sensor_msgs/Image`` or
``CompressedImage`` topic (the only one of each by default); scans and images pair by header stamp
within ``sync_tolerance``; a walk-and-pause recording gives one frame per still pause. The camera
comes from the config file, else from ``sensor_msgs/CameraInfo``. docs/datasets.md has every rule
and threshold. Readers are opened lazily, once per process (the source is picklable).
"""

from __future__ import annotations

import logging
import os
import struct
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np

from ilcc_graph.config import Config, parse_config
from ilcc_graph.datasets.frame_source import FrameRef, FrameSource
from ilcc_graph.datasets.ros_messages import (
    CLOUD,
    COMPRESSED,
    IMAGE,
    INFO,
    camera_section,
    check_image_format,
    decode_cloud,
    decode_image,
    image_message_size,
    sweep_offset,
)
from ilcc_graph.datasets.timeline import (
    IMAGE_STILL,
    LIDAR_STILL,
    MOTION_STEP_S,
    Stream,
    image_change,
    lidar_change,
    motion_image,
    nearest,
    pair_by_time,
    range_image,
    unpaired,
)
from ilcc_graph.errors import InputError, quote
from ilcc_graph.io import GroundTruth, read_ground_truth, read_yaml
from ilcc_graph.types import Scan

log = logging.getLogger(__name__)

__all__ = ["BagSource", "is_bag"]

SELECT = ("auto", "pauses", "all")


def is_bag(path: Path) -> bool:
    """A ``.bag``, ``.db3`` or ``.mcap`` file, or a folder with ``metadata.yaml`` (ROS 2)."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.is_file() and path.suffix.lower() in (".bag", ".db3", ".mcap")


_OPEN: dict[tuple, Any] = {}  # per process: (path, mtime, size) -> open AnyReader
#: per process, at most one: the image message ``header_size`` read, kept for the ``read_image`` that
#: follows it (``run.stages.observe_image``), so that the message is read once
_KEPT: dict[tuple, tuple[Any, str]] = {}
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_OPEN.clear)  # a forked worker opens its own
    os.register_at_fork(after_in_child=_KEPT.clear)


class BagSource(FrameSource):
    """A ROS 1 or ROS 2 bag; frames are scans (with their paired images), named by bag time."""

    def __init__(
        self,
        path: str | Path,
        *,
        config: str | Path | None = None,
        lidar_topic: str | None = None,
        image_topic: str | None = None,
        camera_info_topic: str | None = None,
        sync_tolerance: float = 0.05,
        min_pause: float = 1.0,
        select: str = "auto",
        max_frames: int = 60,
    ) -> None:
        self.path = Path(path)
        if not is_bag(self.path):
            raise InputError(f"{self.path}: not a ROS bag (.bag, .db3, .mcap, a folder with metadata.yaml)")
        for name, v in zip(
            ("sync_tolerance", "min_pause", "max_frames"), (sync_tolerance, min_pause, max_frames)
        ):
            if not v > 0:
                raise InputError(f"{self.path}: {name} must be > 0, got {quote(v)}")
        if select not in SELECT:
            raise InputError(f"{self.path}: select must be one of {SELECT}, got {quote(select)}")
        self.config_path = None if config is None else Path(config)
        self.topics = {"lidar": lidar_topic, "image": image_topic, "info": camera_info_topic}
        self.tolerance, self.min_pause = float(sync_tolerance), float(min_pause)
        self.select, self.max_frames = select, int(max_frames)
        self.label = self.path.stem if self.path.is_file() else self.path.resolve().name
        self.location = str(self.path)
        self.streams: dict[str, Stream] = {}
        self._config: Config | None = None
        self._skipped: list[tuple[str, str]] = []
        self._frames: dict[tuple[bool, bool], tuple[list[FrameRef], list[tuple[str, str]]]] = {}
        self._start_ns = 0

    # -- reading ---------------------------------------------------------------------------------
    def _reader(self) -> Any:
        st = self.path.stat()
        key = (str(self.path.resolve()), st.st_mtime_ns, st.st_size)
        if key not in _OPEN:
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore

            reader = AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            self._guard(reader.open)
            while len(_OPEN) >= 4:
                _OPEN.pop(next(iter(_OPEN))).close()
            _OPEN[key] = reader
        return _OPEN[key]

    def _guard(self, fn: Any, *args: Any) -> Any:
        """``fn(*args)`` with rosbags' errors on a damaged bag turned into an InputError."""
        from rosbags.highlevel import AnyReaderError
        from rosbags.rosbag1 import ReaderError as Error1
        from rosbags.rosbag2 import ReaderError as Error2
        from rosbags.serde import SerdeError

        try:
            return fn(*args)
        except (AnyReaderError, Error1, Error2, SerdeError, OSError, KeyError, struct.error) as err:
            raise InputError(f"{self.path}: not a readable ROS bag ({err})") from None

    def _messages(self, topics: list[str], t_ns: int | None = None) -> Any:
        """(topic, bag time ns, message) of ``topics`` in bag order (only at ``t_ns`` when given)."""
        r = self._reader()
        conns = [c for c in r.connections if c.topic in topics]
        if not conns:  # rosbags reads every topic when given none
            return
        it = self._guard(r.messages, conns, t_ns, None if t_ns is None else t_ns + 1)
        while (item := self._guard(next, it, None)) is not None:
            yield item[0].topic, item[1], self._guard(r.deserialize, item[2], item[0].msgtype)

    def _where(self, topic: str, t_ns: int, name: str | None = None) -> str:
        """A message's place for messages: the bag, the topic, the frame's name and the bag time."""
        return f"{self.path}:{topic}{'' if name is None else '@' + name} (bag time {t_ns} ns)"

    def _one(self, locator: tuple[str, int], name: str) -> tuple[Any, str]:
        for _, _, msg in self._messages([locator[0]], locator[1]):
            return msg, self._where(locator[0], locator[1], name)
        raise InputError(f"{self.path}: no message on {locator[0]} at {locator[1]} ns (bag changed?)")

    def read_scan(self, ref: FrameRef, config: Config) -> Scan:
        return decode_cloud(*self._one(ref.scan, ref.name))

    def read_image(self, ref: FrameRef) -> np.ndarray:
        """The image message decoded, its size checked first (``ros_messages.image_message_size``):
        InputError naming the bag, topic and time when it is damaged or truncated."""
        kept = _KEPT.pop((str(self.path), *ref.image), None)
        return decode_image(*(kept or self._one(ref.image, ref.name)))

    def image_location(self, ref: FrameRef) -> str:
        topic, t_ns = ref.image
        return self._where(topic, t_ns, ref.name)

    def header_size(self, ref: FrameRef) -> tuple[int, int] | None:
        """(width, height) the image message declares, nothing decoded (``image_message_size``); the
        message is kept for the ``read_image`` of the same frame that follows."""
        msg, where = self._one(ref.image, ref.name)
        size = image_message_size(msg, where)
        _KEPT.clear()
        key = (str(self.path), *ref.image)
        _KEPT[key] = (msg, where)
        return size

    def image_size(self, ref: FrameRef) -> tuple[int, int]:
        """(width, height) of the frame's image: declared by the message, else decoded (nothing kept)."""
        msg, where = self._one(ref.image, ref.name)
        if (size := image_message_size(msg, where)) is not None:
            return size
        h, w = decode_image(msg, where).shape[:2]
        return int(w), int(h)

    # -- topics and config -------------------------------------------------------------------------
    @overload
    def _topic(self, role: str, types: tuple[str, ...], required: Literal[True] = True) -> str: ...
    @overload
    def _topic(self, role: str, types: tuple[str, ...], required: bool) -> str | None: ...
    def _topic(self, role: str, types: tuple[str, ...], required: bool = True) -> str | None:
        """The topic given for ``role``, else the only one of those types (info: the image's namespace)."""
        found = {name: info.msgtype for name, info in self._guard(lambda: self._reader().topics).items()}
        listing = ", ".join(f"{n} ({t})" for n, t in sorted(found.items())) or "none"
        if (given := self.topics[role]) is not None:
            if found.get(given) not in types:
                what = "no such topic" if given not in found else f"its type is {found[given]}"
                raise InputError(f"{self.path}: {role} topic {given}: {what}; topics: {listing}")
            return given
        cands = sorted(n for n, t in found.items() if t in types)
        if role == "info" and len(cands) > 1 and self.topics["image"]:
            ns = [c for c in cands if self.topics["image"].startswith(c.rsplit("/", 1)[0] + "/")]
            cands = sorted(ns, key=len)[-1:] or cands
        if len(cands) == 1 or (not cands and not required):
            return cands[0] if cands else None
        flag = {"lidar": "--lidar-topic", "image": "--image-topic", "info": "camera_info_topic"}[role]
        what = "no" if not cands else "several"
        raise InputError(
            f"{self.path}: {what} {' or '.join(types)} topic (choose with {flag}); topics: {listing}"
        )

    def _config_file(self) -> Path:
        """--config, else ``<bag>.yaml`` beside the bag, ``config.yaml`` inside a bag folder, beside it."""
        if self.config_path is not None:
            return self.config_path
        p = self.path
        cands = [p.with_suffix(".yaml") if p.is_file() else p.parent / f"{p.name}.yaml"]
        cands += ([p / "config.yaml"] if p.is_dir() else []) + [p.parent / "config.yaml"]
        if found := next((c for c in cands if c.is_file()), None):
            return found
        raise InputError(
            f"{p}: no config for this bag (looked for {', '.join(map(str, cands))}; or --config)"
        )

    def config(self) -> Config:
        if self._config is not None:
            return self._config
        path = self._config_file()
        d, note = read_yaml(path), ""
        if isinstance(d, dict) and "board" in d and "camera" not in d:  # camera from CameraInfo
            self.topics["image"] = self._topic("image", (IMAGE, COMPRESSED), required=False)
            info = self._topic("info", (INFO,), required=False)
            msg = next((m for _, _, m in self._messages([info])), None) if info else None
            if msg is None:
                raise InputError(f"{path}: no camera section, and {self.path} has no CameraInfo message")
            note = f" (the camera section comes from {self.path}:{info})"
            rectified = "rect" in (self.topics["image"] or "")
            d = dict(d, camera=camera_section(msg, f"{self.path}:{info}", rectified))
        try:
            self._config = parse_config(d, str(path), path.parent)
        except InputError as err:
            raise InputError(f"{err}{note}" if ": camera" in str(err) else str(err)) from None
        return self._config

    def ground_truth(self) -> GroundTruth | None:
        """The simulated bag's truth (``<bag>.ground_truth.yaml`` beside it), else None."""
        p = self.path.with_suffix("") if self.path.is_file() else self.path
        gt = p.parent / f"{p.name}.ground_truth.yaml"
        return read_ground_truth(gt) if gt.is_file() else None

    # -- frames ----------------------------------------------------------------------------------
    def survey(self) -> dict[str, Stream]:
        """Read the bag once: stamps of every scan and image, and the motion between samples."""
        if self.streams:
            return self.streams
        lidar = self._topic("lidar", (CLOUD,))
        image = self._topic("image", (IMAGE, COMPRESSED), required=False)
        self.topics.update(lidar=lidar, image=image)
        streams = {lidar: Stream(lidar, LIDAR_STILL)} | ({image: Stream(image, IMAGE_STILL)} if image else {})
        motion = image or lidar  # the camera decides when there is one (docs/datasets.md)
        self._record(streams, {lidar}, {motion}, lambda: self.config().lidar)
        if not streams[lidar].bag_ns:
            raise InputError(f"{self.path}: no message on {lidar}")
        self._set_time_base(list(streams.values()), "no scan has an image")
        self._start_ns = int(self._guard(lambda: self._reader().start_time))
        self.streams = streams
        return streams

    def _record(self, streams: dict[str, Stream], clouds: set[str], motion: set[str], model: Any) -> None:
        """Fill ``streams`` (topic -> Stream) in one pass over the bag: every message's bag time, header
        stamp and sweep offset (``clouds``: PointCloud2 topics), and the motion between samples of each
        ``motion`` topic (``model()``: the LiDAR model giving rings to a cloud without them)."""
        lasts: dict[str, tuple[int, Any]] = {}
        damaged: list[str] = []
        for topic, t, msg in self._messages(list(streams)):
            s, where, at = streams[topic], f"{self.path}:{topic}", self._where(topic, t)
            s.bag_ns.append(t)
            s.stamp_ns.append(int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec))
            try:  # a damaged cloud: no sweep offset and no motion sample; its frame says so when read
                s.offset_s.append(sweep_offset(msg, at) if topic in clouds else 0.0)
            except InputError as err:
                s.offset_s.append(0.0)
                damaged.append(str(err))
                continue
            last = lasts.get(topic)
            if topic not in motion or (last is not None and t - last[0] < MOTION_STEP_S * 1e9):
                continue
            if topic not in clouds:
                check_image_format(msg, where)  # the topic's images cannot be read: said for the bag
            try:  # one damaged message: no motion sample; its frame says so
                sig = self._motion_signal(msg, at, topic in clouds, model)
            except InputError as err:
                damaged.append(str(err))
                continue
            if last is not None:
                s.changes.append((lidar_change if topic in clouds else image_change)(last[1], sig))
            s.samples.append(len(s.bag_ns) - 1)
            lasts[topic] = (t, sig)
        if damaged:
            more = f" (and {len(damaged) - 1} more)" if len(damaged) > 1 else ""
            log.warning("damaged message(s), left out of the motion measure: %s%s", damaged[0], more)

    @staticmethod
    def _motion_signal(msg: Any, where: str, cloud: bool, model: Any) -> np.ndarray:
        """What the motion between samples is measured on: a cloud's range image (rings from
        ``model()`` when it has none) or an image's reduced grey image; InputError when damaged."""
        if cloud:
            scan = decode_cloud(msg, where)
            ring = model().ring_from_points(scan.points) if scan.ring is None else scan.ring
            return range_image(scan.points, ring)
        return motion_image(decode_image(msg, where))

    def _set_time_base(self, streams: list[Stream], what: str) -> None:
        """Header stamps, or bag times when stamps are zero or when no other stream pairs with the first
        by header stamps while some pair by bag time (``what``: the warning's wording)."""
        base, why = "header", ""
        others = [s for s in streams[1:] if s.bag_ns]
        if any(min(s.stamp_ns) == 0 for s in streams if s.stamp_ns):
            base, why = "bag", "zero header stamps"
        elif others:
            first = streams[0]
            pairs = {b: [pair_by_time(first.times(b), s.times(b), self.tolerance) for s in others]
                     for b in ("header", "bag")}  # fmt: skip
            if not any(pairs["header"]) and any(pairs["bag"]):
                base, why = "bag", f"{what} within {self.tolerance} s by header stamps"
        if why:
            log.warning("%s: %s; scans and images pair by bag (receive) time", self.path, why)
        for s in streams:
            s.time_base = base

    def _name(self, t_ns: float) -> str:
        return f"t{(t_ns - self._start_ns) * 1e-9:010.3f}"

    def frames(self, require_scan: bool = True, require_image: bool = True) -> list[FrameRef]:
        """Scans (with their images) chosen by the rule of docs/datasets.md: one per still pause of a
        walk-and-pause recording, else every scan up to ``max_frames``."""
        if (key := (require_scan, require_image)) in self._frames:
            refs, self._skipped = self._frames[key]
            return list(refs)
        streams = self.survey()
        lidar_topic = self.topics["lidar"]
        assert lidar_topic is not None  # survey() sets it
        lid, img = streams[lidar_topic], streams.get(self.topics["image"] or "")
        if img is None and require_image:
            raise InputError(f"{self.path}: no Image or CompressedImage topic; topics: {', '.join(streams)}")
        ts, ti = lid.times(), (img.times() if img else np.zeros(0))
        pairs = pair_by_time(ts, ti, self.tolerance)
        if require_image and not pairs:
            gap = float(np.abs(ti[nearest(ti, ts)] - ts).min()) if len(ti) else float("inf")
            raise InputError(f"{self.path}: no scan has an image within {self.tolerance} s (the closest are "
                             f"{gap:.3f} s apart); check the topics or --sync-tolerance")  # fmt: skip
        scans = [i for i in range(len(ts)) if i in pairs or not require_image]
        motion = img or lid
        runs, moving = motion.runs(), max(motion.changes, default=0.0) > motion.still
        pauses = [(a, b) for a, b in runs if b - a >= self.min_pause]
        self._skipped = []
        if self.select == "pauses" or (self.select == "auto" and moving and pauses):
            chosen = []
            for a, b in pauses:
                inside = [i for i in scans if a <= ts[i] <= b and (i not in pairs or a <= ti[pairs[i]] <= b)]
                if inside:
                    chosen.append(min(inside, key=lambda i: abs(ts[i] - 0.5 * (a + b))))
                else:
                    why = f"no scan with an image within {self.tolerance} s in this still pause"
                    self._skipped.append((f"pause-{self._name(a * 1e9)}", why))
            how = f"one per still pause of >= {self.min_pause} s ({len(pauses)})"
        else:
            chosen = scans
            if len(chosen) > self.max_frames:
                chosen = [
                    scans[k]
                    for k in sorted({round(x) for x in np.linspace(0, len(scans) - 1, self.max_frames)})
                ]
            how = "as asked" if self.select == "all" else "no motion" if not moving else "no still pause"
            how = f"every scan ({how}; at most {self.max_frames})"
            if require_image:
                self._skipped = unpaired(ts, ti, pairs, self.tolerance, [self._name(t) for t in lid.bag_ns])
        log.info(
            "%s: %d scans on %s, %d images on %s, %d pairs within %g s (%s time); %s: %d frames",
            self.path, len(ts), lid.topic, len(ti), img.topic if img else "-", len(pairs), self.tolerance,
            lid.time_base, how, len(chosen),
        )  # fmt: skip
        image = (
            (lambda i: (img.topic, img.bag_ns[pairs[i]]) if i in pairs else None) if img else (lambda i: None)
        )
        refs = [FrameRef(self._name(lid.bag_ns[i]), (lid.topic, lid.bag_ns[i]), image(i)) for i in chosen]
        self._frames[key] = (refs, self._skipped)
        return list(refs)

    def skipped(self) -> list[tuple[str, str]]:
        return list(self._skipped)
