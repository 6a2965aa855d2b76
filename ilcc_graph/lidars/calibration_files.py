"""A unit's own beam table from the calibration file its driver uses (``lidar.calibration_file``).

Formats (picked by content, not by name):

- Ouster sensor metadata JSON (``ouster_client``/``ouster-ros`` "metadata", SDK ``SensorInfo``):
  ``beam_altitude_angles`` (deg, one per beam, first = top beam, = row 0 of the organised cloud),
  ``beam_azimuth_angles`` (deg), ``lidar_mode`` ``"<columns>x<Hz>"``; either at the top level
  (legacy layout) or nested as ``beam_intrinsics.beam_altitude_angles`` and
  ``config_params.lidar_mode`` (firmware 2.x and later; ``lidar_data_format.columns_per_frame``
  also gives the columns).
- Velodyne VeloView / ``db.xml``: per laser an ``id_`` and ``vertCorrection_`` (deg), optional
  ``rotCorrection_`` (deg), inside ``<item><px>..</px></item>`` of ``lasers_``.
- ROS ``velodyne_pointcloud`` YAML: ``lasers: [{laser_id, vert_correction (rad),
  rot_correction (rad), ...}]`` (and ``num_lasers``).
- Hesai correction CSV: header ``Laser id,Elevation,Azimuth`` then one line per channel (deg).

Returns a :class:`LidarModel` named ``measured`` (or the caller's name), with elevations sorted
ascending; the azimuth step comes from the Ouster mode, else from ``default_resolution_deg``
(the scan's own step replaces it later, see measure.py).
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import InputError, quote
from .tables import LidarModel

__all__ = ["read_calibration_file", "read_calibration_table", "CalibrationTable"]


@dataclass(frozen=True)
class CalibrationTable:
    """What a calibration file says: elevations (deg) and azimuth offsets (deg) per laser in the
    file's order (the hardware / ring numbering), the columns per turn (Ouster) or None, and the
    file's kind (``ouster-json``, ``velodyne-xml``, ``velodyne-yaml``, ``hesai-csv``)."""

    elevations_deg: np.ndarray
    azimuth_offsets_deg: np.ndarray
    columns: int | None
    kind: str


def _fail(path: Path, what: str) -> InputError:
    return InputError(f"{path}: {what}")


def _numbers(path: Path, v: object, key: str) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise _fail(path, f"{key} must be a list of numbers") from None
    if a.size < 1 or not np.all(np.isfinite(a)):
        raise _fail(path, f"{key} must be a non-empty list of finite numbers")
    return a


def _ouster(path: Path, d: dict) -> CalibrationTable:
    intr = d.get("beam_intrinsics", d)
    if "beam_altitude_angles" not in intr:
        raise _fail(path, "Ouster metadata without beam_altitude_angles")
    alt = _numbers(path, intr["beam_altitude_angles"], "beam_altitude_angles")
    azi = intr.get("beam_azimuth_angles")
    azi = np.zeros_like(alt) if azi is None else _numbers(path, azi, "beam_azimuth_angles")
    if azi.size != alt.size:
        raise _fail(path, f"{alt.size} beam_altitude_angles but {azi.size} beam_azimuth_angles")
    mode = d.get("lidar_mode", (d.get("config_params") or {}).get("lidar_mode"))
    columns = (d.get("lidar_data_format") or {}).get("columns_per_frame")
    if mode is not None:
        try:
            columns = int(str(mode).lower().split("x")[0])
        except ValueError:
            raise _fail(
                path, f"lidar_mode {quote(mode)} is not '<columns>x<rate>' (e.g. '1024x10')"
            ) from None
    if columns is not None and not (isinstance(columns, int) and columns > 0):
        raise _fail(path, f"columns per frame must be a positive integer, got {quote(columns)}")
    return CalibrationTable(alt, azi, columns, "ouster-json")


def _velodyne_xml(path: Path, text: str) -> CalibrationTable:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise _fail(path, f"not valid XML ({e})") from None
    ids, vert, rot = [], [], []
    for el in root.iter():
        v, i = el.find("vertCorrection_"), el.find("id_")
        if v is None or i is None:
            continue
        try:
            ids.append(int(i.text or ""))
            vert.append(float(v.text or ""))
            r = el.find("rotCorrection_")
            rot.append(float(r.text) if r is not None and r.text else 0.0)
        except ValueError:
            raise _fail(
                path, f"laser entry with non-numeric id_/vertCorrection_ ({i.text!r}, {v.text!r})"
            ) from None
    if not ids:
        raise _fail(path, "XML without Velodyne laser entries (<px><id_>..</id_><vertCorrection_>..)")
    order = np.argsort(ids)
    return CalibrationTable(np.asarray(vert)[order], np.asarray(rot)[order], None, "velodyne-xml")


