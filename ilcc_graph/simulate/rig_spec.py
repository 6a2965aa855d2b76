"""Simulated rigs (several cameras and LiDARs) with ground truth: :class:`RigSpec`, the preset rigs
:func:`ring_rig` and :func:`backpack_rig`, and :func:`simulate_moments` (pure, in memory).

The scene is the single-pair simulator's (room, board on its stand, maybe a person), built in the
rig's body frame (x forward, y left, z up; origin at the body origin, the ground at
``-scene.lidar_height_m``). Each sensor sits at ``T_body_sensor``; LiDARs are ray cast from their
own origin (``simulate_scan(..., T_scene_lidar)``), cameras rendered by the single-pair renderer
(``ImageRenderer`` of a spec whose ``T_cam_lidar`` maps the body frame into the camera). Every sensor
has its own random streams (its seed is drawn from the rig's seed), and the room's texture is the
same for every camera. Boards are placed by ``rig_placements.py`` so that the sensors of each
``views`` entry see the whole board. ``moved`` turns and shifts one sensor's mount (for ``verify``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..board import Board
from ..cameras import CameraModel, Equirectangular
from ..config import RigConfig, RigData, RigSensor
from ..io.rig_truth import RigGroundTruth
from ..lidars import LidarModel, lidar_model
from ..types import Scan
from .lidar import beam_biases, simulate_scan
from .placements import _occludes, frame_scene
from .render import ImageRenderer
from .rig_placements import rig_placements, sees
from .scene import SURF_PERSON
from .spec import RenderOptions, SceneOptions, SimulationSpec, Systematics, default_camera, paper_board

__all__ = [
    "RIG_PRESETS", "Mount", "RigMoment", "RigSensorSpec", "RigSpec", "backpack_rig", "horizontal_fov_deg",
    "mount", "rig_ground_truth", "ring_rig", "simulate_moments",
]  # fmt: skip

PURPOSE_RIG_SENSOR = 7  # stream key of the per-sensor seeds (placements.py: 0-2, intrinsics.py: 9)


def _T(xyz: Any, R: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.asarray(xyz, dtype=np.float64)
    return T


def mount(xyz_m: Any, ypr_deg: Any, R_flu_sensor: np.ndarray, tweak_deg: Any = (0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) ``T_body_sensor`` of a sensor at ``xyz_m`` whose forward-left-up axes are turned by
    ``ypr_deg`` (yaw, pitch, roll; REP 103), then by the small rotation vector ``tweak_deg`` in its own
    frame (how far the real mount is from the drawing)."""
    R = Rotation.from_euler("ZYX", ypr_deg, degrees=True).as_matrix() @ R_flu_sensor
    return _T(xyz_m, R @ Rotation.from_rotvec(np.deg2rad(tweak_deg)).as_matrix())


@dataclass(frozen=True, eq=False)
class RigSensorSpec:
    """One simulated sensor: its name, true pose ``T_body_sensor`` (4, 4), and either a ``camera``
    (the true camera model) or a ``lidar`` (model name or :class:`LidarModel`, with its
    ``sensor_format``, ``spec.SENSOR_FORMATS``). nominal: (4, 4) the mount as drawn, written to
    rig.yaml as the pose guess (None: no guess)."""

    name: str
    T_body_sensor: np.ndarray
    camera: CameraModel | None = None
    lidar: str | LidarModel | None = None
    sensor_format: str = "plain"
    nominal: np.ndarray | None = None

    def __post_init__(self) -> None:
        if (self.camera is None) == (self.lidar is None):
            raise ValueError(f"RigSensorSpec {self.name}: give exactly one of camera or lidar")
        if isinstance(self.lidar, str):
            object.__setattr__(self, "lidar", lidar_model(self.lidar))

    @property
    def kind(self) -> str:
        return "camera" if self.camera is not None else "lidar"

    @property
    def R_flu_sensor(self) -> np.ndarray:
        return np.eye(3) if self.camera is None else np.asarray(self.camera.R_flu_cam)


