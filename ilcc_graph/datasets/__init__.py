"""Frame sources, picked by what the user points at (``open_source``).

- a ROS 1 ``.bag``, a ROS 2 bag folder (``metadata.yaml``), a ``.db3`` or ``.mcap`` file:
  :class:`BagSource` (``rosbag.py``; options: ``config``, ``lidar_topic``, ``image_topic``,
  ``camera_info_topic``, ``sync_tolerance``, ``min_pause``, ``select``, ``max_frames``).
- a folder with ``config.yaml``: :class:`FolderSource` (interface.md's layout).
"""

from __future__ import annotations

from pathlib import Path

from ilcc_graph.datasets.base import FrameRef, FrameSource
from ilcc_graph.datasets.folder import FolderSource, is_folder_source
from ilcc_graph.datasets.rosbag import BagSource, is_bag
from ilcc_graph.errors import InputError

__all__ = ["BagSource", "FolderSource", "FrameRef", "FrameSource", "open_source"]


def open_source(path: str | Path, **options: object) -> FrameSource:
    """The frame source for ``path``; InputError saying what was expected when none fits.

    options: the bag source's keyword arguments (None values are ignored); a folder takes none.
    """
    p = Path(path)
    given = {k: v for k, v in options.items() if v is not None}
    if is_bag(p):
        return BagSource(p, **given)  # type: ignore[arg-type]
    if given:
        raise InputError(f"{p}: {', '.join(sorted(given))}: options of a ROS bag, not of a folder data set")
    if is_folder_source(p):
        return FolderSource(p)
    if p.is_dir():
        raise InputError(
            f"{p}: no config.yaml in this folder (expected a data set with config.yaml, pcd/ and img/)"
        )
    if not p.exists():
        raise InputError(f"{p}: not found")
    raise InputError(f"{p}: not a data set (expected a folder with config.yaml, pcd/ and img/, or a ROS bag)")
