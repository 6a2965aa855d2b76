"""The simulator's front door: :func:`simulate_frames` yields in-memory frames; :func:`ground_truth`.

Pure: no file I/O (see ``write_set.py`` for writing a data set). Every random stream is derived
from ``spec.seed`` with ``np.random.SeedSequence(seed, spawn_key=(purpose, frame, stream))``, so a
frame's content does not depend on which other frames are generated or in what order.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..types import Scan
from .intrinsics_error import stated_camera
from .lidar import beam_biases, beam_gains, simulate_scan
from .placements import board_placements, frame_scene
from .render import ImageRenderer
from .spec import SimulationSpec

__all__ = ["SimFrame", "simulate_frames", "simulate_frame", "ground_truth", "frame_name"]


@dataclass(frozen=True, eq=False)
class SimFrame:
    """One simulated frame.

    name: file stem, ``"0001"`` for the first frame.
    scan: the LiDAR scan (points in scan order, LiDAR frame, with rings).
    image: (H, W, 3) uint8 BGR.
    T_lidar_board: (4, 4) true board pose, ``p_lidar = T_lidar_board @ p_board``.
    """

    name: str
    scan: Scan
    image: np.ndarray
    T_lidar_board: np.ndarray


def frame_name(i: int) -> str:
    """Stem of frame ``i`` (0-based): ``"0001"``, ``"0002"``, ..."""
    return f"{i + 1:04d}"


def simulate_frames(spec: SimulationSpec, frames: Iterable[int] | None = None) -> Iterator[SimFrame]:
    """Yield the frames of ``spec`` (all, or the 0-based indices in ``frames``), one at a time.

    The empty room's image is rendered once, at the first frame, and reused.
    """
    placements = board_placements(spec)
    renderer = ImageRenderer(spec)
    biases = beam_biases(spec)
    for i in range(len(placements)) if frames is None else frames:
        T = placements[i]
        scene = frame_scene(spec, T, i)
        scan = simulate_scan(spec, scene, i, biases)
        image = renderer.render(scene, i)
        yield SimFrame(frame_name(i), scan, image, T.copy())


def simulate_frame(spec: SimulationSpec, i: int) -> SimFrame:
    """Frame ``i`` (0-based) alone; identical to the one :func:`simulate_frames` yields."""
    return next(simulate_frames(spec, [i]))


class NamedPose(Protocol):
    """What ``ground_truth`` reads of a frame: its name and true board pose."""

    @property
    def name(self) -> str: ...

    @property
    def T_lidar_board(self) -> np.ndarray: ...


def ground_truth(spec: SimulationSpec, frames: Iterable[NamedPose] | None = None) -> dict[str, Any]:
    """The content of ``ground_truth.yaml`` (plain lists, ready for YAML).

    Keys: ``T_cam_lidar`` (4x4); ``T_lidar_board`` {stem: 4x4}; ``corners_lidar`` {stem: (K, 3)
    inner corners in the LiDAR frame, index k as interface.md}; ``board`` (config schema);
    ``camera_truth`` (the camera that rendered the images, config schema) and
    ``camera_intrinsics_error`` {name: stated minus true} (config.yaml's camera is the stated one);
    ``lidar_beam_bias_m`` and ``lidar_beam_intensity_gain`` (per ring); ``simulation`` (the
    settings). ``frames``: the frames written (their names and poses); None -> every frame of the
    spec, from the placements alone.
    """
    if frames is None:
        poses = {frame_name(i): T for i, T in enumerate(board_placements(spec))}
    else:
        poses = {f.name: f.T_lidar_board for f in frames}
    K = spec.board.corners_board()
    corners = {k: (K @ T[:3, :3].T + T[:3, 3]).tolist() for k, T in poses.items()}
    return {
        "T_cam_lidar": np.asarray(spec.T_cam_lidar).tolist(),
        "T_lidar_board": {k: np.asarray(T).tolist() for k, T in poses.items()},
        "corners_lidar": corners,
        "board": spec.board.to_dict(),
        "camera_truth": spec.camera.to_dict(),
        "camera_intrinsics_error": _intrinsics_error(spec),
        "lidar_beam_bias_m": beam_biases(spec).tolist(),
        "lidar_beam_intensity_gain": beam_gains(spec).tolist(),
        "simulation": spec.summary(),
    }


def _intrinsics_error(spec: SimulationSpec) -> dict[str, float]:
    """{name: stated minus true} of the camera's intrinsics (all 0 when the error is off)."""
    stated = stated_camera(spec.camera, spec.intrinsics_error, spec.units_seed).intrinsics()
    d = stated - spec.camera.intrinsics()
    return {n: float(v) for n, v in zip(spec.camera.intrinsic_names, d, strict=True)}
