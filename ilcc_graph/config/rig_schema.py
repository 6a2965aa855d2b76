"""The reader of ``rig.yaml`` (docs/rig.md): :func:`load_rig_config` -> :class:`RigConfig`.

Schema::

    reference: <sensor name>          the frame every pose is given in
    board:    as config.yaml's board section (without roi: a roi belongs to a LiDAR)
    data:     (optional) bag (path; without it a folder per sensor), sync_tolerance s, anchor
              (sensor), select auto|pauses|all, min_pause s, max_moments
    sensors:
      <name>:
        camera: as config.yaml's camera section      (exactly one of camera / lidar)
        lidar:  as config.yaml's lidar section ({} or empty: the scans' own beam table)
        roi:    (LiDARs) as config.yaml's board.roi, in this LiDAR's frame
        folder: (folder layout) default <name>, relative to the rig file's folder
        topic:  (bag layout) default the only topic of its type
        T_ref_sensor: (optional guess) a 4x4 matrix, or {xyz_m: [f, l, u], ypr_deg: [y, p, r]}

A single-pair ``config.yaml`` (ours or ILCC's) is read as the rig of one LiDAR and one camera
(``rig.rig_from_config``). Every failure is an ``InputError`` naming the file, the key path
(``sensors.front.camera.K``), the value and what was expected.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from ..cameras import camera_from_config
from ..checks import MISSING, Checker
from ..errors import InputError
from ..io.files import SMALL_FILE, read_yaml
from .camera_file import camera_section
from .ours import parse_board, parse_lidar, parse_roi
from .rig_config import SELECT, RigConfig, RigData, RigSensor, pose_from_flu, rig_from_config

__all__ = ["load_rig_config", "parse_rig_config"]

TOP_KEYS = ("reference", "board", "data", "sensors")
DATA_KEYS = ("bag", "sync_tolerance", "anchor", "select", "min_pause", "max_moments")
SENSOR_KEYS = ("camera", "lidar", "roi", "folder", "topic", "T_ref_sensor")
GUESS_KEYS = ("xyz_m", "ypr_deg")
NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
T = TypeVar("T")


class _Prefixed(Checker):
    """A Checker whose key paths start with ``prefix`` (a section's parser reused one level down)."""

    def __init__(self, source: str, prefix: str) -> None:
        super().__init__(source)
        self.prefix = prefix

    def fail(self, key: str, value: Any, expected: str) -> InputError:
        return super().fail(self.prefix + key, value, expected)


def _under(source: str, prefix: str, fn: Callable[..., T], *args: Any) -> T:
    """``fn(*args)`` whose InputError's key path (``<source>: camera.K``) gets ``prefix`` in front."""
    try:
        return fn(*args)
    except InputError as err:
        msg = str(err)
        head = f"{source}: "
        raise InputError(head + prefix + msg[len(head) :] if msg.startswith(head) else msg) from None


def _pose(c: Checker, v: Any, key: str, R_flu_ref: np.ndarray, R_flu_sensor: np.ndarray) -> np.ndarray:
    if isinstance(v, dict):
        c.unknown(v, GUESS_KEYS, key)
        xyz = c.numbers(v.get("xyz_m", [0.0, 0.0, 0.0]), f"{key}.xyz_m", 3, lo=-1000.0, hi=1000.0)
        ypr = c.numbers(v.get("ypr_deg", [0.0, 0.0, 0.0]), f"{key}.ypr_deg", 3, lo=-360.0, hi=360.0)
        return pose_from_flu(xyz, ypr, R_flu_ref, R_flu_sensor)
    what = (
        "a 4x4 rigid transform (4 rows of 4 numbers, last row [0, 0, 0, 1]) or {xyz_m: [...], ypr_deg: [...]}"
    )
    if not isinstance(v, (list, tuple)) or len(v) != 4:
        raise c.fail(key, v, what)
    M = np.array([c.numbers(row, f"{key}[{i}]", 4) for i, row in enumerate(v)])
    R = M[:3, :3]
    if np.abs(M[3] - [0, 0, 0, 1]).max() > 1e-9:
        raise c.fail(key, v, what)
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
        raise c.fail(key, v, "a rigid transform: its 3x3 block must be a rotation (orthonormal, det +1)")
    return M


def _data(c: Checker, d: Any, names: list[str]) -> RigData:
    if d is None:
        return RigData()
    d = c.section(d, "data")
    c.unknown(d, DATA_KEYS, "data")
    bag = d.get("bag")
    if bag is not None and not isinstance(bag, str):
        raise c.fail("data.bag", bag, "a path to a ROS bag, relative to the rig file's folder")
    anchor = d.get("anchor")
    if anchor is not None and anchor not in names:
        raise c.fail("data.anchor", anchor, f"one of the sensors {names}")
    num = c.number
    return RigData(
        bag=bag,
        sync_tolerance=num(
            d.get("sync_tolerance", 0.05), "data.sync_tolerance", lo=0.0, hi=10.0, lo_open=True
        ),
        anchor=anchor,
        select=c.choice(d.get("select", "auto"), "data.select", SELECT),
        min_pause=num(d.get("min_pause", 1.0), "data.min_pause", lo=0.0, hi=3600.0, lo_open=True),
        max_moments=int(num(d.get("max_moments", 60), "data.max_moments", lo=1, hi=100000, integer=True)),
    )


def _sensor(c: Checker, name: Any, d: Any, base: Path) -> RigSensor:
    key = f"sensors.{name}"
    if not isinstance(name, str) or not NAME.match(name):
        raise c.fail(key, name, "a sensor name of letters, digits, '_', '.', '-' (it names a folder)")
    d = c.section(d, key)
    c.unknown(d, SENSOR_KEYS, key)
    kinds = [k for k in ("camera", "lidar") if k in d]
    if len(kinds) != 1:
        raise c.fail(key, d, "exactly one of the sections camera (a camera) or lidar (a LiDAR)")
    folder, topic = d.get("folder", name), d.get("topic")
    if not isinstance(folder, str) or not folder.strip():
        raise c.fail(f"{key}.folder", folder, "a folder path (relative to the rig file's folder)")
    if topic is not None and (not isinstance(topic, str) or not topic.strip()):
        raise c.fail(f"{key}.topic", topic, "a topic name of the bag, e.g. /front/image_raw")
    if kinds == ["camera"]:
        if "roi" in d:
            raise c.fail(f"{key}.roi", d["roi"], "no roi on a camera (a roi limits a LiDAR's board search)")
        section = camera_section(_Prefixed(c.source, f"{key}."), d["camera"], base)
        camera = _under(c.source, f"{key}.", camera_from_config, section, c.source)
        return RigSensor(name, "camera", camera=camera, folder=folder, topic=topic)
    section = d["lidar"]
    lc = _Prefixed(c.source, f"{key}.")
    lidar, col = parse_lidar(lc, {} if section is None else lc.section(section, "lidar"), base)
    roi = None if d.get("roi") is None else parse_roi(c, d["roi"], f"{key}.roi")
    return RigSensor(name, "lidar", lidar=lidar, intensity_column=col, roi=roi, folder=folder, topic=topic)


def _unique(c: Checker, sensors: list[RigSensor], attr: str) -> None:
    seen: dict[Any, str] = {}
    for s in sensors:
        v = getattr(s, attr)
        if v is None:
            continue
        where = Path(v).as_posix() if attr == "folder" else v
        if where in seen:
            raise c.fail(f"sensors.{s.name}.{attr}", v, f"a {attr} of its own ({seen[where]} has it too)")
        seen[where] = s.name


def parse_rig_config(d: Any, source: str = "<rig>", base_dir: Path | str | None = None) -> RigConfig:
    """Validate a loaded ``rig.yaml`` mapping (or a single-pair config.yaml's) into a :class:`RigConfig`.

    source names the file in messages; base_dir is the folder relative paths start from."""
    base = Path(source).parent if base_dir is None else Path(base_dir)
    c = Checker(source)
    if not isinstance(d, dict):
        raise InputError(
            f"{source}: expected a mapping with reference, board and sensors; got {type(d).__name__}"
        )
    if "sensors" not in d:  # a single-pair config.yaml: the rig of one LiDAR and one camera
        from . import parse_config

        return rig_from_config(parse_config(d, source, base), base)
    c.unknown(d, TOP_KEYS, "")
    board_d = c.section(d.get("board", MISSING), "board")
    if board_d.get("roi") is not None:
        raise c.fail(
            "board.roi", board_d["roi"], "no roi here: a roi belongs to a LiDAR (sensors.<lidar>.roi)"
        )
    board, _ = parse_board(c, board_d)
    raw = c.section(d["sensors"], "sensors")
    if len(raw) < 2:
        raise c.fail("sensors", raw, "at least two sensors (a rig relates sensors to each other)")
    sensors = [_sensor(c, name, sd, base) for name, sd in raw.items()]
    _unique(c, sensors, "folder")
    _unique(c, sensors, "topic")
    names = [s.name for s in sensors]
    ref = d.get("reference", MISSING)
    if ref not in names:
        raise c.fail(
            "reference", ref, f"the name of the sensor whose frame the poses are given in, one of {names}"
        )
    R_flu_ref = next(s for s in sensors if s.name == ref).R_flu_sensor
    for i, s in enumerate(sensors):
        guess = raw[s.name].get("T_ref_sensor")
        if guess is None:
            continue
        key = f"sensors.{s.name}.T_ref_sensor"
        T = _pose(c, guess, key, R_flu_ref, s.R_flu_sensor)
        if s.name == ref and np.abs(T - np.eye(4)).max() > 1e-9:
            raise c.fail(key, guess, "nothing, or the identity: this is the reference sensor")
        sensors[i] = replace(s, T_ref_sensor=T)
    return RigConfig(board, tuple(sensors), ref, _data(c, d.get("data"), names), base, source)


def load_rig_config(path: str | Path) -> RigConfig:
    """Read and validate ``rig.yaml`` (or a single-pair config.yaml as a rig of two sensors).

    Raises ``InputError`` naming the file, the key, the value and what was expected."""
    p = Path(path)
    d = read_yaml(p, "rig file", SMALL_FILE)
    if d is None:
        raise InputError(f"{p}: rig file is empty; expected reference, board and sensors (docs/rig.md)")
    return parse_rig_config(d, str(p), p.parent)
