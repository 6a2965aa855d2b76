"""Board placements for a simulated rig (body frame: x forward, y left, z up) and which sensors see
a board whole.

A sensor sees a board when its printed face is turned towards the sensor (within about 75 deg) and
every point of the board's outline lies in the sensor's field: inside a camera's image with a 3 %
border (a panorama: inside its rows), inside a LiDAR's vertical field with 0.3 deg to spare (a
scanline-free LiDAR: inside its cone) and at least 0.5 m away.

Each moment takes the next entry of ``RigSpec.views`` (cycled): the board is drawn, as the
single-pair placements do (``placements.py``: 1.2-2.6 m away, facing the sensors, turned 45 deg in
its plane plus a random quarter turn, tilted up to 15 deg and 25 deg), towards the mean looking
direction of the entry's cameras (a panorama or no camera: a direction that turns by the golden
angle from moment to moment), at an elevation inside the entry's LiDARs' fields, from the mean
origin of the entry's LiDARs; it is redrawn until every sensor of the entry sees it whole, no camera
outside the entry does, and it stands inside the room, 30 cm clear of the walls and the floor. After
repeated failures the draws move farther out and towards the middle direction.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .placements import frame_rng, pose_facing
from .scene import Scene

if TYPE_CHECKING:
    from .rig_spec import RigSensorSpec, RigSpec

__all__ = ["rig_placements", "sees"]

PURPOSE_RIG_PLACEMENT = 8  # stream key (placements.py: 0-2, rig_spec.py: 7, intrinsics.py: 9)
GOLDEN = np.pi * (3.0 - np.sqrt(5.0))
ATTEMPTS = 600


def _outline(spec: RigSpec, T_body_board: np.ndarray) -> np.ndarray:
    return Scene(None, None, None, spec.board, T_body_board).board_outline_samples(16)


def sees(s: RigSensorSpec, T_body_sensor: np.ndarray, T_body_board: np.ndarray, spec: RigSpec) -> bool:
    """True when sensor ``s`` at ``T_body_sensor`` sees the whole board at ``T_body_board`` (module doc)."""
    pts = _outline(spec, T_body_board)
    centre = T_body_board[:3, :3] @ spec.board.pattern_centre + T_body_board[:3, 3]
    to_sensor = T_body_sensor[:3, 3] - centre
    if T_body_board[:3, 2] @ to_sensor < 0.25 * np.linalg.norm(to_sensor):
        return False
    p = (pts - T_body_sensor[:3, 3]) @ T_body_sensor[:3, :3]  # outline in the sensor's frame
    if s.camera is not None:
        cam = s.camera
        uv = cam.project(p)
        bw, bh = 0.03 * cam.width, 0.03 * cam.height
        if not np.all(np.isfinite(uv)) or uv[:, 1].min() < bh or uv[:, 1].max() > cam.height - 1 - bh:
            return False
        return bool(cam.periodic_u or (uv[:, 0].min() >= bw and uv[:, 0].max() <= cam.width - 1 - bw))
    model = s.lidar
    el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    va = model.vertical_angles_deg  # type: ignore[union-attr]
    if np.linalg.norm(p, axis=1).min() < 0.5:
        return False
    if model.ringless:  # type: ignore[union-attr]
        off_axis = np.degrees(np.arccos(np.clip(p[:, 0] / np.linalg.norm(p, axis=1), -1.0, 1.0)))
        return bool(off_axis.max() <= np.abs(va).max() - 0.5)
    return bool(el.min() >= va[0] + 0.3 and el.max() <= va[-1] - 0.3)


def _acceptable(spec: RigSpec, poses: dict[str, np.ndarray], view: tuple[str, ...], T: np.ndarray) -> bool:
    pts = _outline(spec, T)
    if pts[:, 2].min() < -spec.scene.lidar_height_m + 0.3:
        return False
    if spec.scene.room is not None:
        xmin, xmax, ymin, ymax = spec.scene.room
        if pts[:, 0].min() < xmin + 0.3 or pts[:, 0].max() > xmax - 0.3:
            return False
        if pts[:, 1].min() < ymin + 0.3 or pts[:, 1].max() > ymax - 0.3:
            return False
    for s in spec.sensors:
        if s.name in view or s.camera is not None:
            if sees(s, poses[s.name], T, spec) != (s.name in view):
                return False
    return True


def _direction(
    spec: RigSpec, poses: dict[str, np.ndarray], view: tuple[str, ...], i: int
) -> tuple[float, float]:
    """(azimuth, jitter) rad: the mean looking direction of the view's cameras, or a golden-angle turn."""
    dirs = []
    for n in view:
        cam = spec.sensor(n).camera
        if cam is not None and not cam.periodic_u:
            dirs.append(poses[n][:3, :3] @ cam.R_flu_cam.T @ np.array([1.0, 0.0, 0.0]))
    if not dirs:
        return float(i * GOLDEN), np.deg2rad(15.0)
    d = np.sum(dirs, axis=0)
    return float(np.arctan2(d[1], d[0])), np.deg2rad(12.0 if len(dirs) == 1 else 5.0)


