"""What to simulate: :class:`SimulationSpec` and its option groups, and :func:`standard_spec`.

Frames follow ``shared/interface.md``: LiDAR x forward, y left, z up; ``T_cam_lidar`` maps LiDAR
points into the camera frame (the camera model's axes, ``CameraModel.R_flu_cam``: equirectangular
x forward, y left, z up; lens models OpenCV's z forward, x right, y down). Lengths are metres,
angles degrees where a name says ``_deg``.

Default magnitudes and why:

- board noise (1.6, 1.6, 10) mm along the board's x, y and normal: the paper's Section 6.2
  baseline, times ``noise_scale``. Other surfaces: range noise with the LiDAR model's
  ``range_sigma_m`` times ``noise_scale`` (HDL-32E: 20 mm, its data sheet accuracy).
- :class:`Systematics` (all switchable, ``Systematics.off()`` gives the paper's white-noise
  baseline): per-beam range bias sigma 3 mm (residual of a factory beam calibration), dark
  surfaces reading 4 mm farther (range walk of a weak return), 0.2 % dropped returns overall and
  up to 2 % on black print, and a global ``range_offset_m`` (0 by default). An extra switch,
  off by default: ``beam_intensity_gain_sigma``, a relative intensity gain per beam (uneven
  per-laser intensity calibration; 0.05 is a plausible value).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..board import Board
from ..cameras import CameraModel, Equirectangular, camera_class
from ..lidars import LASER_ID_ELEVATIONS_DEG, LidarModel, lidar_model
from .intrinsics_error import IntrinsicsError
from .rosette import rosette_for

__all__ = [
    "SENSOR_FORMATS",
    "INTENSITY_FIELDS",
    "Systematics",
    "RenderOptions",
    "SceneOptions",
    "SimulationSpec",
    "standard_spec",
    "default_T_cam_lidar",
    "paper_board",
]

#: how simulated scans are written (see simulate/lidar.py)
SENSOR_FORMATS = ("plain", "ouster", "velodyne-csv")
#: what a scan's intensity field holds (see simulate/lidar.py): the printed pattern as the LiDAR sees
#: it; a print the LiDAR cannot see (black reads as white); every value 0; the ring number
INTENSITY_FIELDS = ("print", "invisible", "zero", "none", "ring")
#: Default camera centre in the LiDAR frame (m): a camera mounted 25 cm above the LiDAR.
DEFAULT_CAMERA_CENTRE_LIDAR = (0.05, -0.03, 0.25)
#: Default small rotation (rotation vector, degrees) between the nominal and the true camera axes.
DEFAULT_ROTVEC_DEG = (2.0, -3.0, 4.0)


def paper_board() -> Board:
    """The board of ILCC's sample data and our default: 6 x 8 squares of 75 mm, no margin, black origin."""
    return Board(6, 8, 0.075)


