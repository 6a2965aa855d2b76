"""Write a simulated data set as a ROS 1 bag or a ROS 2 bag (sqlite3 or mcap), with rosbags' writers.

Messages: ``sensor_msgs/PointCloud2`` (x y z intensity float32, ring uint16 (none for a scanline-free
lidar), Velodyne's 32-byte point layout), ``sensor_msgs/Image`` (bgr8) or ``CompressedImage`` (png / jpeg) and
``sensor_msgs/CameraInfo`` (pinhole: plumb_bob or rational_polynomial; fisheye: equidistant; none for
a panorama), serialised with rosbags' typestore. Stamps: scan k at ``start + k / rate_hz``, its image
``image_delay_s`` later; bag (receive) times lag the stamps by the transport latencies.

Beside the bag: ``<bag>.yaml`` (board and LiDAR; the camera section only when CameraInfo cannot
carry it) and ``<bag>.ground_truth.yaml`` (``T_lidar_board`` for every scan, named as the bag source
names frames, and ``pauses``: the first and last scan of each still pause).

Without a timeline every scan is one frame of ``simulate_frames(spec)`` (the board moves between
consecutive scans, as in a set of snapshots). With :class:`WalkAndPause` the board is held still at
each placement for ``pause_s`` and carried to the next one over ``move_s``; every message then has
its own noise (the simulator's streams are keyed by message index).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ..io import write_yaml
from ..io.output_folders import staged_files
from ..types import Scan
from .frames import SimFrame, ground_truth, simulate_frames
from .lidar import beam_biases, simulate_scan
from .placements import board_placements, frame_scene
from .render import ImageRenderer
from .spec import SimulationSpec
from .write_set import config_dict

if TYPE_CHECKING:  # rosbags is imported when a bag is written
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys.store import Msg, Msgarg

__all__ = ["RosMessages", "WalkAndPause", "bag_frame_name", "simulate_walk", "walk_poses", "write_bag"]

STORAGES = ("ros1", "sqlite3", "mcap")
IMAGE_FORMATS = ("bgr8", "png", "jpeg", "none")
LIDAR_TOPIC, IMAGE_TOPIC, INFO_TOPIC = "/lidar/points", "/camera/image_raw", "/camera/camera_info"
START_NS = 1_700_000_000 * 10**9


@dataclass(frozen=True)
class WalkAndPause:
    """A person holds the board still at each placement for ``pause_s`` s, then carries it to the next
    over ``move_s`` s (pose interpolated: slerp and straight line, lowered by ``dip_m`` half-way)."""

    pause_s: float = 1.5
    move_s: float = 1.0
    dip_m: float = 0.2


def bag_frame_name(t_ns: int, start_ns: int) -> str:
    """The bag source's name of a scan received at bag time ``t_ns`` (bag starts at ``start_ns``)."""
    return f"t{(t_ns - start_ns) * 1e-9:010.3f}"


def _timeline(spec: SimulationSpec, walk: WalkAndPause, rate_hz: float) -> list[tuple[np.ndarray, int, bool]]:
    """(T_lidar_board, placement index for the scene's clutter, still) per scan."""
    return walk_poses(board_placements(spec), walk, rate_hz)


def walk_poses(
    poses: Sequence[np.ndarray], walk: WalkAndPause, rate_hz: float
) -> list[tuple[np.ndarray, int, bool]]:
    """(board pose, placement index for the scene's clutter, still) per scan of a walk through ``poses``."""
    n_pause, n_move = max(1, round(walk.pause_s * rate_hz)), max(1, round(walk.move_s * rate_hz))
    out = []
    for k, T in enumerate(poses):
        out += [(T, k, True)] * n_pause
        if k + 1 < len(poses):
            U = poses[k + 1]
            slerp = Slerp([0.0, 1.0], Rotation.from_matrix([T[:3, :3], U[:3, :3]]))
            for s in (np.arange(n_move) + 1.0) / (n_move + 1.0):
                M = np.eye(4)
                M[:3, :3] = slerp([s]).as_matrix()[0]
                M[:3, 3] = (1 - s) * T[:3, 3] + s * U[:3, 3] - [0.0, 0.0, walk.dip_m * np.sin(np.pi * s)]
                out.append((M, k + 1, False))
    return out


def simulate_walk(spec: SimulationSpec, walk: WalkAndPause, rate_hz: float = 10.0) -> list[SimFrame]:
    """One simulated frame per scan of a walk-and-pause timeline (its own noise each), in time order."""
    steps = _timeline(spec, walk, rate_hz)
    renderer, biases = ImageRenderer(spec), beam_biases(spec)
    frames = []
    for i, (T, k, _) in enumerate(steps):
        scene = frame_scene(spec, T, k)
        frames.append(
            SimFrame(f"{i:05d}", simulate_scan(spec, scene, i, biases), renderer.render(scene, i), T)
        )
    return frames


