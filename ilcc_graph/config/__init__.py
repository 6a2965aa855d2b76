"""The one reader of ``config.yaml``: our schema (interface.md) and ILCC's.

``load_config(path)`` returns a :class:`Config` of ready objects (``Board``, ``LidarModel``,
``CameraModel``, optional ``Roi``). Every key is checked; a wrong file raises ``InputError`` whose
message names the file, the key path (``board.squares``), the value found and what was expected.

The schemas: ``ours`` (interface.md) and ``ilcc`` (mfxox/ILCC's); the resolved form: ``model``.
A whole rig (several cameras and LiDARs): ``load_rig_config(path)`` -> :class:`RigConfig`
(``rig_schema``, ``rig``; docs/rig.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..checks import Checker
from ..errors import InputError
from ..io.files import SMALL_FILE, read_yaml
from .ilcc import is_ilcc, parse_ilcc
from .model import Config, Roi, config_to_dict
from .ours import TOP_KEYS, parse_ours
from .rig_config import RigConfig, RigData, RigSensor, rig_config_to_dict, rig_from_config
from .rig_schema import load_rig_config, parse_rig_config

__all__ = [
    "Roi", "Config", "load_config", "parse_config", "config_to_dict",
    "RigConfig", "RigData", "RigSensor", "load_rig_config", "parse_rig_config", "rig_config_to_dict",
    "rig_from_config",
]  # fmt: skip


def parse_config(d: Any, source: str = "<config>", base_dir: Path | str | None = None) -> Config:
    """Validate a loaded YAML mapping (ours or ILCC's schema) into a :class:`Config`.

    source names the file in messages; base_dir is the data folder (ILCC perspective cameras
    read their image size from ``base_dir/img``).
    """
    c = Checker(source)
    if not isinstance(d, dict):
        raise InputError(
            f"{source}: expected a mapping with sections board, lidar, camera; got {type(d).__name__}"
        )
    if is_ilcc(d):
        ours = [k for k in d if k in TOP_KEYS]
        if ours:
            raise c.fail(
                ours[0], d[ours[0]], "either our schema (board, lidar, camera) or ILCC's keys, not both"
            )
        return parse_ilcc(c, d, source, Path(base_dir) if base_dir is not None else None)
    return parse_ours(c, d, source, Path(base_dir) if base_dir is not None else None)


def load_config(path: str | Path) -> Config:
    """Read and validate ``config.yaml`` (ours or ILCC's). Raises ``InputError`` naming file and key."""
    p = Path(path)
    d = read_yaml(p, "config file", SMALL_FILE)
    if d is None:
        raise InputError(f"{p}: config file is empty; expected sections board, lidar, camera")
    return parse_config(d, str(p), p.parent)
