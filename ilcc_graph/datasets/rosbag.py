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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ilcc_graph.cameras import camera_section_from_ros
from ilcc_graph.config import Config, parse_config
from ilcc_graph.datasets.base import FrameRef, FrameSource
from ilcc_graph.errors import InputError
from ilcc_graph.io import read_ground_truth, read_yaml
from ilcc_graph.io.scans import find_fields, make_scan
from ilcc_graph.types import Scan

log = logging.getLogger(__name__)

__all__ = ["BagSource", "Stream", "camera_section", "decode_cloud", "decode_image", "is_bag", "still_runs"]

CLOUD, IMAGE, COMPRESSED, INFO = (
    f"sensor_msgs/msg/{t}" for t in ("PointCloud2", "Image", "CompressedImage", "CameraInfo")
)
SELECT = ("auto", "pauses", "all")
MOTION_STEP_S = 0.09  # motion is measured between samples at least this far apart (<= ~10 Hz)
IMAGE_WIDTH = 320  # grey images are shrunk to about this width to measure motion
IMAGE_LEVEL, IMAGE_STILL = 10, 0.002  # a pixel changed by > 10 grey levels; still: <= 0.2 % changed
LIDAR_STEP_M, LIDAR_STILL = 0.10, 0.003  # a cell changed by > 10 cm and 3 %; still: <= 0.3 % changed
AZIMUTH_BINS = 360
_PF = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
#: encoding -> (bytes per channel, channels, OpenCV conversion to BGR or None)
_ENCODINGS = {"bgr8": (1, 3, None), "rgb8": (1, 3, "RGB2BGR"), "bgra8": (1, 4, "BGRA2BGR"),
              "rgba8": (1, 4, "RGBA2BGR"), "mono8": (1, 1, "GRAY2BGR"),
              "mono16": (2, 1, "GRAY2BGR")}  # fmt: skip


def is_bag(path: Path) -> bool:
    """A ``.bag``, ``.db3`` or ``.mcap`` file, or a folder with ``metadata.yaml`` (ROS 2)."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.is_file() and path.suffix.lower() in (".bag", ".db3", ".mcap")


# ----------------------------------------------------------------------------------------------
# Messages -> plain data


def _records(msg: Any, where: str) -> np.ndarray:
    """A PointCloud2's points as a structured array, from its own field list (any layout)."""
    end = ">" if msg.is_bigendian else "<"
    step, h, w = int(msg.point_step), int(msg.height), int(msg.width)
    if step <= 0 or h < 0 or w < 0:
        raise InputError(f"{where}: point_step {step}, height {h}, width {w}: not a point layout")
    names, formats, offsets = [], [], []
    for f in msg.fields:
        if f.datatype not in _PF:
            raise InputError(f"{where}: field {f.name!r} has unknown PointField datatype {f.datatype}")
        if not f.name or f.name in names:
            continue
        fmt = np.dtype(end + _PF[f.datatype])
        names.append(f.name)
        formats.append(fmt if int(f.count) <= 1 else np.dtype((fmt, (int(f.count),))))
        offsets.append(int(f.offset))
        if offsets[-1] + formats[-1].itemsize > step:
            raise InputError(f"{where}: field {f.name!r} at offset {f.offset} overruns point_step {step}")
    row = int(msg.row_step) or w * step
    data = np.asarray(msg.data, dtype=np.uint8)
    if row < w * step or data.size < (h - 1) * row + w * step:
        raise InputError(f"{where}: {data.size} data bytes do not hold {h} x {w} points of {step} bytes")
    rows = np.lib.stride_tricks.as_strided(data, (h, w * step), (row, 1)) if h else data[:0]
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    try:
        return np.ascontiguousarray(rows).reshape(-1).view(dt)
    except ValueError as err:  # fields that overlap or do not fit the record
        raise InputError(f"{where}: the point fields do not make a record of {step} bytes ({err})") from None


def _column(rec: np.ndarray, name: str) -> np.ndarray:
    a = rec[name]
    return a[:, 0] if a.ndim > 1 else a