@dataclass(frozen=True)
class Mount:
    """A moved mount: sensor ``sensor`` turned by the rotation vector ``rotation_deg`` and shifted by
    ``translation_mm``, both in its own frame (``T_body_sensor @ [Exp(rotation), translation]``)."""

    sensor: str
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    translation_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def delta(self) -> np.ndarray:
        """(4, 4) the change in the sensor's own frame."""
        R = Rotation.from_rotvec(np.deg2rad(self.rotation_deg)).as_matrix()
        return _T(np.asarray(self.translation_mm, dtype=np.float64) / 1000.0, R)


@dataclass(frozen=True, eq=False)
class RigSpec:
    """Everything a simulated rig set depends on; same spec, same bytes.

    sensors: the sensors, in order; reference: the name whose frame the truth is given in.
    views: per moment (cycled), the sensors that must see the whole board; a camera not listed
        must not see all of it (a LiDAR not listed may). n_moments, seed: as the single-pair spec's.
    unit_seed: the seed of the sensors' own draws (a LiDAR's beam biases and gains); None: ``seed``.
        Sets with one ``unit_seed`` and different seeds are captures of one rig.
    placements: explicit ``T_body_board`` (4, 4) per moment (overrides views and n_moments) or None.
    moved: one sensor's mount moved (a ``verify`` capture) or None.
    only_seen: a camera writes an image only at the moments it sees the whole board (so moments
        lack some sensors; LiDARs always scan).
    board, noise_scale, systematics, scene, image: as :class:`SimulationSpec`'s.
    """

    sensors: tuple[RigSensorSpec, ...]
    reference: str
    views: tuple[tuple[str, ...], ...]
    n_moments: int = 12
    seed: int = 0
    unit_seed: int | None = None
    placements: tuple[np.ndarray, ...] | None = None
    moved: Mount | None = None
    only_seen: bool = False
    board: Board = field(default_factory=paper_board)
    noise_scale: float = 1.0
    systematics: Systematics = field(default_factory=Systematics)
    scene: SceneOptions = field(default_factory=SceneOptions)
    image: RenderOptions = field(default_factory=RenderOptions)

    def __post_init__(self) -> None:
        names = [s.name for s in self.sensors]
        if len(names) < 2 or len(set(names)) != len(names):
            raise ValueError(f"RigSpec: at least two sensors with distinct names, got {names}")
        if self.reference not in names:
            raise ValueError(f"RigSpec: reference {self.reference!r} is not one of {names}")
        if not any(s.kind == "lidar" for s in self.sensors):
            raise ValueError("RigSpec: a rig needs at least one LiDAR (the scene is laid out around it)")
        bad = [v for v in self.views if not v or not set(v) <= set(names)]
        if not self.views or bad:
            raise ValueError(
                f"RigSpec: views must be non-empty lists of sensor names {names}, got {bad or 'none'}"
            )
        if self.moved is not None and self.moved.sensor not in names:
            raise ValueError(f"RigSpec: moved sensor {self.moved.sensor!r} is not one of {names}")
        if self.placements is not None:
            object.__setattr__(
                self, "placements", tuple(np.array(T, dtype=np.float64) for T in self.placements)
            )
            object.__setattr__(self, "n_moments", len(self.placements))
        if int(self.n_moments) < 1 or min(int(self.seed), int(self.unit_seed or 0)) < 0:
            raise ValueError(
                f"RigSpec: n_moments >= 1 and seeds >= 0, got {self.n_moments}, {self.seed}, {self.unit_seed}"
            )

    def with_(self, **changes: Any) -> RigSpec:
        """A copy with some fields changed (``dataclasses.replace``)."""
        return replace(self, **changes)

    def sensor(self, name: str) -> RigSensorSpec:
        return next(s for s in self.sensors if s.name == name)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.sensors)

    def poses(self) -> dict[str, np.ndarray]:
        """{sensor: (4, 4) true ``T_body_sensor``}, the moved mount applied."""
        out = {s.name: np.array(s.T_body_sensor, dtype=np.float64) for s in self.sensors}
        if self.moved is not None:
            out[self.moved.sensor] = out[self.moved.sensor] @ self.moved.delta()
        return out

    def T_ref_sensor(self) -> dict[str, np.ndarray]:
        """{sensor: (4, 4) true pose in the reference's frame}, the moved mount applied."""
        poses = self.poses()
        return {n: np.linalg.solve(poses[self.reference], T) for n, T in poses.items()}

    def sensor_seed(self, name: str, unit: bool = False) -> int:
        """The seed of sensor ``name``'s simulation, drawn from ``seed`` (``unit``: of its own draws,
        from ``unit_seed`` when set)."""
        seed = self.unit_seed if unit and self.unit_seed is not None else self.seed
        k = self.names.index(name)
        return int(np.random.SeedSequence(int(seed), spawn_key=(PURPOSE_RIG_SENSOR, k)).generate_state(1)[0])

    def sensor_spec(self, name: str) -> SimulationSpec:
        """The single-pair spec that simulates sensor ``name`` in the body frame (its own seed): a camera
        with ``T_cam_lidar`` = its ``T_sensor_body``; a LiDAR (cast with ``T_scene_lidar``)."""
        s, poses = self.sensor(name), self.poses()
        lidar = s.lidar if s.lidar is not None else next(x.lidar for x in self.sensors if x.lidar is not None)
        camera = s.camera if s.camera is not None else Equirectangular(64, 32)
        T_cam_body = np.linalg.inv(poses[name]) if s.camera is not None else np.eye(4)
        return SimulationSpec(
            lidar=lidar, camera=camera, board=self.board, n_frames=1, seed=self.sensor_seed(name),
            unit_seed=None if self.unit_seed is None else self.sensor_seed(name, unit=True),
            noise_scale=self.noise_scale, T_cam_lidar=T_cam_body, systematics=self.systematics,
            scene=self.scene, image=self.image, sensor_format=s.sensor_format,
        )  # fmt: skip

    def rig_config(self, topics: dict[str, str] | None = None, bag: str | None = None) -> RigConfig:
        """The rig.yaml this set is written with: the true sensor models, nominal mounts as guesses,
        a folder per sensor named after it (or ``topics`` of ``bag``)."""
        poses = {s.name: s.nominal for s in self.sensors}
        ref = poses[self.reference]
        sensors = tuple(
            RigSensor(
                s.name,
                s.kind,
                camera=s.camera,
                lidar=s.lidar,  # type: ignore[arg-type]
                folder=s.name,
                topic=None if topics is None else topics[s.name],
                T_ref_sensor=None
                if ref is None or (pose := poses[s.name]) is None
                else np.linalg.solve(ref, pose),
            )  # fmt: skip
            for s in self.sensors
        )
        return RigConfig(self.board, sensors, self.reference, RigData(bag=bag))


