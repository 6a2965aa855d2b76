"""Board placements like the paper's Section 6.2 and the per-frame scene around each board.

Default placements (LiDAR frame): frames are split over five horizontal directions (72 deg apart
for a panoramic camera, whose columns wrap; spread over the horizontal field of view otherwise), four per
direction for 20 frames. Each board sits 1.2-2.6 m away (``SceneOptions.board_distance_m``; the distances
of one direction staggered over that range), its azimuth jittered by up to 12 deg, its centre at a height
that keeps the whole board inside the LiDAR's vertical field of view; it faces the sensors (board z
towards the point between LiDAR and camera), is turned 45 deg in its plane (a diamond; plus a random
quarter turn and up to 8 deg jitter, so every corner of the pattern may end up lowest) and tilted by up to
15 deg (pitch) and 25 deg (yaw). A placement is redrawn until the board is fully inside the LiDAR's
vertical field, inside the room and (not panoramic) inside the image with a 3 % border; after repeated
failures the draws move farther out (up to 1.5 m beyond the far distance) and, when not panoramic, towards
the middle of the view (e.g. a VLP-16's +-15 deg field cannot hold a 0.75 m board at 1.2 m).
A scanline-free lidar's field is a cone about x (``vertical_angles_deg`` = +-its half-angle): the
directions are spread over its width (for a panorama too) and the board must lie inside the cone.

Per frame: a thin pole (3 x 3 cm) from the ground up to just below and behind the board's lowest
point, and, with ``SceneOptions.person_probability``, a person-sized box (0.44 x 0.28 x 1.7 m)
beside the board that occludes it from neither sensor.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..board import Board
from .scene import SURF_PERSON, SURF_POLE, Box, Scene, cast_rays
from .spec import SimulationSpec

__all__ = [
    "board_placements",
    "moved_placements",
    "frame_scene",
    "static_scene",
    "frame_rng",
    "camera_centre_lidar",
    "pose_facing",
]

# stream keys for np.random.SeedSequence(seed, spawn_key=(purpose, ...))
PURPOSE_UNIT, PURPOSE_PLACEMENT, PURPOSE_FRAME = 0, 1, 2
N_DIRECTIONS = 5
PERSON_HALF = np.array([0.22, 0.14, 0.85])


def frame_rng(seed: int, *key: int) -> np.random.Generator:
    """An independent generator for one purpose (and frame, stream): random access, order-free."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=tuple(int(k) for k in key)))


def camera_centre_lidar(T_cam_lidar: np.ndarray) -> np.ndarray:
    """(3,) camera centre in the LiDAR frame."""
    return -T_cam_lidar[:3, :3].T @ T_cam_lidar[:3, 3]


def static_scene(spec: SimulationSpec) -> Scene:
    """The room without board, stand or person."""
    so = spec.scene
    ground = _ground_z(spec)
    ceiling = None if so.room is None else ground + float(so.ceiling_height_m)
    return Scene(ground, so.room, ceiling)


def _ground_z(spec: SimulationSpec) -> float:
    """Height of the ground (LiDAR frame z): the static scene always has one."""
    return -float(spec.scene.lidar_height_m)


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _pose(spec: SimulationSpec, centre: np.ndarray, roll: float, pitch: float, yaw: float) -> np.ndarray:
    """T_lidar_board with the pattern centre at ``centre`` facing the sensors, then tilted and rolled."""
    target = 0.5 * camera_centre_lidar(spec.true_T_cam_lidar)  # between LiDAR and camera
    return pose_facing(spec.board, centre, target, roll, pitch, yaw)


def pose_facing(
    board: Board, centre: np.ndarray, target: np.ndarray, roll: float, pitch: float, yaw: float
) -> np.ndarray:
    """(4, 4) board pose with the pattern centre at ``centre``, its z towards ``target`` (x level),
    then turned by ``yaw`` (about its y), ``pitch`` (about x) and ``roll`` (about z), radians."""
    z0 = target - centre
    z0 /= np.linalg.norm(z0)
    x0 = np.cross([0.0, 0.0, 1.0], z0)
    x0 /= np.linalg.norm(x0)
    y0 = np.cross(z0, x0)
    R = np.column_stack([x0, y0, z0]) @ _rot_y(yaw) @ _rot_x(pitch) @ _rot_z(roll)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre - R @ board.pattern_centre
    return T


def _cone_half_angle(spec: SimulationSpec) -> float | None:
    """Half-angle (rad) of a scanline-free lidar's circular field about x; None for a spinning one."""
    m = spec.lidar_model
    return float(np.deg2rad(np.abs(m.vertical_angles_deg).max())) if m.ringless else None


