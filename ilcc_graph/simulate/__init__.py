"""Simulated LiDAR-camera data sets: scene, LiDAR ray casting, image rendering (pure, in memory).

``simulate_frames(spec)`` yields :class:`SimFrame` objects; ``ground_truth(spec, frames)`` gives the
content of ground_truth.yaml; ``simulate_dataset(out_dir, spec)`` (in ``export``, the one module that
writes files) writes the data-set layout of interface.md; ``write_bag(path, spec)`` (in ``bag``)
writes it as a ROS 1 or ROS 2 bag, optionally as a walk-and-pause recording (``bag.WalkAndPause``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the type checker sees every name where it is defined
    from .bag import write_bag as write_bag
    from .frames import SimFrame as SimFrame
    from .frames import frame_name as frame_name
    from .frames import ground_truth as ground_truth
    from .frames import simulate_frame as simulate_frame
    from .frames import simulate_frames as simulate_frames
    from .intrinsics_error import IntrinsicsError as IntrinsicsError
    from .intrinsics_error import stated_camera as stated_camera
    from .lidar import beam_biases as beam_biases
    from .lidar import beam_gains as beam_gains
    from .lidar import simulate_scan as simulate_scan
    from .placements import board_placements as board_placements
    from .placements import frame_scene as frame_scene
    from .placements import moved_placements as moved_placements
    from .render import ImageRenderer as ImageRenderer
    from .scene import Box as Box
    from .scene import Scene as Scene
    from .scene import cast_rays as cast_rays
    from .spec import SENSOR_FORMATS as SENSOR_FORMATS
    from .spec import RenderOptions as RenderOptions
    from .spec import SceneOptions as SceneOptions
    from .spec import SimulationSpec as SimulationSpec
    from .spec import Systematics as Systematics
    from .spec import default_camera as default_camera
    from .spec import default_T_cam_lidar as default_T_cam_lidar
    from .spec import paper_board as paper_board
    from .spec import standard_spec as standard_spec
    from .write_set import simulate_dataset as simulate_dataset

#: each public name's module: imported when the name is first asked for (PEP 562), so that importing
#: one module of the package (a command's choices: ``spec.INTENSITY_FIELDS``) costs no scipy, io or
#: rosbags
_WHERE = {
    "write_bag": "bag",
    **dict.fromkeys(
        ("SimFrame", "frame_name", "ground_truth", "simulate_frame", "simulate_frames"), "frames"
    ),
    **dict.fromkeys(("IntrinsicsError", "stated_camera"), "intrinsics_error"),
    **dict.fromkeys(("beam_biases", "beam_gains", "simulate_scan"), "lidar"),
    **dict.fromkeys(("board_placements", "frame_scene", "moved_placements"), "placements"),
    "ImageRenderer": "render",
    **dict.fromkeys(("Box", "Scene", "cast_rays"), "scene"),
    **dict.fromkeys(
        ("SENSOR_FORMATS", "RenderOptions", "SceneOptions", "SimulationSpec", "Systematics", "default_camera",
         "default_T_cam_lidar", "paper_board", "standard_spec"),
        "spec",
    ),  # fmt: skip
    "simulate_dataset": "write_set",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> object:
    """The public ``name``, imported from its module (``_WHERE``) when first asked for."""
    where = _WHERE.get(name)
    if where is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{where}"), name)
    globals()[name] = value
    return value