@dataclass(frozen=True, eq=False)
class RigMoment:
    """One simulated moment: its name (``0001``...), ``T_body_board`` (4, 4), the sensors that see the
    whole board, and each sensor's data: ``scans`` {lidar: Scan (its own frame)}, ``images``
    {camera: (H, W, 3) BGR uint8} (a camera missing when ``only_seen`` and it does not see the board)."""

    name: str
    T_body_board: np.ndarray
    seen_by: tuple[str, ...]
    scans: dict[str, Scan]
    images: dict[str, np.ndarray]


def simulate_moments(spec: RigSpec, scene_keys: Sequence[int] | None = None) -> Iterator[RigMoment]:
    """Yield the moments of ``spec`` one at a time (each camera's empty room rendered once).

    The boards are placed for the unmoved rig, so a capture with ``moved`` has the same boards as
    the one without (the same seed). scene_keys: per moment, the key of the scene's random draws
    (the person); default the moment's index (a walk keeps one key per placement)."""
    poses = spec.poses()
    boards = rig_placements(spec, spec.with_(moved=None).poses())
    first_cam = next((s.name for s in spec.sensors if s.camera is not None), spec.sensors[0].name)
    scene_spec = spec.sensor_spec(first_cam).with_(seed=int(spec.seed))
    specs = {n: spec.sensor_spec(n) for n in spec.names}
    texture = ImageRenderer(scene_spec).texture  # one room for every camera (made once)
    flat = replace(spec.image, textured_background=False)
    renderers = {
        s.name: ImageRenderer(specs[s.name].with_(image=flat)) for s in spec.sensors if s.camera is not None
    }
    for r in renderers.values():
        r.texture = texture
    biases = {s.name: beam_biases(specs[s.name]) for s in spec.sensors if s.lidar is not None}
    origins = [T[:3, 3] for T in poses.values()]
    for i, T in enumerate(boards):
        scene = frame_scene(scene_spec, T, i if scene_keys is None else int(scene_keys[i]))
        targets = np.vstack(
            [scene.board_outline_samples(16), T[:3, :3] @ spec.board.pattern_centre + T[:3, 3]]
        )
        boxes = tuple(
            b for b in scene.boxes if b.surface != SURF_PERSON or not _occludes(b, origins, targets)
        )
        scene = replace(scene, boxes=boxes)  # no person in any sensor's way
        seen = tuple(n for n in spec.names if sees(spec.sensor(n), poses[n], T, spec))
        scans = {n: simulate_scan(specs[n], scene, i, biases[n], poses[n]) for n in biases}
        images = {n: r.render(scene, i) for n, r in renderers.items() if not spec.only_seen or n in seen}
        yield RigMoment(f"{i + 1:04d}", T.copy(), seen, scans, images)