def _azimuth_range(spec: SimulationSpec) -> tuple[float, float] | None:
    """Horizontal span (rad, LiDAR azimuth) of the image's middle row (within a scanline-free lidar's
    cone); None for a panorama (columns wrap) with a spinning lidar."""
    cam = spec.camera
    cone = _cone_half_angle(spec)
    lim = float(np.deg2rad(80.0)) if cone is None else 0.8 * cone
    if cam.periodic_u:
        return None if cone is None else (-lim, lim)
    uv = np.column_stack([np.linspace(0, cam.width - 1, 81), np.full(81, (cam.height - 1) / 2)])
    b = cam.bearing(uv)
    d = b[np.all(np.isfinite(b), axis=1)] @ spec.true_T_cam_lidar[:3, :3]  # rows: R_lidar_cam b
    az = np.arctan2(d[:, 1], d[:, 0])
    return float(max(az.min(), -lim)), float(min(az.max(), lim))


def _acceptable(spec: SimulationSpec, T: np.ndarray) -> bool:
    ground = _ground_z(spec)
    scene = Scene(ground, None, None, spec.board, T)
    pts = scene.board_outline_samples(16)
    el = np.degrees(np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1])))
    va = spec.lidar_model.vertical_angles_deg
    if el.min() < va[0] + 0.3 or el.max() > va[-1] - 0.3 or pts[:, 2].min() < ground + 0.3:
        return False
    cone = _cone_half_angle(spec)
    if cone is not None:
        off_axis = np.arccos(np.clip(pts[:, 0] / np.linalg.norm(pts, axis=1), -1.0, 1.0))
        if off_axis.max() > cone - np.deg2rad(0.5):
            return False
    room = spec.scene.room
    if room is not None:
        xmin, xmax, ymin, ymax = room
        if pts[:, 0].min() < xmin + 0.3 or pts[:, 0].max() > xmax - 0.3:
            return False
        if pts[:, 1].min() < ymin + 0.3 or pts[:, 1].max() > ymax - 0.3:
            return False
    cam = spec.camera
    if not cam.periodic_u:
        T_cam_lidar = spec.true_T_cam_lidar
        uv = cam.project(pts @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3])
        bw, bh = 0.03 * cam.width, 0.03 * cam.height
        if not np.all(np.isfinite(uv)):
            return False
        if (uv[:, 0].min() < bw or uv[:, 0].max() > cam.width - 1 - bw or uv[:, 1].min() < bh
                or uv[:, 1].max() > cam.height - 1 - bh):  # fmt: skip
            return False
    return True


def board_placements(spec: SimulationSpec) -> list[np.ndarray]:
    """``T_lidar_board`` (4, 4) per frame: ``spec.placements`` if given, else the paper-like layout."""
    if spec.placements is not None:
        return [np.array(T) for T in spec.placements]
    n = int(spec.n_frames)
    az_range = _azimuth_range(spec)
    if az_range is None:
        centres = np.deg2rad(72.0 * np.arange(N_DIRECTIONS))
        jitter = np.deg2rad(12.0)
    else:
        edges = np.linspace(*az_range, N_DIRECTIONS + 1)
        centres = 0.5 * (edges[1:] + edges[:-1])
        jitter = 0.3 * (edges[1] - edges[0])
    x0, x1, y0, y1 = spec.board.extent()
    radius = 0.5 * np.hypot(x1 - x0, y1 - y0)
    va = np.deg2rad(spec.lidar_model.vertical_angles_deg)
    cone = _cone_half_angle(spec)
    direction = (np.arange(n) * N_DIRECTIONS) // n
    out = []
    for i in range(n):
        rng = frame_rng(spec.seed, PURPOSE_PLACEMENT, i)
        members = np.flatnonzero(direction == direction[i])
        j, m = int(np.searchsorted(members, i)), len(members)
        lo, hi = spec.scene.board_distance_m
        for attempt in range(400):
            relax = attempt / 400.0
            d = lo + (j + rng.random()) * (hi - lo) / m + 1.5 * relax  # move out when nothing fits
            # not panoramic: drift towards the middle of the view when nothing fits
            az = centres[direction[i]] + rng.uniform(-1, 1) * jitter * (1.0 - relax)
            if az_range is not None:
                az = (1.0 - relax) * az + relax * 0.5 * (az_range[0] + az_range[1])
            a = np.arcsin(min(1.0, radius / d))
            el_lo, el_hi = va[0] + a + np.deg2rad(1.0), va[-1] - a - np.deg2rad(1.0)
            if cone is not None:  # inside the cone at this azimuth: cos(el) cos(az) >= cos(room)
                c = np.cos(max(cone - a - np.deg2rad(1.0), 0.0)) / max(np.cos(az), 1e-9)
                el_hi = float(np.arccos(c)) if c <= 1.0 else -1.0
                el_lo = -el_hi
            el = 0.5 * (el_lo + el_hi) + (0.0 if el_hi < el_lo else rng.uniform(-0.4, 0.4) * (el_hi - el_lo))
            centre = d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
            roll = np.deg2rad(45.0 + 90.0 * rng.integers(4) + rng.uniform(-8, 8))
            pitch, yaw = np.deg2rad(rng.uniform(-15, 15)), np.deg2rad(rng.uniform(-25, 25))
            T = _pose(spec, centre, roll, pitch, yaw)
            if _acceptable(spec, T):
                break
        else:
            raise ValueError(
                f"frame {i + 1}: no board placement fits the LiDAR's and camera's fields of view"
            )
        out.append(T)
    return out


