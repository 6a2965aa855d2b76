"""A rig: every sensor (cameras of any model, LiDARs of any kind), a reference sensor, one board, and
where each sensor's data are (:class:`RigConfig`, read from ``rig.yaml`` by ``config.rig_schema``).

Frames: ``T_ref_sensor`` maps a sensor's points into the reference sensor's frame
(``p_ref = T_ref_sensor @ p_sensor``), each sensor in its own frame (a LiDAR's, a camera model's
axes). A pose guess can also be written in forward-left-up (FLU) terms: ``xyz_m`` the sensor's
origin along the reference's forward, left and up axes, ``ypr_deg`` yaw, pitch, roll (intrinsic
z-y'-x'', REP 103: yaw left, pitch nose down, roll right side down) of the sensor's forward-left-up
axes against the reference's; a camera's FLU axes are its model's (``CameraModel.R_flu_cam``).
docs/rig.md has the schema and an example.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..board import Board
from ..cameras import CameraModel, RefinedIntrinsics
from ..lidars import LidarModel
from .model import Config, Roi

__all__ = [
    "PAIR_NAMES",
    "as_calibrated",
    "RigConfig",
    "RigData",
    "RigSensor",
    "flu_from_pose",
    "pose_from_flu",
    "rig_config_to_dict",
    "rig_from_config",
    "solved_camera",
]

#: the sensors of a single-pair data set seen as a rig: (LiDAR, camera) names, also their folders
#: in interface.md's layout (``DATA/pcd``, ``DATA/img``)
PAIR_NAMES = ("lidar", "camera")
PAIR_FOLDERS = {"lidar": "pcd", "camera": "img"}
SELECT = ("auto", "pauses", "all")


@dataclass(frozen=True, eq=False)
class RigSensor:
    """One sensor of a rig.

    name: unique, letters, digits and ``_ . -`` (a folder name). kind: ``"camera"`` or ``"lidar"``.
    camera: the camera model (cameras only). lidar: the beam table (LiDARs; None: the scans' own,
    measured). intensity_column: CSV column of intensity for files without header (LiDARs).
    roi: board-search limits in this LiDAR's frame, or None.
    folder: where its files are in the folder layout, relative to ``RigConfig.base_dir`` (or absolute).
    topic: its topic in the bag layout (None: the only topic of its type).
    T_ref_sensor: (4, 4) rough pose guess in the reference's frame, or None (identity for the reference).
    """

    name: str
    kind: str
    camera: CameraModel | None = None
    lidar: LidarModel | None = None
    intensity_column: int | None = None
    roi: Roi | None = None
    folder: str = ""
    topic: str | None = None
    T_ref_sensor: np.ndarray | None = None

    @property
    def R_flu_sensor(self) -> np.ndarray:
        """(3, 3) the sensor's axes in its forward-left-up frame (identity for a LiDAR)."""
        return np.eye(3) if self.camera is None else np.asarray(self.camera.R_flu_cam)


@dataclass(frozen=True)
class RigData:
    """Where the data are: ``bag`` (a ROS 1 bag, ROS 2 bag folder or storage file, relative to
    ``RigConfig.base_dir``) or None for a folder per sensor; the bag's pairing by time:
    ``sync_tolerance`` s, ``anchor`` (the sensor whose messages define the moments; None: the first
    LiDAR), ``select`` / ``min_pause`` s / ``max_moments`` as the single-pair bag source's
    ``select`` / ``min_pause`` / ``max_frames`` (docs/datasets.md)."""

    bag: str | None = None
    sync_tolerance: float = 0.05
    anchor: str | None = None
    select: str = "auto"
    min_pause: float = 1.0
    max_moments: int = 60


