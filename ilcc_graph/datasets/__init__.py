"""Frame sources, picked by what the user points at (``open_source``).

- a folder with ``config.yaml``: :class:`FolderSource` (interface.md's layout).
"""

from __future__ import annotations

from pathlib import Path

from ilcc_graph.datasets.base import FrameRef, FrameSource
from ilcc_graph.datasets.folder import FolderSource, is_folder_source
from ilcc_graph.errors import InputError

__all__ = ["FolderSource", "FrameRef", "FrameSource", "open_source"]


def open_source(path: str | Path, **options: object) -> FrameSource:
    """The frame source for ``path``; InputError saying what was expected when none fits."""
    p = Path(path)
    if is_folder_source(p):
        return FolderSource(p)
    if p.is_dir():
        raise InputError(
            f"{p}: no config.yaml in this folder (expected a data set with config.yaml, pcd/ and img/)"
        )
    if not p.exists():
        raise InputError(f"{p}: not found")
    raise InputError(f"{p}: not a data set (expected a folder with config.yaml, pcd/ and img/)")