def moved_placements(spec: SimulationSpec, k: int) -> dict[int, np.ndarray]:
    """``k`` frames of ``spec`` (drawn from its seed) with their board moved 20-60 mm and 1-3 deg
    (random directions, about the pattern's centre), as a hand-held board moves between the scan
    and the photo: frame index -> the moved ``T_lidar_board`` (4, 4), metres. Simulate the photos
    with ``replace(spec, placements=...)`` and put them in place of those frames' images."""
    rng = np.random.default_rng([spec.seed, 38])
    poses = board_placements(spec)
    centre = np.append(spec.board.pattern_centre, 1.0)
    out = {}
    for i in sorted(rng.choice(len(poses), size=min(k, len(poses)), replace=False)):
        axis, way = rng.normal(size=3), rng.normal(size=3)
        angle = np.radians(rng.uniform(1.0, 3.0))
        turn = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()
        T = np.array(poses[i], dtype=np.float64)
        c = (T @ centre)[:3]
        moved = np.eye(4)
        moved[:3, :3] = turn @ T[:3, :3]
        moved[:3, 3] = turn @ (T[:3, 3] - c) + c + rng.uniform(0.02, 0.06) * way / np.linalg.norm(way)
        out[int(i)] = moved
    return out


def _pole(scene_ground: float, T_lidar_board: np.ndarray, outline: np.ndarray) -> Box:
    """A vertical 3 x 3 cm pole from the ground to 1 cm below and 2.5 cm behind the board's lowest point."""
    low = outline[np.argmin(outline[:, 2])]
    n = T_lidar_board[:3, 2]
    top = low - 0.025 * n - np.array([0.0, 0.0, 0.01])
    h = max(top[2] - scene_ground, 0.02)
    T = np.eye(4)
    T[:3, :3] = _rot_z(float(np.arctan2(n[1], n[0])))
    T[:3, 3] = [top[0], top[1], scene_ground + 0.5 * h]
    return Box(T, np.array([0.015, 0.015, 0.5 * h]), SURF_POLE)


def _occludes(box: Box, origins: list[np.ndarray], targets: np.ndarray) -> bool:
    single = Scene(None, None, None, boxes=(box,))
    for o in origins:
        d = targets - o
        dist = np.linalg.norm(d, axis=1)
        hits = cast_rays(single, o, d / dist[:, None])
        if np.any(hits.t < dist):
            return True
    return False


def frame_scene(spec: SimulationSpec, T_lidar_board: np.ndarray, frame: int) -> Scene:
    """The full scene of one frame: room, board at ``T_lidar_board``, its stand and maybe a person."""
    base, ground = static_scene(spec), _ground_z(spec)
    probe = Scene(base.ground_z, base.room, base.ceiling_z, spec.board, T_lidar_board)
    boxes: list[Box] = []
    outline = probe.board_outline_samples(16)
    if spec.scene.stand:
        boxes.append(_pole(ground, T_lidar_board, outline))
    rng = frame_rng(spec.seed, PURPOSE_FRAME, frame, 0)
    if spec.scene.clutter and rng.random() < spec.scene.person_probability:
        centre = T_lidar_board[:3, :3] @ spec.board.pattern_centre + T_lidar_board[:3, 3]
        d_board = float(np.hypot(centre[0], centre[1]))
        az_board = float(np.arctan2(centre[1], centre[0]))
        x0, x1, y0, y1 = spec.board.extent()
        a_board = np.arcsin(min(1.0, 0.5 * np.hypot(x1 - x0, y1 - y0) / d_board))
        origins = [np.zeros(3), camera_centre_lidar(spec.true_T_cam_lidar)]
        targets = np.vstack([outline, centre])
        for _ in range(20):
            d = d_board + rng.uniform(-0.2, 1.2)
            az = az_board + rng.choice([-1.0, 1.0]) * (
                a_board + np.arctan(0.35 / d) + np.deg2rad(rng.uniform(5, 25))
            )
            T = np.eye(4)
            T[:3, :3] = _rot_z(rng.uniform(-np.pi, np.pi))
            T[:3, 3] = [d * np.cos(az), d * np.sin(az), ground + PERSON_HALF[2]]
            person = Box(T, PERSON_HALF.copy(), SURF_PERSON)
            if base.room is not None:
                xmin, xmax, ymin, ymax = base.room
                c = person.corners()
                if c[:, 0].min() < xmin + 0.3 or c[:, 0].max() > xmax - 0.3:
                    continue
                if c[:, 1].min() < ymin + 0.3 or c[:, 1].max() > ymax - 0.3:
                    continue
            if d < 1.0 or _occludes(person, origins, targets):
                continue
            boxes.append(person)
            break
    return Scene(base.ground_z, base.room, base.ceiling_z, spec.board, np.array(T_lidar_board), tuple(boxes))
