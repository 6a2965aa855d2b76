"""Simulated LiDAR-camera data sets: scene, LiDAR ray casting, image rendering (pure, in memory).

``simulate_frames(spec)`` yields :class:`SimFrame` objects; ``ground_truth(spec, frames)`` gives the
content of ground_truth.yaml; ``simulate_dataset(out_dir, spec)`` (in ``export``, the one module that
writes files) writes the data-set layout of interface.md; ``write_bag(path, spec)`` (in ``bag``)
writes it as a ROS 1 or ROS 2 bag, optionally as a walk-and-pause recording (``bag.WalkAndPause``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .frames import SimFrame, frame_name, ground_truth, simulate_frame, simulate_frames
from .intrinsics_error import IntrinsicsError, stated_camera
from .lidar import beam_biases, beam_gains, simulate_scan
from .placements import board_placements, frame_scene, moved_placements
from .render import ImageRenderer
from .scene import Box, Scene, cast_rays
from .spec import (
    SENSOR_FORMATS,
    RenderOptions,
    SceneOptions,
    SimulationSpec,
    Systematics,
    default_camera,
    default_T_cam_lidar,
    paper_board,
    standard_spec,
)

if TYPE_CHECKING:  # the type checker sees the writers' own signatures
    from .bag import write_bag
    from .write_set import simulate_dataset
else:

    def simulate_dataset(*args, **kwargs):  # lazy: keeps io out of `import ilcc_graph.simulate`
        """Write a data set; see :func:`ilcc_graph.simulate.write_set.simulate_dataset`."""
        from .write_set import simulate_dataset as _write

        return _write(*args, **kwargs)

    def write_bag(*args, **kwargs):  # lazy: keeps rosbags out of `import ilcc_graph.simulate`
        """Write a data set as a ROS bag; see :func:`ilcc_graph.simulate.bag.write_bag`."""
        from .bag import write_bag as _write

        return _write(*args, **kwargs)


__all__ = [
    "SENSOR_FORMATS",
    "Box", "RenderOptions", "ImageRenderer", "Scene", "SceneOptions", "SimFrame", "SimulationSpec",
    "Systematics", "beam_biases", "beam_gains", "board_placements", "cast_rays", "default_T_cam_lidar",
    "default_camera", "frame_name", "frame_scene", "ground_truth", "moved_placements", "paper_board",
    "simulate_dataset",
    "simulate_frame", "simulate_frames", "simulate_scan", "standard_spec", "write_bag",
    "IntrinsicsError", "stated_camera",
]  # fmt: skip