@dataclass(frozen=True, eq=False)
class RigConfig:
    """A resolved rig: the board, the sensors (in the file's order), the reference sensor's name,
    the data's place, the folder that relative paths start from and the file it came from."""

    board: Board
    sensors: tuple[RigSensor, ...]
    reference: str
    data: RigData = field(default_factory=RigData)
    base_dir: Path = field(default_factory=Path)
    source: str = ""

    def __post_init__(self) -> None:
        names = [s.name for s in self.sensors]
        if len(set(names)) != len(names):
            raise ValueError(f"RigConfig: sensor names must be unique, got {names}")
        if self.reference not in names:
            raise ValueError(f"RigConfig: reference {self.reference!r} is not one of the sensors {names}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.sensors)

    @property
    def cameras(self) -> tuple[str, ...]:
        """Names of the cameras, in the file's order."""
        return tuple(s.name for s in self.sensors if s.kind == "camera")

    @property
    def lidars(self) -> tuple[str, ...]:
        """Names of the LiDARs, in the file's order."""
        return tuple(s.name for s in self.sensors if s.kind == "lidar")

    def sensor(self, name: str) -> RigSensor:
        """The sensor called ``name``; KeyError naming the sensors otherwise."""
        for s in self.sensors:
            if s.name == name:
                return s
        raise KeyError(f"{self.source}: no sensor {name!r}; the sensors are {list(self.names)}")

    def folder(self, name: str) -> Path:
        """The folder of sensor ``name``'s files (folder layout)."""
        return self.base_dir / self.sensor(name).folder

    def bag_path(self) -> Path | None:
        return None if self.data.bag is None else self.base_dir / self.data.bag

    def with_intrinsics(self, refined: Mapping[str, Mapping[str, Any]]) -> tuple[RigConfig, list[str]]:
        """The rig with each camera as a calibration refined it (``as_calibrated``; ``refined``:
        {camera: its refined intrinsics as a calibration file's ``camera_intrinsics`` reads back});
        and a line per camera that keeps its own."""
        sensors: list[RigSensor] = []
        notes: list[str] = []
        for s in self.sensors:
            if s.camera is not None and (got := refined.get(s.name)) is not None:
                cam, note = as_calibrated(s.camera, RefinedIntrinsics.from_entry(got), s.name)
                s = replace(s, camera=cam)
                notes += [note] if note else []
            sensors.append(s)
        return replace(self, sensors=tuple(sensors)), notes

    def pair_config(self, camera: str, lidar: str) -> Config:
        """The single-pair :class:`Config` of one camera and one LiDAR of the rig (the stages' input)."""
        sc, sl = self.sensor(camera), self.sensor(lidar)
        if sc.camera is None or sl.kind != "lidar":
            raise ValueError(f"pair_config: {camera!r} must be a camera and {lidar!r} a LiDAR")
        return Config(self.board, sl.lidar, sc.camera, sl.roi, sl.intensity_column, self.source)


def as_calibrated(
    camera: CameraModel, refined: RefinedIntrinsics, name: str
) -> tuple[CameraModel, str | None]:
    """``camera`` with the intrinsics a calibration refined when it states the ones that calibration
    was made with (the same lens as configured then), taken as exact (their uncertainty is in the
    calibration's covariance; a stated ``intrinsics_sigma`` was the stated values'); else as it is,
    with a note on camera ``name``."""
    same = refined.names == camera.intrinsic_names
    if same and np.allclose(camera.intrinsics(), refined.stated, rtol=1e-9, atol=1e-12):
        return replace(camera.with_intrinsics(refined.values), intrinsics_sigma=None), None
    return camera, f"{name}: its intrinsics stated otherwise than calibrated: its own used"


def solved_camera(camera: CameraModel, sensors: Mapping[str, Any]) -> CameraModel:
    """``camera`` as a calibration's ``sensors`` (``Calibration.sensors``) refined it
    (``as_calibrated``), else as it is."""
    lens = sensors.get("camera_intrinsics")
    return camera if lens is None else as_calibrated(camera, RefinedIntrinsics.from_entry(lens), "camera")[0]


def rig_from_config(
    cfg: Config, base_dir: Path | str | None = None, data: RigData | None = None
) -> RigConfig:
    """A single-pair config as a rig of two sensors, ``lidar`` (the reference, folder ``pcd``) and
    ``camera`` (folder ``img``; or the folders of other common names the data set has,
    ``io.data_folders``): interface.md's folder layout is this rig's folder layout."""
    from ..io.frame_pairs import data_folders

    base = Path(cfg.source).parent if base_dir is None else Path(base_dir)
    on_disk = base.is_dir() and (data is None or data.bag is None)  # a bag's folder holds no frames
    scans, images = data_folders(base) if on_disk else (None, None)
    lidar = RigSensor(
        "lidar", "lidar", lidar=cfg.lidar, intensity_column=cfg.intensity_column, roi=cfg.roi,
        folder=scans or PAIR_FOLDERS["lidar"],
    )  # fmt: skip
    camera = RigSensor("camera", "camera", camera=cfg.camera, folder=images or PAIR_FOLDERS["camera"])
    return RigConfig(cfg.board, (lidar, camera), "lidar", data or RigData(), base, cfg.source)


def pose_from_flu(xyz_m: Any, ypr_deg: Any, R_flu_ref: np.ndarray, R_flu_sensor: np.ndarray) -> np.ndarray:
    """(4, 4) ``T_ref_sensor`` from a forward-left-up guess (module docstring)."""
    R_ypr = Rotation.from_euler("ZYX", np.asarray(ypr_deg, dtype=np.float64), degrees=True).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R_flu_ref.T @ R_ypr @ R_flu_sensor
    T[:3, 3] = R_flu_ref.T @ np.asarray(xyz_m, dtype=np.float64)
    return T


def flu_from_pose(
    T_ref_sensor: np.ndarray, R_flu_ref: np.ndarray, R_flu_sensor: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(xyz_m (3,), ypr_deg (3,)) of ``T_ref_sensor``: the inverse of :func:`pose_from_flu`."""
    T = np.asarray(T_ref_sensor, dtype=np.float64)
    R_ypr = R_flu_ref @ T[:3, :3] @ R_flu_sensor.T
    return R_flu_ref @ T[:3, 3], Rotation.from_matrix(R_ypr).as_euler("ZYX", degrees=True)


def _sensor_dict(
    s: RigSensor, R_flu_ref: np.ndarray, bag: bool, flu: bool, reference: bool
) -> dict[str, Any]:
    d: dict[str, Any] = {}
    if s.kind == "camera":
        d["camera"] = s.camera.to_dict()  # type: ignore[union-attr]
    else:
        lidar = {} if s.lidar is None else s.lidar.to_dict()
        if s.intensity_column is not None:
            lidar["intensity_column"] = int(s.intensity_column)
        d["lidar"] = lidar
        if s.roi is not None and not s.roi.is_empty():
            d["roi"] = s.roi.to_dict()
    if bag:
        if s.topic is not None:
            d["topic"] = s.topic
    elif s.folder != s.name:
        d["folder"] = s.folder
    if s.T_ref_sensor is not None and not reference:
        if flu:
            xyz, ypr = flu_from_pose(s.T_ref_sensor, R_flu_ref, s.R_flu_sensor)
            d["T_ref_sensor"] = {"xyz_m": [round(float(v), 6) + 0.0 for v in xyz],
                                 "ypr_deg": [round(float(v), 6) + 0.0 for v in ypr]}  # fmt: skip
        else:
            d["T_ref_sensor"] = np.asarray(s.T_ref_sensor, dtype=np.float64).tolist()
    return d


def rig_config_to_dict(rig: RigConfig, flu_guesses: bool = True) -> dict[str, Any]:
    """The rig in the ``rig.yaml`` schema (plain types; paths as given), e.g. to write beside results.

    flu_guesses: pose guesses as ``{xyz_m, ypr_deg}`` (else as 4x4 matrices)."""
    R_flu_ref = rig.sensor(rig.reference).R_flu_sensor
    bag = rig.data.bag is not None
    out: dict[str, Any] = {"reference": rig.reference, "board": rig.board.to_dict()}
    if rig.data != RigData():
        data = {k: getattr(rig.data, k) for k in RigData.__dataclass_fields__}
        out["data"] = {k: v for k, v in data.items() if v != getattr(RigData(), k)}
    out["sensors"] = {
        s.name: _sensor_dict(s, R_flu_ref, bag, flu_guesses, s.name == rig.reference) for s in rig.sensors
    }
    return out