def _mounted(name: str, xyz: Any, ypr: Any, tweak: Any, **kw: Any) -> RigSensorSpec:
    """A sensor at ``xyz`` m turned by ``ypr`` deg as drawn (its ``nominal``), truly off by ``tweak`` deg."""
    cam = kw.get("camera")
    R_flu = np.eye(3) if cam is None else cam.R_flu_cam
    return RigSensorSpec(name, mount(xyz, ypr, R_flu, tweak), nominal=mount(xyz, ypr, R_flu), **kw)


def horizontal_fov_deg(cam: CameraModel) -> float:
    """Degrees between the bearings of the middle row's first and last pixel (360 when it wraps)."""
    mid = (cam.height - 1) / 2
    b = cam.bearing(np.array([[0.0, mid], [cam.width - 1.0, mid]])) @ np.asarray(cam.R_flu_cam).T
    az = np.degrees(np.arctan2(b[:, 1], b[:, 0]))
    return float(az[0] - az[1]) if np.all(np.isfinite(az)) and not cam.periodic_u else 360.0


def _narrowed(cam: CameraModel, max_deg: float) -> CameraModel:
    """``cam`` with fx and fy raised in 5 % steps until its horizontal field is at most ``max_deg``."""
    if cam.intrinsic_names[:2] != ("fx", "fy"):
        return cam
    theta = cam.intrinsics().copy()
    while horizontal_fov_deg(cam) > max_deg:
        theta[:2] *= 1.05
        cam = cam.with_intrinsics(theta)
    return cam


def ring_rig(
    camera: str = "pinhole", width: int | None = 640, lidar: str = "hdl32", n_moments: int = 12, **kw: Any
) -> RigSpec:
    """One LiDAR (the reference) and four lens cameras of one kind at 90 deg yaw steps (front, left,
    back, right), 12 cm out from the LiDAR's axis and 20 cm above it, each off its drawn mount by a
    known small rotation. A camera wider than 140 deg is narrowed to 140 deg (fx, fy raised), so that a
    board can be seen by one camera alone. Up to 100 deg wide (pinhole: 90): each board is seen by one
    camera, so no camera pair shares a board. Wider (fisheye): per 8 boards front+left share 2,
    left+back 1, back+right and right+front none."""
    names = ("front", "left", "back", "right")
    sensors = [RigSensorSpec("lidar", np.eye(4), lidar=lidar, nominal=np.eye(4))]
    cam = _narrowed(default_camera(camera, width), 140.0)
    for k, name in enumerate(names):
        yaw = 90.0 * k
        xyz = [0.12 * np.cos(np.deg2rad(yaw)), 0.12 * np.sin(np.deg2rad(yaw)), 0.20]
        tweak = np.array([1.0, -1.5, 2.0]) * (1.0 if k % 2 == 0 else -0.7)
        sensors.append(_mounted(name, xyz, (yaw, 0.0, 0.0), tweak, camera=cam))
    F, L, B, R = names
    views: tuple[tuple[str, ...], ...]
    if horizontal_fov_deg(cam) > 100.0:
        views = ((F,), (F, L), (L,), (L, B), (B,), (R,), (F, L), (R,))
    else:
        views = ((F,), (L,), (B,), (R,))
    return RigSpec(tuple(sensors), "lidar", tuple((*v, "lidar") for v in views), n_moments=n_moments, **kw)