class RosMessages:
    """Builds and serialises messages with rosbags' ROS 1 (noetic) or ROS 2 (humble) typestore."""

    def __init__(self, ros1: bool) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.ros1 = ros1
        self.ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)

    def make(self, msgtype: str, /, **values: Msgarg) -> Msg:
        """A message of ``msgtype`` (``sensor_msgs/msg/Image``); field names matched case-insensitively."""
        fields = {f.lower(): f for f, _ in self.ts.fielddefs[msgtype][1]}
        return self.ts.types[msgtype](**{fields[k.lower()]: v for k, v in values.items()})

    def header(self, t_ns: int, frame: str) -> Msg:
        stamp = self.make("builtin_interfaces/msg/Time", sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        extra = {"seq": 0} if self.ros1 else {}
        return self.make("std_msgs/msg/Header", stamp=stamp, frame_id=frame, **extra)

    def serialize(self, msg: object, msgtype: str) -> bytes:
        ser = self.ts.serialize_ros1 if self.ros1 else self.ts.serialize_cdr
        return bytes(ser(msg, msgtype))

    def cloud(self, frame: SimFrame | Scan, t_ns: int) -> Msg:
        """The PointCloud2 of a frame's scan (or of a scan)."""
        scan = frame if isinstance(frame, Scan) else frame.scan
        n = len(scan)
        rec = np.zeros(n, dtype={"names": ["x", "y", "z", "intensity", "ring"],
                                 "formats": ["<f4", "<f4", "<f4", "<f4", "<u2"],
                                 "offsets": [0, 4, 8, 16, 20], "itemsize": 32})  # fmt: skip
        rec["x"], rec["y"], rec["z"] = scan.points.T
        rec["intensity"] = scan.intensity
        pf = "sensor_msgs/msg/PointField"
        layout: tuple[tuple[str, int, int], ...] = (  # 7 f4, 4 u2
            ("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("ring", 20, 4)
        )  # fmt: skip
        if scan.ring is None:  # a scanline-free lidar (Livox): no ring field
            layout = layout[:4]
        else:
            rec["ring"] = scan.ring
        if not scan.has_intensity:  # x y z (and ring) only
            layout = tuple(f for f in layout if f[0] != "intensity")
        fields = [self.make(pf, name=c, offset=o, datatype=d, count=1) for c, o, d in layout]
        return self.make("sensor_msgs/msg/PointCloud2", header=self.header(t_ns, "lidar"), height=1, width=n,
                         fields=fields, is_bigendian=False, point_step=32, row_step=32 * n,
                         data=rec.view(np.uint8).reshape(-1), is_dense=True)  # fmt: skip

    def image(self, img: np.ndarray, t_ns: int, fmt: str) -> Msg:
        import cv2

        if fmt == "bgr8":
            h, w = img.shape[:2]
            return self.make("sensor_msgs/msg/Image", header=self.header(t_ns, "camera"), height=h, width=w,
                             encoding="bgr8", is_bigendian=0, step=3 * w, data=img.reshape(-1))  # fmt: skip
        params = [cv2.IMWRITE_JPEG_QUALITY, 95] if fmt == "jpeg" else []
        data = np.frombuffer(cv2.imencode(f".{'jpg' if fmt == 'jpeg' else 'png'}", img, params)[1], np.uint8)
        return self.make("sensor_msgs/msg/CompressedImage", header=self.header(t_ns, "camera"),
                         format=f"bgr8; {fmt} compressed bgr8", data=data)  # fmt: skip

    def camera_info(self, spec: SimulationSpec, t_ns: int) -> Msg | None:
        cam = spec.camera
        ros = cam.ros_camera_info()
        if ros is None:
            return None
        model, dist = ros
        K = np.asarray(cam.to_dict()["K"], dtype=np.float64)
        P = np.hstack([K, np.zeros((3, 1))])
        roi = self.make("sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=0, width=0,
                        do_rectify=False)  # fmt: skip
        return self.make("sensor_msgs/msg/CameraInfo", header=self.header(t_ns, "camera"), height=cam.height,
                         width=cam.width, distortion_model=model, d=np.array(dist), k=K.reshape(-1),
                         r=np.eye(3).reshape(-1), p=P.reshape(-1), binning_x=0, binning_y=0,
                         roi=roi)  # fmt: skip


def _write(writer: Writer1 | Writer2, m: RosMessages, spec: SimulationSpec, frames: Sequence[SimFrame],
           image_format: str, times: tuple[np.ndarray, ...],
           progress: Callable[[int, int], None] | None) -> bool:  # fmt: skip
    """Every message into an open-able ``writer``; True when CameraInfo was written."""
    t_scan, t_image, bag_scan, bag_image = times
    cloud_t, info_t = "sensor_msgs/msg/PointCloud2", "sensor_msgs/msg/CameraInfo"
    image_t = "sensor_msgs/msg/Image" if image_format == "bgr8" else "sensor_msgs/msg/CompressedImage"
    has_info = image_format != "none" and m.camera_info(spec, 0) is not None
    with writer:
        c_cloud = writer.add_connection(LIDAR_TOPIC, cloud_t, typestore=m.ts)
        topic = IMAGE_TOPIC if image_format == "bgr8" else IMAGE_TOPIC + "/compressed"
        c_image = writer.add_connection(topic, image_t, typestore=m.ts) if image_format != "none" else None
        c_info = writer.add_connection(INFO_TOPIC, info_t, typestore=m.ts) if has_info else None
        for k, f in enumerate(frames):
            writer.write(c_cloud, int(bag_scan[k]), m.serialize(m.cloud(f, int(t_scan[k])), cloud_t))
            if c_image is not None:
                image = m.image(f.image, int(t_image[k]), image_format)
                writer.write(c_image, int(bag_image[k]), m.serialize(image, image_t))
            if c_info is not None:
                info = m.camera_info(spec, int(t_image[k]))
                writer.write(c_info, int(bag_image[k]), m.serialize(info, info_t))
            if progress is not None:
                progress(k + 1, len(frames))
    return has_info


def write_bag(
    path: Path | str,
    spec: SimulationSpec,
    *,
    storage: str = "auto",
    image_format: str = "bgr8",
    timeline: WalkAndPause | None = None,
    rate_hz: float = 10.0,
    image_delay_s: float | Sequence[float] = 0.012,
    latency_s: tuple[float, float] = (0.030, 0.020),
    frames: Sequence[SimFrame] | None = None,
    progress: Callable[[int, int], None] | None = None,
    flag: str = "write_bag",
) -> Path:
    """Simulate ``spec`` and write it as a bag at ``path``; returns the bag's path.

    storage: ``ros1`` (a ``.bag`` file), ``sqlite3`` or ``mcap`` (a ROS 2 bag folder); ``auto``: ros1 for
    a ``.bag`` path, else sqlite3. image_format: ``bgr8`` (Image), ``png`` or ``jpeg`` (CompressedImage),
    ``none`` (no images, no CameraInfo).
    image_delay_s: image stamp minus scan stamp, one value or one per scan. latency_s: (LiDAR, camera)
    bag time minus stamp. frames: the frames to write when already simulated (``simulate_frames(spec)``,
    or ``simulate_walk(spec, timeline, rate_hz)`` with a timeline).
    The bag, ``<bag>.yaml`` and ``<bag>.ground_truth.yaml`` are written in a staging folder beside them
    and moved in at the end, the bag last (``io.output_folders.staged_files``), so a failed or stopped
    write leaves nothing behind; none of them may exist (a run never writes over a file it did not
    write): ``OutputError`` naming ``flag``, the bag and the file in the way otherwise, before any work.
    """
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    out = Path(path)
    storage = ("ros1" if out.suffix == ".bag" else "sqlite3") if storage == "auto" else storage
    if storage not in STORAGES or image_format not in IMAGE_FORMATS:
        raise ValueError(f"storage must be one of {STORAGES}, image_format one of {IMAGE_FORMATS}")
    ros1 = storage == "ros1"
    stem = out.with_suffix("") if ros1 else out
    config_name, truth_name = f"{stem.name}.yaml", f"{stem.name}.ground_truth.yaml"
    with staged_files([out.parent / config_name, out.parent / truth_name, out], flag) as tmp:
        steps = None if timeline is None else _timeline(spec, timeline, rate_hz)
        if frames is None:
            frames = (
                list(simulate_frames(spec)) if timeline is None else simulate_walk(spec, timeline, rate_hz)
            )
        n = len(frames)
        delays = np.broadcast_to(np.asarray(image_delay_s, dtype=np.float64), (n,))
        t_scan = START_NS + np.round(np.arange(n) / rate_hz * 1e9).astype(np.int64)
        t_image = t_scan + np.round(delays * 1e9).astype(np.int64)
        bag_scan, bag_image = t_scan + round(latency_s[0] * 1e9), t_image + round(latency_s[1] * 1e9)
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        bag = tmp / out.name
        writer = Writer1(bag) if ros1 else Writer2(bag, version=9, storage_plugin=plugin)
        times = (t_scan, t_image, bag_scan, bag_image)
        has_info = _write(writer, RosMessages(ros1), spec, frames, image_format, times, progress)

        config = config_dict(spec)
        if has_info:
            config.pop("camera")
        write_yaml(tmp / config_name, config)
        start = int(bag_scan.min() if image_format == "none" else min(bag_scan.min(), bag_image.min()))
        names = [bag_frame_name(int(t), start) for t in bag_scan]
        gt = ground_truth(
            spec, [SimFrame(nm, f.scan, f.image, f.T_lidar_board) for nm, f in zip(names, frames)]
        )
        still = np.asarray([s[2] for s in steps] if steps is not None else [False] * n, dtype=int)
        edges = np.flatnonzero(np.diff(np.r_[0, still, 0]))
        gt["pauses"] = [[names[a], names[b - 1]] for a, b in zip(edges[::2], edges[1::2])]
        write_yaml(tmp / truth_name, gt)
    return out
