"""ROS sensor messages as plain data: PointCloud2 -> Scan, Image / CompressedImage -> BGR array,
CameraInfo -> our config's camera section. Messages are rosbags' deserialised objects (ROS 1 or 2).

An image message's size is read before a pixel is decoded (``image_message_size``: the Image's
fields, a CompressedImage's encoded header), as ``io.images`` reads an image file's header: a message
whose data do not hold the image it declares, or that declares an absurd size, is refused unread."""

from __future__ import annotations

from typing import Any

import numpy as np

from ilcc_graph.cameras import camera_section_from_ros
from ilcc_graph.errors import InputError
from ilcc_graph.io.images import eight_bits, encoded_image_size
from ilcc_graph.io.scans import find_fields, make_scan
from ilcc_graph.types import Scan

__all__ = [
    "CLOUD",
    "COMPRESSED",
    "IMAGE",
    "INFO",
    "camera_section",
    "check_image_format",
    "decode_cloud",
    "decode_image",
    "image_message_size",
    "sweep_offset",
]

CLOUD, IMAGE, COMPRESSED, INFO = (
    f"sensor_msgs/msg/{t}" for t in ("PointCloud2", "Image", "CompressedImage", "CameraInfo")
)
_PF = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
#: encoding -> (bytes per channel, channels, OpenCV conversion to BGR or None)
_ENCODINGS = {"bgr8": (1, 3, None), "rgb8": (1, 3, "RGB2BGR"), "bgra8": (1, 4, "BGRA2BGR"),
              "rgba8": (1, 4, "RGBA2BGR"), "mono8": (1, 1, "GRAY2BGR"),
              "mono16": (2, 1, "GRAY2BGR")}  # fmt: skip


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
    reflectivity when there is one, ring or laser_id); NaN and (0, 0, 0) points ("no return") dropped."""
    rec = _records(msg, where)
    names = list(rec.dtype.names or ())
    cols = find_fields(where, names)  # type: ignore[arg-type]
    xyz = np.empty((len(rec), 3))
    for k, axis in enumerate("xyz"):
        xyz[:, k] = _column(rec, names[cols[axis]])  # type: ignore[index]
    xyz[(xyz[:, 0] == 0) & (xyz[:, 1] == 0) & (xyz[:, 2] == 0)] = np.nan
    ring = None if cols["ring"] is None else _column(rec, names[cols["ring"]])
    inten = None if cols["intensity"] is None else _column(rec, names[cols["intensity"]])
    return make_scan(where, xyz, inten, ring)  # type: ignore[arg-type]


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


def check_image_format(msg: Any, where: str) -> None:
    """InputError when an Image's encoding or a CompressedImage's format is not one we decode (a
    topic's problem rather than one message's)."""
    if hasattr(msg, "format"):  # CompressedImage: jpeg / png
        if "compresseddepth" in msg.format.lower():
            raise InputError(f"{where}: cannot decode the compressed image (format {msg.format!r})")
    elif msg.encoding.lower() not in _ENCODINGS:
        raise InputError(
            f"{where}: image encoding {msg.encoding!r} is not supported ({', '.join(_ENCODINGS)})"
        )


def image_message_size(msg: Any, where: str) -> tuple[int, int] | None:
    """(width, height) px an Image or CompressedImage declares (its fields; the encoded image's header),
    no pixel decoded; None when a compressed image's header does not tell (its decoder then says what
    is wrong). InputError starting with ``where`` when the encoding is not supported or the message is
    damaged or truncated: its data do not hold the image it declares, or its header declares a size
    of zero or more than ``io.images.MAX_PIXELS``."""
    check_image_format(msg, where)
    if hasattr(msg, "format"):
        return encoded_image_size(np.asarray(msg.data, dtype=np.uint8), where)
    size, ch, _ = _ENCODINGS[msg.encoding.lower()]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    n = np.asarray(msg.data, dtype=np.uint8).size
    if w <= 0 or h <= 0 or step < w * ch * size or n < h * step:
        raise InputError(
            f"{where}: {n} data bytes do not hold a {w} x {h} {msg.encoding} image of {step} bytes a row "
            "(a damaged or truncated message)"
        )
    return w, h


def decode_image(msg: Any, where: str) -> np.ndarray:
    """An Image (bgr8, rgb8, mono8, mono16, bgra8, rgba8) or CompressedImage as (H, W, 3) BGR uint8;
    its size checked first (``image_message_size``)."""
    import cv2

    image_message_size(msg, where)
    if hasattr(msg, "format"):  # CompressedImage: jpeg / png
        img = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise InputError(f"{where}: cannot decode the compressed image (format {msg.format!r})")
        return img
    size, ch, conversion = _ENCODINGS[msg.encoding.lower()]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    px = data[: h * step].reshape(h, step)[:, : w * ch * size]
    if size == 2:  # 16 bits scaled to 8 as io.read_image does
        px = eight_bits(px.copy().view(">u2" if msg.is_bigendian else "<u2"))
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