def _velodyne_yaml(path: Path, d: dict) -> CalibrationTable:
    lasers = d.get("lasers")
    if not isinstance(lasers, list) or not lasers:
        raise _fail(path, "velodyne YAML without a 'lasers' list")
    rows = []
    for k, las in enumerate(lasers):
        if not isinstance(las, dict) or "vert_correction" not in las:
            raise _fail(path, f"lasers[{k}] has no vert_correction")
        try:
            rows.append(
                (
                    int(las.get("laser_id", k)),
                    float(las["vert_correction"]),
                    float(las.get("rot_correction", 0.0)),
                )
            )
        except (TypeError, ValueError):
            raise _fail(
                path, f"lasers[{k}]: laser_id, vert_correction and rot_correction must be numbers"
            ) from None
    rows.sort()
    a = np.degrees(np.array([r[1] for r in rows]))
    return CalibrationTable(a, np.degrees(np.array([r[2] for r in rows])), None, "velodyne-yaml")


def _hesai_csv(path: Path, text: str) -> CalibrationTable:
    rows = []
    for ln in text.splitlines()[1:]:
        parts = [t.strip() for t in ln.split(",")]
        if len(parts) < 3 or not parts[0]:
            continue
        try:
            rows.append((int(parts[0]), float(parts[1]), float(parts[2])))
        except ValueError:
            if ln.strip().lower().startswith("eeff"):
                continue
            raise _fail(path, f"bad Hesai correction line {ln!r}") from None
    if not rows:
        raise _fail(path, "Hesai correction CSV without channel lines")
    rows.sort()
    return CalibrationTable(np.array([r[1] for r in rows]), np.array([r[2] for r in rows]), None, "hesai-csv")


def read_calibration_table(
    path: str | Path, text: str | None = None, load_yaml: Callable[[str], Any] = yaml.safe_load
) -> CalibrationTable:
    """Parse a calibration file (any of the module's formats); InputError naming the problem.

    text: the file's content when the caller read it already (``config`` reads it bounded in size:
    ``io.read_bounded``); load_yaml: the YAML loader (``config``'s refuses duplicate keys and
    alias bombs)."""
    p = Path(path)
    if text is None:
        if not p.is_file():
            raise _fail(p, "calibration file not found")
        try:
            text = p.read_text(encoding="utf-8-sig")
        except (OSError, UnicodeDecodeError) as e:
            raise _fail(p, f"cannot read the calibration file ({e})") from None
    head = text.lstrip()[:200].lower()
    if head.startswith("{"):
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise _fail(p, f"not valid JSON ({e})") from None
        return _ouster(p, d)
    if head.startswith("<"):
        return _velodyne_xml(p, text)
    if head.startswith("laser id") or head.startswith("eeff"):
        return _hesai_csv(p, text)
    try:
        d = load_yaml(text)
    except yaml.YAMLError as e:
        raise _fail(p, f"not an Ouster JSON, Velodyne XML/YAML or Hesai CSV calibration file ({e})") from None
    if isinstance(d, dict) and "lasers" in d:
        return _velodyne_yaml(p, d)
    if isinstance(d, dict) and ("beam_altitude_angles" in d or "beam_intrinsics" in d):
        return _ouster(p, d)
    raise _fail(p, "not an Ouster metadata JSON, Velodyne db.xml / YAML or Hesai correction CSV")


def read_calibration_file(
    path: str | Path,
    name: str = "measured",
    default_resolution_deg: float = 0.2,
    range_sigma_m: float = 0.03,
    beam_divergence_rad: float = 3e-3,
    text: str | None = None,
    load_yaml: Callable[[str], Any] = yaml.safe_load,
) -> LidarModel:
    """The :class:`LidarModel` of a calibration file: its elevations sorted ascending (ring = index);
    ``text`` and ``load_yaml`` as :func:`read_calibration_table`'s."""
    t = read_calibration_table(path, text, load_yaml)
    a = np.sort(t.elevations_deg)
    if np.any(np.diff(a) <= 0):
        a = a + 1e-6 * np.arange(a.size)  # two lasers at one elevation (rare): keep both
    res = 360.0 / t.columns if t.columns else float(default_resolution_deg)
    try:
        return LidarModel(
            name, a, res, range_sigma_m, beam_divergence_rad, source=f"{Path(path).name} ({t.kind})"
        )
    except ValueError as e:
        raise _fail(Path(path), f"unusable beam table ({e})") from None