@dataclass(frozen=True)
class Systematics:
    """Systematic LiDAR errors, each off when its number is 0.

    beam_bias_sigma_m: sigma of a constant range bias per beam (drawn once per data set).
    dark_range_offset_m: extra range on black print (scaled by 1 - colour; white reads true).
    dropout: probability that a return is lost anywhere.
    dropout_black: probability on black print (linear in 1 - colour between white and black).
    range_offset_m: constant added to every range (a global offset, e.g. a LiDAR zero error).
    beam_intensity_gain_sigma: sigma of a relative intensity gain per beam (uneven per-laser
        intensity calibration; drawn once per data set).
    board_plane_sigma: (offset m, tilt rad) sigmas of a random plane per frame between the board's
        LiDAR returns and its printed face (a bent print or backing, the LiDAR's errors that move a
        board's returns as a whole): the returns come from a face ``delta + alpha x + beta y``
        nearer the sensor (board-frame x, y from the pattern's centre); the camera sees the print.
    edge_returns: beams whose footprint straddles the board's outline return from the board, from
        behind it or as a mixed return between the two (``simulate/edges.py``); off: the centre ray
        alone decides, a sharp edge.
    """

    beam_bias_sigma_m: float = 0.003
    dark_range_offset_m: float = 0.004
    dropout: float = 0.002
    dropout_black: float = 0.02
    range_offset_m: float = 0.0
    beam_intensity_gain_sigma: float = 0.0
    board_plane_sigma: tuple[float, float] = (0.0, 0.0)
    edge_returns: bool = False

    def __post_init__(self) -> None:
        for name in ("beam_bias_sigma_m", "dark_range_offset_m", "beam_intensity_gain_sigma"):
            if not np.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                raise ValueError(f"Systematics: {name} must be finite and >= 0, got {getattr(self, name)!r}")
        for name in ("dropout", "dropout_black"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ValueError(f"Systematics: {name} must be in [0, 1), got {getattr(self, name)!r}")
        bp = tuple(self.board_plane_sigma)
        if len(bp) != 2 or not all(np.isfinite(v) and v >= 0 for v in bp):
            raise ValueError(f"Systematics: board_plane_sigma must be two sigmas >= 0, got {bp!r}")
        if not np.isfinite(self.range_offset_m):
            raise ValueError(f"Systematics: range_offset_m must be finite, got {self.range_offset_m!r}")

    @classmethod
    def off(cls) -> Systematics:
        """No systematic error at all: the paper's white-noise baseline."""
        return cls(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class RenderOptions:
    """How images are rendered.

    supersample: S; pixels on the edges of moving objects and of the print get S x S rays.
    blur_sigma_px: Gaussian blur of the whole image (0 = none).
    noise_sigma: Gaussian pixel noise, grey levels (0 = none).
    textured_background: procedural texture on walls, floor and ceiling (else flat colours).
    """

    supersample: int = 3
    blur_sigma_px: float = 0.6
    noise_sigma: float = 2.0
    textured_background: bool = True

    def __post_init__(self) -> None:
        if not (1 <= int(self.supersample) <= 8):
            raise ValueError(f"RenderOptions: supersample must be in 1..8, got {self.supersample!r}")
        if self.blur_sigma_px < 0 or self.noise_sigma < 0:
            raise ValueError("RenderOptions: blur_sigma_px and noise_sigma must be >= 0")


@dataclass(frozen=True)
class SceneOptions:
    """The static scene and the clutter, LiDAR frame.

    lidar_height_m: LiDAR origin above the ground (ground plane at z = -lidar_height_m).
    room: (xmin, xmax, ymin, ymax) of the walls, or None for an open scene (ground only).
    ceiling_height_m: ceiling above the ground (ignored when ``room`` is None).
    clutter: a person-sized box standing near some boards.
    person_probability: chance per frame of the person when ``clutter``.
    stand: the board stands on a thin pole reaching the ground.
    board_distance_m: (near, far) distances of the default board placements from the LiDAR, m
        (``placements.board_placements``).
    """

    lidar_height_m: float = 1.5
    room: tuple[float, float, float, float] | None = (-4.5, 5.5, -3.5, 4.5)
    ceiling_height_m: float = 3.0
    clutter: bool = True
    person_probability: float = 0.6
    stand: bool = True
    board_distance_m: tuple[float, float] = (1.2, 2.6)

    def __post_init__(self) -> None:
        lo, hi = (float(v) for v in self.board_distance_m)
        if not 0.3 < lo <= hi:
            raise ValueError(
                f"SceneOptions: board_distance_m must be 0.3 < near <= far, got {self.board_distance_m!r}"
            )
        object.__setattr__(self, "board_distance_m", (lo, hi))


@dataclass(frozen=True, eq=False)
class SimulationSpec:
    """Everything a simulated data set depends on; same spec, same bytes.

    lidar: LiDAR model name (``lidars.MODEL_NAMES``) or a ready :class:`LidarModel`.
    camera: the true camera model, which renders the images (config.yaml states it as is, or
        perturbed by ``intrinsics_error``; ground_truth.yaml records it as ``camera_truth``).
    intrinsics_error: how far config.yaml's camera is from ``camera`` (off by default).
    board: the chessboard.
    n_frames: number of frames (board placements).
    seed: master seed; every random stream is derived from it with ``np.random.SeedSequence``.
    unit_seed: the seed of the sensors' own draws (each beam's range bias and intensity gain, the
        error of config.yaml's intrinsics); None: ``seed``. Sets with one ``unit_seed`` and different
        seeds are captures of one rig (the calibration's set and a ``verify`` capture).
    noise_scale: multiplies every geometric LiDAR noise sigma (board and range noise).
    T_cam_lidar: (4, 4) true extrinsic; None -> :func:`default_T_cam_lidar` of the camera.
    board_noise_sigma_m: (3,) sigma along the board's x, y and normal, before ``noise_scale``.
    range_noise_m: None, or the range noise (one sigma, m) of every return along its beam, the board's
        too, in place of ``board_noise_sigma_m`` and the model's ``range_sigma_m`` (a real LiDAR's
        noise: its ranges are noisy, its beams' directions are not; ``noise_scale`` then leaves the
        geometry alone).
    systematics: switchable systematic errors.
    placements: explicit ``T_lidar_board`` (4, 4) per frame (overrides ``n_frames``) or None.
    scene, image: option groups.
    intensity_black, intensity_white: mean LiDAR intensity on black and white print.
    intensity_sigma_black, intensity_sigma_white: its noise on each.
    beam_aperture_m: beam diameter at the sensor; footprint diameter = aperture + divergence * range.
    sensor_format: how the scans look on disk, like a real driver's (``SENSOR_FORMATS``, see
        simulate/lidar.py): ``"plain"`` (PCD, ring 0 = lowest, intensity 0-255), ``"ouster"``
        (organised PCD, ring 0 = top, raw signal intensity, (0, 0, 0) for lost returns) or
        ``"velodyne-csv"`` (ILCC CSV with the hardware laser_id; hdl32 and vlp16). A scanline-free
        lidar (``livox-mid40``, ``livox-mid70``) writes ``"plain"`` PCDs without ring field
        (intensity: Livox's reflectivity 0-255).
    integration_time_s: how long a scanline-free lidar's returns are accumulated into one scan
        (a spinning lidar's scan is one turn whatever this says). 0.5 s: 50,000 returns of a
        Mid-40/70, about half of the Mid-70's field covered.
    intensity_field: what the scans' intensity holds (``INTENSITY_FIELDS``): ``"print"`` the
        printed pattern (default); ``"invisible"`` a print the LiDAR cannot see (dye inks in the
        near infrared: black print returns like white, with no dark range offset or extra
        dropout); ``"zero"`` every intensity 0 (a simulator or driver that fills none); ``"none"``
        no intensity field at all (x y z only: Open3D's legacy clouds, MATLAB's ``pcwrite`` of a cloud
        without Intensity, a depth camera's or a simulator's cloud);
        ``"ring"`` the ring value as the file writes it (a driver that puts the ring number in the
        field named intensity). The print's effect on range is kept for ``"zero"``, ``"none"`` and
        ``"ring"``.
    ring_field: False writes scans without a ring field (an organised Ouster scan keeps its rows).
    """

    lidar: str | LidarModel = "hdl32"
    camera: CameraModel = field(default_factory=lambda: Equirectangular(8000, 4000))
    intrinsics_error: IntrinsicsError = field(default_factory=IntrinsicsError)
    board: Board = field(default_factory=paper_board)
    n_frames: int = 20
    seed: int = 0
    unit_seed: int | None = None
    noise_scale: float = 1.0
    T_cam_lidar: np.ndarray | None = None
    board_noise_sigma_m: tuple[float, float, float] = (0.0016, 0.0016, 0.010)
    range_noise_m: float | None = None
    systematics: Systematics = field(default_factory=Systematics)
    placements: tuple[np.ndarray, ...] | None = None
    scene: SceneOptions = field(default_factory=SceneOptions)
    image: RenderOptions = field(default_factory=RenderOptions)
    intensity_black: float = 10.0
    intensity_white: float = 80.0
    intensity_sigma_black: float = 1.5
    intensity_sigma_white: float = 4.0
    beam_aperture_m: float = 0.01
    sensor_format: str = "plain"
    integration_time_s: float = 0.5
    intensity_field: str = "print"
    ring_field: bool = True

    def __post_init__(self) -> None:
        model = self.lidar if isinstance(self.lidar, LidarModel) else lidar_model(self.lidar)
        self.intrinsics_error.sigmas(self.camera)  # ValueError: an error on a camera without intrinsics
        object.__setattr__(self, "_lidar_model", model)
        if self.sensor_format not in SENSOR_FORMATS:
            raise ValueError(
                f"SimulationSpec: sensor_format must be one of {SENSOR_FORMATS}, got {self.sensor_format!r}"
            )
        if self.intensity_field not in INTENSITY_FIELDS:
            raise ValueError(
                f"SimulationSpec: intensity_field must be one of {INTENSITY_FIELDS}, "
                f"got {self.intensity_field!r}"
            )
        if not self.ring_field and self.sensor_format == "velodyne-csv":
            raise ValueError(
                "SimulationSpec: a 'velodyne-csv' scan always has its laser_id column (ring_field)"
            )
        if model.ringless:
            rosette_for(model)  # ValueError: no pattern to render
            if self.sensor_format != "plain":
                raise ValueError(
                    f"SimulationSpec: a scanline-free lidar ({model.name}) writes 'plain' scans, "
                    f"got sensor_format {self.sensor_format!r}"
                )
        if not (np.isfinite(self.integration_time_s) and 0 < self.integration_time_s <= 10):
            raise ValueError(
                f"SimulationSpec: integration_time_s must be in (0, 10] s, got {self.integration_time_s!r}"
            )
        if self.sensor_format == "velodyne-csv" and model.name not in LASER_ID_ELEVATIONS_DEG:
            raise ValueError(
                f"SimulationSpec: sensor_format 'velodyne-csv' needs a lidar with a known laser_id numbering "
                f"({sorted(LASER_ID_ELEVATIONS_DEG)}), got {model.name!r}"
            )
        T = default_T_cam_lidar(self.camera) if self.T_cam_lidar is None else _check_pose(self.T_cam_lidar)
        T.setflags(write=False)
        object.__setattr__(self, "T_cam_lidar", T)
        if self.placements is not None:
            ps = tuple(_check_pose(p) for p in self.placements)
            if not ps:
                raise ValueError("SimulationSpec: placements must hold at least one pose")
            object.__setattr__(self, "placements", ps)
            object.__setattr__(self, "n_frames", len(ps))
        if int(self.n_frames) < 1:
            raise ValueError(f"SimulationSpec: n_frames must be >= 1, got {self.n_frames!r}")
        rn = self.range_noise_m
        if rn is not None and not (np.isfinite(rn) and rn >= 0):
            raise ValueError(f"SimulationSpec: range_noise_m must be finite and >= 0, got {rn!r}")
        if not (np.isfinite(self.noise_scale) and self.noise_scale >= 0):
            raise ValueError(f"SimulationSpec: noise_scale must be finite and >= 0, got {self.noise_scale!r}")
        if int(self.seed) < 0 or int(self.units_seed) < 0:
            raise ValueError(f"SimulationSpec: seeds must be >= 0, got {self.seed!r}, {self.unit_seed!r}")
        sig = tuple(float(s) for s in self.board_noise_sigma_m)
        if len(sig) != 3 or min(sig) < 0:
            raise ValueError(f"SimulationSpec: board_noise_sigma_m must be 3 numbers >= 0, got {sig!r}")
        object.__setattr__(self, "board_noise_sigma_m", sig)

    @property
    def true_T_cam_lidar(self) -> np.ndarray:
        """(4, 4) the true extrinsic: ``T_cam_lidar`` as resolved at construction (never None)."""
        T = self.T_cam_lidar
        if T is None:
            raise AssertionError("SimulationSpec.__post_init__ sets T_cam_lidar")
        return T

    @property
    def units_seed(self) -> int:
        """The seed of the sensors' own draws: ``unit_seed``, or ``seed`` when None."""
        return int(self.seed if self.unit_seed is None else self.unit_seed)

    @property
    def lidar_model(self) -> LidarModel:
        """The resolved :class:`LidarModel`."""
        return self._lidar_model  # type: ignore[attr-defined]

    def with_(self, **changes: Any) -> SimulationSpec:
        """A copy with some fields changed (``dataclasses.replace``).

        A new ``camera`` also gets its default ``T_cam_lidar`` (its own nominal axes) when the
        current one is the old camera's default and no ``T_cam_lidar`` is given.
        """
        cam = changes.get("camera")
        if (
            cam is not None
            and "T_cam_lidar" not in changes
            and np.array_equal(self.true_T_cam_lidar, default_T_cam_lidar(self.camera))
        ):
            changes["T_cam_lidar"] = None
        return replace(self, **changes)

    def summary(self) -> dict[str, Any]:
        """Plain-data description of the settings (for ground_truth.yaml)."""
        s = self.systematics
        return {
            "lidar_model": self.lidar_model.name,
            "sensor_format": self.sensor_format,
            **({"integration_time_s": float(self.integration_time_s)} if self.lidar_model.ringless else {}),
            **({"intensity_field": self.intensity_field} if self.intensity_field != "print" else {}),
            **({"ring_field": False} if not self.ring_field else {}),
            "camera_model": self.camera.kind,
            "intrinsics_error": self.intrinsics_error.summary(),
            "n_frames": int(self.n_frames),
            "seed": int(self.seed),
            **({"unit_seed": int(self.unit_seed)} if self.unit_seed is not None else {}),
            "noise_scale": float(self.noise_scale),
            "board_noise_sigma_m": [float(v * self.noise_scale) for v in self.board_noise_sigma_m],
            "range_sigma_m": float(self.lidar_model.range_sigma_m * self.noise_scale),
            **({"range_noise_m": float(self.range_noise_m)} if self.range_noise_m is not None else {}),
            "systematics": {
                "beam_bias_sigma_m": s.beam_bias_sigma_m,
                "dark_range_offset_m": s.dark_range_offset_m,
                "dropout": s.dropout,
                "dropout_black": s.dropout_black,
                "range_offset_m": s.range_offset_m,
                "beam_intensity_gain_sigma": s.beam_intensity_gain_sigma,
                "board_plane_sigma": [float(v) for v in s.board_plane_sigma],
            },
            "image": {
                "supersample": int(self.image.supersample),
                "blur_sigma_px": float(self.image.blur_sigma_px),
                "noise_sigma": float(self.image.noise_sigma),
            },
            "lidar_height_m": float(self.scene.lidar_height_m),
        }


def _check_pose(T: Any) -> np.ndarray:
    T = np.array(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"pose must be a finite (4, 4) matrix, got shape {T.shape}")
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1) > 1e-6:
        raise ValueError("pose's 3x3 block is not a rotation")
    if np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-12:
        raise ValueError("pose's last row must be [0, 0, 0, 1]")
    return T


def default_T_cam_lidar(camera: str | CameraModel) -> np.ndarray:
    """The default true extrinsic for a camera (or camera kind), (4, 4).

    The camera centre sits at ``DEFAULT_CAMERA_CENTRE_LIDAR`` in the LiDAR frame (25 cm above it);
    its axes are the camera model's nominal ones looking along LiDAR x (``R_flu_cam.T``, the LiDAR
    frame being forward-left-up: equirectangular the LiDAR's own, lens models OpenCV's with z along
    LiDAR x) turned by the rotation vector ``DEFAULT_ROTVEC_DEG``.
    """
    R_flu_cam = (camera_class(camera) if isinstance(camera, str) else camera).R_flu_cam
    R_small = Rotation.from_rotvec(np.deg2rad(DEFAULT_ROTVEC_DEG)).as_matrix()
    R = R_small @ R_flu_cam.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ np.asarray(DEFAULT_CAMERA_CENTRE_LIDAR)
    return T


def default_camera(kind: str, width: int | None = None) -> CameraModel:
    """A camera of the given kind with plausible intrinsics (``CameraModel.default``), ``width`` px wide."""
    return camera_class(kind).default(width)


def standard_spec(
    lidar: str = "hdl32",
    camera: str = "equirectangular",
    width: int | None = None,
    frames: int = 20,
    seed: int = 0,
    noise_scale: float = 1.0,
    **overrides: Any,
) -> SimulationSpec:
    """The paper's Section 6.2 set-up (and more) for a LiDAR and camera kind.

    camera: a camera kind (``cameras.camera_kinds()``); its ``default(width)`` intrinsics.
    width: image width in pixels; None -> the kind's default (equirectangular 8000, pinhole 1920, ...).
    overrides: any other :class:`SimulationSpec` field (``systematics=Systematics.off()``, ...).
    """
    return SimulationSpec(
        lidar=lidar,
        camera=default_camera(camera, width),
        n_frames=frames,
        seed=seed,
        noise_scale=noise_scale,
        **overrides,
    )
