"""Write a simulated rig set (docs/rig.md): as a folder per sensor, or as one ROS bag with a topic per
sensor; both with ``rig.yaml`` and ``rig_ground_truth.yaml``.

Folder layout: ``OUT/rig.yaml``, ``OUT/<sensor>/<moment>.pcd`` (``.csv`` for ``velodyne-csv``; the
single-pair writer's formats, ``export.write_scan``) or ``.png``, ``OUT/rig_ground_truth.yaml``.
Bag layout: ``OUT/rig.bag`` (ROS 1) or ``OUT/rig/`` (ROS 2, sqlite3 or mcap) with ``/<sensor>/points``
(PointCloud2) and ``/<sensor>/image_raw`` (Image; ``.../compressed`` for png / jpeg), messages of the
single-pair bag writer (``bag.RosMessages``); moment k's messages are stamped ``k / rate_hz`` s after
the start (cameras 12 ms after the LiDARs, each sensor 1 ms after the previous one of its kind) and
received 30 ms (LiDARs) or 20 ms (cameras) later; the truth names moments as the rig source names them
(the first LiDAR's bag time). Either set is assembled in a staging folder that becomes ``OUT``
(``export.assemble``), so ``OUT`` holds a whole set or is left as it was; ``OUT`` must be new, empty or
an earlier simulated set (docs/faults.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..config import rig_config_to_dict
from ..io import write_image, write_yaml
from ..io.rig_truth import write_rig_ground_truth
from .bag import START_NS, RosMessages, WalkAndPause, bag_frame_name, walk_poses
from .rig_spec import RigMoment, RigSpec, rig_ground_truth, simulate_moments
from .write_set import assemble, write_scan

__all__ = ["rig_walk", "write_rig_bag", "write_rig_set"]

Progress = Callable[[int, int], None] | None
CLOUD_T, IMAGE_T, COMPRESSED_T = (f"sensor_msgs/msg/{t}" for t in ("PointCloud2", "Image", "CompressedImage"))


def write_rig_set(
    out: Path | str, spec: RigSpec, progress: Progress = None, moments: Sequence[RigMoment] | None = None,
    command: str = "",
) -> Path:
    """Simulate ``spec`` and write it as a folder per sensor to ``out`` (new, empty or an earlier
    simulated set).

    progress: called as ``progress(done, total)`` after each moment. moments: ``simulate_moments(spec)``
    when already simulated. command: the command line that asked (recorded in the folder's marker).
    Returns ``out``; OutputError naming it when it holds anything else."""

    def fill(tmp: Path) -> None:
        write_yaml(tmp / "rig.yaml", rig_config_to_dict(spec.rig_config()))
        for name in spec.names:  # every sensor's folder, also one that sees no board
            (tmp / name).mkdir()
        done = []
        for k, m in enumerate(simulate_moments(spec) if moments is None else moments):
            for name, scan in m.scans.items():
                write_scan(tmp / name, m.name, scan, spec.sensor(name).sensor_format)
            for name, image in m.images.items():
                write_image(tmp / name / f"{m.name}.png", image)
            done.append((m.name, m.T_body_board, m.seen_by))
            if progress is not None:
                progress(k + 1, int(spec.n_moments))
        write_rig_ground_truth(tmp, rig_ground_truth(spec, done))

    return assemble(Path(out), fill, command)


def rig_walk(
    spec: RigSpec, walk: WalkAndPause, rate_hz: float = 10.0
) -> tuple[RigSpec, list[int], list[bool]]:
    """A walk-and-pause recording of ``spec``'s boards (``bag.walk_poses``): the spec with one moment
    per message time (``placements``), the scene key of each (its placement: the person stays) and
    whether the board is still."""
    from .rig_placements import rig_placements

    steps = walk_poses(rig_placements(spec, spec.with_(moved=None).poses()), walk, rate_hz)
    walk_spec = spec.with_(placements=tuple(T for T, _, _ in steps))
    return walk_spec, [k for _, k, _ in steps], [still for _, _, still in steps]


def write_rig_bag(
    out: Path | str,
    spec: RigSpec,
    progress: Progress = None,
    *,
    storage: str = "ros1",
    image_format: str = "bgr8",
    rate_hz: float = 10.0,
    timeline: WalkAndPause | None = None,
    moments: Sequence[RigMoment] | None = None,
    command: str = "",
) -> Path:
    """Simulate ``spec`` and write it as one bag with a topic per sensor, in the folder ``out`` (created;
    must be empty or absent) beside ``rig.yaml`` and ``rig_ground_truth.yaml``. storage: ``ros1``,
    ``sqlite3`` or ``mcap``; image_format: ``bgr8``, ``png`` or ``jpeg``. timeline: a walk-and-pause
    recording (:func:`rig_walk`; the truth's ``pauses`` lists each pause's first and last moment).
    moments: ``simulate_moments`` of the spec (of ``rig_walk``'s with a timeline) when already
    simulated. command: as ``write_rig_set`` takes it. Returns ``out``."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    if storage not in ("ros1", "sqlite3", "mcap") or image_format not in ("bgr8", "png", "jpeg"):
        raise ValueError("storage must be ros1, sqlite3 or mcap; image_format bgr8, png or jpeg")
    image_t = IMAGE_T if image_format == "bgr8" else COMPRESSED_T
    suffix = "/image_raw" if image_format == "bgr8" else "/image_raw/compressed"
    topics = {s.name: f"/{s.name}" + ("/points" if s.kind == "lidar" else suffix) for s in spec.sensors}
    lidars = [s.name for s in spec.sensors if s.kind == "lidar"]
    cameras = [s.name for s in spec.sensors if s.kind == "camera"]
    offset_s = {n: 0.001 * j for j, n in enumerate(lidars)} | {
        n: 0.012 + 0.001 * j for j, n in enumerate(cameras)
    }
    latency_ns = {n: round((0.030 if n in lidars else 0.020) * 1e9) for n in spec.names}
    bag_name = "rig.bag" if storage == "ros1" else "rig"

    still = None
    if timeline is not None:
        spec, keys, still = rig_walk(spec, timeline, rate_hz)
        moments = list(simulate_moments(spec, keys)) if moments is None else moments

    def fill(tmp: Path) -> None:
        m = RosMessages(storage == "ros1")
        path = tmp / bag_name
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Writer1(path) if storage == "ros1" else Writer2(path, version=9, storage_plugin=plugin)
        done, anchor_ns = [], []
        with writer:
            conns = {n: writer.add_connection(topics[n], CLOUD_T if n in lidars else image_t, typestore=m.ts)
                     for n in spec.names}  # fmt: skip
            for k, moment in enumerate(simulate_moments(spec) if moments is None else moments):
                t0 = START_NS + round(k / rate_hz * 1e9)
                msgs = []
                for n, scan in moment.scans.items():
                    stamp = t0 + round(offset_s[n] * 1e9)
                    msgs.append((stamp + latency_ns[n], n, m.cloud(scan, stamp), CLOUD_T))
                for n, img in moment.images.items():
                    stamp = t0 + round(offset_s[n] * 1e9)
                    msgs.append((stamp + latency_ns[n], n, m.image(img, stamp, image_format), image_t))
                for t, n, msg, msgtype in sorted(msgs, key=lambda x: x[0]):
                    writer.write(conns[n], t, m.serialize(msg, msgtype))
                anchor_ns.append(t0 + round(offset_s[lidars[0]] * 1e9) + latency_ns[lidars[0]])
                done.append((moment.T_body_board, moment.seen_by))
                if progress is not None:
                    progress(k + 1, int(spec.n_moments))
        start = min(anchor_ns)  # the first messages are moment 0's LiDAR scans
        names = [bag_frame_name(t, start) for t in anchor_ns]
        write_yaml(tmp / "rig.yaml", rig_config_to_dict(spec.rig_config(topics, bag_name)))
        truth = rig_ground_truth(spec, [(nm, T, seen) for nm, (T, seen) in zip(names, done, strict=True)])
        if still is not None:
            edges = np.flatnonzero(np.diff(np.r_[0, np.asarray(still, dtype=int), 0]))
            truth.extra["pauses"] = [
                [names[a], names[b - 1]] for a, b in zip(edges[::2], edges[1::2], strict=True)
            ]
        write_rig_ground_truth(tmp, truth)

    return assemble(Path(out), fill, command)