def decode_cloud(msg: Any, where: str) -> Scan:
    """A PointCloud2 as a Scan: fields by name through ``io.scans``' aliases (x y z, intensity or
    reflectivity, ring or laser_id); NaN and (0, 0, 0) points ("no return") dropped."""
    rec = _records(msg, where)
    names = list(rec.dtype.names or ())
    cols = find_fields(where, names)  # type: ignore[arg-type]
    xyz = np.empty((len(rec), 3))
    for k, axis in enumerate("xyz"):
        xyz[:, k] = _column(rec, names[cols[axis]])  # type: ignore[index]
    xyz[(xyz[:, 0] == 0) & (xyz[:, 1] == 0) & (xyz[:, 2] == 0)] = np.nan
    ring = None if cols["ring"] is None else _column(rec, names[cols["ring"]])
    return make_scan(where, xyz, _column(rec, names[cols["intensity"]]), ring)  # type: ignore[index, arg-type]


def sweep_offset(msg: Any, where: str) -> float:
    """Seconds from a PointCloud2's header stamp to the middle of its sweep: the middle of the per-point
    ``t`` (integer: ns) or ``time`` (float: s) range; 0 without one or when it spans over 0.5 s."""
    names = [f.name for f in msg.fields]
    name = next((n for n in names if n.lower() in ("t", "time")), None)
    if name is None or not int(msg.width) * int(msg.height):
        return 0.0
    rec = _records(msg, where)
    t = _column(rec, name).astype(np.float64) * (1e-9 if rec.dtype[name].kind in "iu" else 1.0)
    lo, hi = float(np.nanmin(t)), float(np.nanmax(t))
    return 0.5 * (lo + hi) if np.isfinite(lo + hi) and hi - lo <= 0.5 and abs(lo + hi) <= 1.0 else 0.0


def decode_image(msg: Any, where: str) -> np.ndarray:
    """An Image (bgr8, rgb8, mono8, mono16, bgra8, rgba8) or CompressedImage as (H, W, 3) BGR uint8."""
    import cv2

    if hasattr(msg, "format"):  # CompressedImage: jpeg / png
        img = None
        if "compresseddepth" not in msg.format.lower():
            img = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise InputError(f"{where}: cannot decode the compressed image (format {msg.format!r})")
        return img
    enc = _ENCODINGS.get(msg.encoding.lower())
    if enc is None:
        raise InputError(
            f"{where}: image encoding {msg.encoding!r} is not supported ({', '.join(_ENCODINGS)})"
        )
    size, ch, conversion = enc
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * ch * size or data.size < h * step:
        raise InputError(f"{where}: {data.size} data bytes do not hold a {w} x {h} {msg.encoding} image")
    px = data[: h * step].reshape(h, step)[:, : w * ch * size]
    if size == 2:  # 16 bits scaled to 8 as io.read_image does
        px = np.round(px.copy().view(">u2" if msg.is_bigendian else "<u2") / 257.0).astype(np.uint8)
    px = np.array(px).reshape(h, w, ch)  # a copy: the message's buffer is read-only
    return px if conversion is None else cv2.cvtColor(px, getattr(cv2, f"COLOR_{conversion}"))


def _field(msg: Any, name: str) -> Any:
    """A CameraInfo field by its ROS 2 name (``k``) or its ROS 1 name (``K``)."""
    return getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper())


def camera_section(info: Any, where: str, rectified: bool = False) -> dict[str, Any]:
    """A CameraInfo as our config's camera section (the camera model that reads its distortion_model,
    ``cameras.camera_section_from_ros``). rectified: the image topic is rectified (P, no distortion)."""
    model = info.distortion_model.lower()
    K = np.asarray(_field(info, "k"), dtype=np.float64).reshape(3, 3)
    dist = [float(v) for v in _field(info, "d")]
    if (info.binning_x or 1) > 1 or (info.binning_y or 1) > 1 or info.roi.width or info.roi.height:
        raise InputError(f"{where}: CameraInfo with binning or a region of interest is not supported")
    if rectified:
        K, dist, model = np.asarray(_field(info, "p"), dtype=np.float64).reshape(3, 4)[:, :3], [], "plumb_bob"
    try:
        return camera_section_from_ros(model, info.width, info.height, K, dist)
    except ValueError as e:
        raise InputError(f"{where}: {e}") from None


# ----------------------------------------------------------------------------------------------
# Motion and stillness (plain arrays in, intervals out)


