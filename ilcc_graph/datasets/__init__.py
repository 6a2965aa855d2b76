"""Frame sources, picked by what the user points at (``open_source``).

- a ROS 1 ``.bag``, a ROS 2 bag folder (``metadata.yaml``), a ``.db3`` or ``.mcap`` file:
  :class:`BagSource` (``rosbag.py``; options: ``config``, ``lidar_topic``, ``image_topic``,
  ``camera_info_topic``, ``sync_tolerance``, ``min_pause``, ``select``, ``max_frames``).
- a folder with ``config.yaml``: :class:`FolderSource` (interface.md's layout).
- with ``rig=True``: a rig (``rig.yaml``, or a folder holding it; docs/rig.md) as a
  :class:`RigSource` (``rig.py``, ``rig_bag.py``); a single-pair folder or bag opens as the rig of
  one LiDAR and one camera.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Literal, overload

from ilcc_graph.datasets.folder import FolderSource, is_folder_source
from ilcc_graph.datasets.frame_source import FrameRef, FrameSource
from ilcc_graph.datasets.rig_source import Moment, RigPair, RigSource, is_rig_source
from ilcc_graph.datasets.rosbag import BagSource, is_bag
from ilcc_graph.errors import InputError
from ilcc_graph.io.files import not_a_file

__all__ = [
    "BagSource", "FolderSource", "FrameRef", "FrameSource", "Moment", "RigPair", "RigSource", "open_source",
]  # fmt: skip


@overload
def open_source(path: str | Path, *, rig: Literal[False] = ..., **options: object) -> FrameSource: ...
@overload
def open_source(path: str | Path, *, rig: Literal[True], **options: object) -> RigSource: ...
def open_source(path: str | Path, *, rig: bool = False, **options: object) -> FrameSource | RigSource:
    """The frame source for ``path``; InputError saying what was expected when none fits.

    options: the bag source's keyword arguments (None values are ignored); a folder takes none.
    rig: open a rig (``RigSource``): a rig file or folder, or a single-pair data set as a rig of two.
    """
    p = Path(path)
    given = {k: v for k, v in options.items() if v is not None}
    if rig:
        return _open_rig(p, given)
    if is_bag(p):
        return BagSource(p, **given)  # type: ignore[arg-type]
    if given:
        raise InputError(f"{p}: {', '.join(sorted(given))}: options of a ROS bag, not of a folder data set")
    if is_folder_source(p):
        return FolderSource(p)
    if is_rig_source(p):
        raise InputError(f"{p}: a rig data set (several sensors, docs/rig.md), not one camera-LiDAR pair")
    _no_file_where_one_belongs(p)
    if p.is_dir():
        raise InputError(
            f"{p}: no config.yaml in this folder (expected a data set with config.yaml, pcd/ and img/)"
        )
    if not p.exists():
        raise InputError(f"{p}: not found")
    raise InputError(f"{p}: not a data set (expected a folder with config.yaml, pcd/ and img/, or a ROS bag)")


def _open_rig(p: Path, given: dict[str, object]) -> RigSource:
    from ilcc_graph.config import RigData, load_config, rig_from_config

    if is_bag(p):
        bag = BagSource(p, **given)  # type: ignore[arg-type]
        data = RigData(str(p.resolve()), bag.tolerance, "lidar", bag.select, bag.min_pause, bag.max_frames)
        pair = rig_from_config(bag.config(), p.parent, data)
        topics = {"lidar": bag.topics["lidar"], "camera": bag.topics["image"]}
        return RigSource(
            p, replace(pair, sensors=tuple(replace(s, topic=topics[s.name]) for s in pair.sensors))
        )
    if given:
        raise InputError(
            f"{p}: {', '.join(sorted(given))}: options of a ROS bag, not of a rig or folder data set"
        )
    if is_rig_source(p) or (p.is_file() and p.suffix.lower() in (".yaml", ".yml")):
        return RigSource(p)  # a rig file, or a single-pair config file (the rig of two beside it)
    if is_folder_source(p):
        return RigSource(p, rig_from_config(load_config(p / "config.yaml"), p))
    _no_file_where_one_belongs(p)
    if not p.exists():
        raise InputError(f"{p}: not found")
    raise InputError(
        f"{p}: not a rig (expected a rig file, a folder with rig.yaml or config.yaml, or a ROS bag)"
    )


def _no_file_where_one_belongs(p: Path) -> None:
    """InputError naming what is there when ``p`` (or its config.yaml / rig.yaml) exists but is no
    regular file or folder: a FIFO, a device, a folder named config.yaml (issue 36: "not found" or
    "no config.yaml in this folder" before)."""
    for q in (p / "config.yaml", p / "rig.yaml") if p.is_dir() else (p,):
        problem = not_a_file(q) if os.path.lexists(q) else None
        if problem is not None and q != p:
            raise InputError(f"{q} {problem}: a data set's {q.name} is a file")
        if problem is not None and not p.is_dir():
            raise InputError(f"{p} {problem}: expected a data set (a folder with config.yaml, or a ROS bag)")