def _elevations(spec: RigSpec, view: tuple[str, ...], d: float) -> tuple[float, float]:
    """(lo, hi) rad of the board centre's elevation that keeps it inside the view's LiDARs' fields
    (each taken as level; the exact test is ``sees``)."""
    x0, x1, y0, y1 = spec.board.extent()
    a = np.arcsin(min(1.0, 0.5 * np.hypot(x1 - x0, y1 - y0) / d)) + np.deg2rad(1.0)
    lidars = [spec.sensor(n) for n in view if spec.sensor(n).lidar is not None]
    lidars = lidars or [s for s in spec.sensors if s.lidar is not None][:1]
    lo = max(np.deg2rad(s.lidar.vertical_angles_deg[0]) + a for s in lidars)  # type: ignore[union-attr]
    hi = min(np.deg2rad(s.lidar.vertical_angles_deg[-1]) - a for s in lidars)  # type: ignore[union-attr]
    return float(lo), float(hi)


def _place(spec: RigSpec, poses: dict[str, np.ndarray], view: tuple[str, ...], i: int) -> np.ndarray:
    rng = frame_rng(spec.seed, PURPOSE_RIG_PLACEMENT, i)
    target = np.mean([poses[n][:3, 3] for n in view], axis=0)
    lidars = [n for n in view if spec.sensor(n).lidar is not None]
    base = np.mean([poses[n][:3, 3] for n in lidars], axis=0) if lidars else np.zeros(3)
    az0, jitter = _direction(spec, poses, view, i)
    near, far = spec.scene.board_distance_m
    for attempt in range(ATTEMPTS):
        relax = attempt / ATTEMPTS
        d = near + rng.random() * (far - near) + 1.5 * relax
        az = az0 + rng.uniform(-1.0, 1.0) * jitter * (1.0 - relax)
        lo, hi = _elevations(spec, view, d)
        el = 0.5 * (lo + hi) + (0.0 if hi < lo else rng.uniform(-0.4, 0.4) * (hi - lo))
        centre = base + d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        roll = np.deg2rad(45.0 + 90.0 * rng.integers(4) + rng.uniform(-8, 8))
        pitch, yaw = np.deg2rad(rng.uniform(-15, 15)), np.deg2rad(rng.uniform(-25, 25))
        T = pose_facing(spec.board, centre, target, roll, pitch, yaw)
        if _acceptable(spec, poses, view, T):
            return T
    raise ValueError(
        f"moment {i + 1}: no board placement is seen whole by {', '.join(view)}"
        + " and by no other camera" * any(s.camera is not None and s.name not in view for s in spec.sensors)
    )


def rig_placements(spec: RigSpec, poses: dict[str, np.ndarray]) -> list[np.ndarray]:
    """``T_body_board`` (4, 4) per moment: ``spec.placements`` if given, else drawn for ``spec.views``.

    poses: {sensor: true ``T_body_sensor``} (``RigSpec.poses()``, a moved mount applied)."""
    if spec.placements is not None:
        return [np.array(T) for T in spec.placements]
    return [_place(spec, poses, spec.views[i % len(spec.views)], i) for i in range(int(spec.n_moments))]