def _grey(img: np.ndarray) -> np.ndarray:
    import cv2

    f = max(1, round(img.shape[1] / IMAGE_WIDTH))  # area averaging: noise / f, board motion kept
    small = cv2.resize(img, (img.shape[1] // f, img.shape[0] // f), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_BGR2GRAY)


def _image_change(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of pixels whose grey level changed by more than IMAGE_LEVEL."""
    return float(np.mean(np.abs(a.astype(np.int16) - b) > IMAGE_LEVEL)) if a.shape == b.shape else 1.0


def _range_image(points: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(beams, AZIMUTH_BINS) nearest range per beam and 1-degree azimuth cell; inf where empty."""
    az = np.arctan2(points[:, 1], points[:, 0])
    col = np.minimum((az + np.pi) * (AZIMUTH_BINS / (2 * np.pi)), AZIMUTH_BINS - 1).astype(np.int64)
    key = rows.astype(np.int64) * AZIMUTH_BINS + col
    order = np.argsort(key, kind="stable")
    k = key[order]
    start = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
    img = np.full((int(rows.max()) + 1 if len(rows) else 1) * AZIMUTH_BINS, np.inf)
    img[k[start]] = np.minimum.reduceat(np.linalg.norm(points, axis=1)[order], start)
    return img.reshape(-1, AZIMUTH_BINS)


def _lidar_change(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of cells seen in both scans whose range changed by more than LIDAR_STEP_M and 3 %."""
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    both = np.isfinite(a) & np.isfinite(b)
    if not both.any():
        return 1.0
    d = np.abs(a[both] - b[both])
    return float(np.mean(d > np.maximum(LIDAR_STEP_M, 0.03 * np.minimum(a[both], b[both]))))


def still_runs(times: np.ndarray, changes: np.ndarray, threshold: float) -> list[tuple[float, float]]:
    """Maximal intervals [t_a, t_b] (a < b) over which every step's change is <= threshold.

    changes[k] is the change from sample k to sample k + 1 (len(times) - 1 values).
    """
    runs, start = [], 0
    for k, c in enumerate(changes):
        if c > threshold:
            if k > start:
                runs.append((float(times[start]), float(times[k])))
            start = k + 1
    if len(times) - 1 > start:
        runs.append((float(times[start]), float(times[-1])))
    return runs


# ----------------------------------------------------------------------------------------------
# The source

_OPEN: dict[tuple, Any] = {}  # per process: (path, mtime, size) -> open AnyReader
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_OPEN.clear)  # a forked worker opens its own


@dataclass
class Stream:
    """One topic's messages: bag (receive) times, header stamps (+ sweep offsets), the time base used
    (``header`` or ``bag``), and the motion between samples (``changes[k]``: sample k to k + 1)."""

    topic: str
    still: float
    bag_ns: list[int] = field(default_factory=list)
    stamp_ns: list[int] = field(default_factory=list)
    offset_s: list[float] = field(default_factory=list)
    samples: list[int] = field(default_factory=list)
    changes: list[float] = field(default_factory=list)
    time_base: str = "header"

    def times(self, base: str | None = None) -> np.ndarray:
        """Seconds of every message in ``base`` (default: the stream's time base)."""
        if (base or self.time_base) == "bag":
            return np.asarray(self.bag_ns, dtype=np.float64) * 1e-9
        return np.asarray(self.stamp_ns, dtype=np.float64) * 1e-9 + np.asarray(self.offset_s)

    def runs(self) -> list[tuple[float, float]]:
        """Still intervals of this stream (seconds, in its time base)."""
        return still_runs(self.times()[self.samples], np.asarray(self.changes), self.still)


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
                raise InputError(f"{self.path}: {name} must be > 0, got {v!r}")
        if select not in SELECT:
            raise InputError(f"{self.path}: select must be one of {SELECT}, got {select!r}")
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

    def _one(self, locator: tuple[str, int], name: str) -> tuple[Any, str]:
        for _, _, msg in self._messages([locator[0]], locator[1]):
            return msg, f"{self.path}:{locator[0]}@{name}"
        raise InputError(f"{self.path}: no message on {locator[0]} at {locator[1]} ns (bag changed?)")

    def read_scan(self, ref: FrameRef, config: Config) -> Scan:
        return decode_cloud(*self._one(ref.scan, ref.name))

    def read_image(self, ref: FrameRef) -> np.ndarray:
        return decode_image(*self._one(ref.image, ref.name))

    # -- topics and config -------------------------------------------------------------------------
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

    def ground_truth(self):  # noqa: ANN201 - io.GroundTruth | None
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
        last: tuple[int, Any] | None = None
        for topic, t, msg in self._messages(list(streams)):
            s, where = streams[topic], f"{self.path}:{topic}"
            s.bag_ns.append(t)
            s.stamp_ns.append(int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec))
            s.offset_s.append(sweep_offset(msg, where) if topic == lidar else 0.0)
            if topic != motion or (last is not None and t - last[0] < MOTION_STEP_S * 1e9):
                continue
            if topic == lidar:
                scan = decode_cloud(msg, where)
                ring = self.config().lidar.ring_from_points(scan.points) if scan.ring is None else scan.ring
                sig = _range_image(scan.points, ring)
            else:
                sig = _grey(decode_image(msg, where))
            if last is not None:
                s.changes.append((_lidar_change if topic == lidar else _image_change)(last[1], sig))
            s.samples.append(len(s.bag_ns) - 1)
            last = (t, sig)
        if not streams[lidar].bag_ns:
            raise InputError(f"{self.path}: no message on {lidar}")
        base, why = "header", ""
        if any(min(s.stamp_ns) == 0 for s in streams.values() if s.stamp_ns):
            base, why = "bag", "zero header stamps"
        elif image and streams[image].bag_ns:
            lid, img = streams[lidar], streams[image]
            if not _pairs(lid.times(), img.times(), self.tolerance) and _pairs(
                lid.times("bag"), img.times("bag"), self.tolerance
            ):
                base, why = "bag", f"no scan has an image within {self.tolerance} s by header stamps"
        if why:
            log.warning("%s: %s; scans and images pair by bag (receive) time", self.path, why)
        for s in streams.values():
            s.time_base = base
        self._start_ns = int(self._guard(lambda: self._reader().start_time))
        self.streams = streams
        return streams

    def _name(self, t_ns: float) -> str:
        return f"t{(t_ns - self._start_ns) * 1e-9:010.3f}"

    def frames(self, require_scan: bool = True, require_image: bool = True) -> list[FrameRef]:
        """Scans (with their images) chosen by the rule of docs/datasets.md: one per still pause of a
        walk-and-pause recording, else every scan up to ``max_frames``."""
        if (key := (require_scan, require_image)) in self._frames:
            refs, self._skipped = self._frames[key]
            return list(refs)
        streams = self.survey()
        lid, img = streams[self.topics["lidar"]], streams.get(self.topics["image"] or "")
        if img is None and require_image:
            raise InputError(f"{self.path}: no Image or CompressedImage topic; topics: {', '.join(streams)}")
        ts, ti = lid.times(), (img.times() if img else np.zeros(0))
        pairs = _pairs(ts, ti, self.tolerance)
        if require_image and not pairs:
            gap = float(np.abs(ti[_nearest(ti, ts)] - ts).min()) if len(ti) else float("inf")
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
                self._skipped = _unpaired(ts, ti, pairs, self.tolerance, [self._name(t) for t in lid.bag_ns])
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


def _nearest(ref: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Index into ``ref`` (non-empty) of the value nearest to each ``q``."""
    order = np.argsort(ref, kind="stable")
    r = ref[order]
    hi = np.clip(np.searchsorted(r, q), 0, len(r) - 1)
    lo = np.maximum(hi - 1, 0)
    return order[np.where(np.abs(q - r[lo]) <= np.abs(r[hi] - q), lo, hi)]


def _pairs(ts: np.ndarray, ti: np.ndarray, tol: float) -> dict[int, int]:
    """Scan index -> image index: mutual nearest neighbours in time at most ``tol`` apart."""
    if not len(ts) or not len(ti):
        return {}
    near_i, near_s = _nearest(ti, ts), _nearest(ts, ti)
    return {i: int(j) for i, j in enumerate(near_i) if near_s[j] == i and abs(ti[j] - ts[i]) <= tol}


def _unpaired(ts: np.ndarray, ti: np.ndarray, pairs: dict[int, int], tol: float, names: list[str]) -> list:
    """(name, reason) of scans whose nearest image is beyond ``tol`` and in no pair: a frame missed."""
    if not len(ti):
        return []
    near, taken = _nearest(ti, ts), set(pairs.values())
    return [
        (
            names[i],
            f"no image within {tol} s of the scan (the nearest is {abs(ti[near[i]] - ts[i]):.3f} s away)",
        )
        for i in range(len(ts))
        if i not in pairs and int(near[i]) not in taken
    ]