def backpack_rig(width: int | None = 2400, n_moments: int = 12, **kw: Any) -> RigSpec:
    """A mapping backpack: a VLP-16 (the reference) level at the body origin, an OS1-64 above and
    behind it turned 90 deg left and tipped 3 deg, and a panorama on a mast 45 cm above; each off its
    drawn mount by a known small rotation. Boards seen by the panorama and both LiDARs, or by the
    panorama and one LiDAR (in turn)."""
    pano = default_camera("equirectangular", width)
    sensors = (
        RigSensorSpec("vlp16", np.eye(4), lidar="vlp16", nominal=np.eye(4)),
        _mounted(
            "os1",
            [-0.08, 0.0, 0.12],
            (90.0, -3.0, 0.0),
            (0.8, -0.5, 1.2),
            lidar="os1-64",
            sensor_format="ouster",
        ),
        _mounted("pano", [0.02, 0.0, 0.45], (0.0, 0.0, 0.0), (-1.0, 1.5, 2.5), camera=pano),
    )
    views = (("pano", "vlp16", "os1"), ("pano", "vlp16"), ("pano", "vlp16", "os1"), ("pano", "os1"))
    return RigSpec(sensors, "vlp16", views, n_moments=n_moments, **kw)


def rig_ground_truth(
    spec: RigSpec, moments: Iterable[tuple[str, np.ndarray, tuple[str, ...]]]
) -> RigGroundTruth:
    """The truth of a written set: every sensor's pose and, per moment (name, ``T_body_board``,
    ``seen_by``), the board's pose in the reference's frame; ``extra``: the moved mount (and the
    unmoved poses), the true cameras, the LiDARs' models and beam biases, the settings."""
    T_ref = spec.T_ref_sensor()
    T_body_ref = spec.poses()[spec.reference]
    boards, seen = {}, {}
    for name, T_body_board, seen_by in moments:
        boards[name] = np.linalg.solve(T_body_ref, T_body_board)
        seen[name] = tuple(seen_by)
    extra: dict[str, Any] = {"moved": None}
    if spec.moved is not None:
        m = spec.moved
        extra["moved"] = {
            "sensor": m.sensor,
            "rotation_deg": list(m.rotation_deg),
            "translation_mm": list(m.translation_mm),
        }
        extra["T_ref_sensor_unmoved"] = spec.with_(moved=None).T_ref_sensor()
    extra["cameras"] = {s.name: s.camera.to_dict() for s in spec.sensors if s.camera is not None}
    extra["lidars"] = {s.name: {"model": s.lidar.name, "sensor_format": s.sensor_format,  # type: ignore[union-attr]
                                "beam_bias_m": beam_biases(spec.sensor_spec(s.name)).tolist()}
                       for s in spec.sensors if s.lidar is not None}  # fmt: skip
    extra["simulation"] = {
        "seed": int(spec.seed), **({"unit_seed": int(spec.unit_seed)} if spec.unit_seed is not None else {}),
        "n_moments": int(spec.n_moments), "noise_scale": float(spec.noise_scale),
        "views": [list(v) for v in spec.views], "only_seen": bool(spec.only_seen),
        "board": spec.board.to_dict(),
        "systematics": spec.sensor_spec(spec.reference).summary()["systematics"],
    }  # fmt: skip
    return RigGroundTruth(spec.reference, T_ref, boards, seen, extra)


#: the preset rigs by name (``ring_rig`` with its camera kind, ``backpack_rig``), each ``f(**kw) -> RigSpec``
RIG_PRESETS: dict[str, Callable[..., RigSpec]] = {
    "ring-pinhole": lambda **kw: ring_rig("pinhole", **kw),
    "ring-fisheye": lambda **kw: ring_rig("fisheye", **kw),
    "backpack": backpack_rig,
}
