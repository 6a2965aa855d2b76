"""Our schema of ``config.yaml`` (interface.md).

Our schema (see interface.md)::

    board:  squares [rows, cols] (rows <= cols), square_size m, margin m or [long, short],
            lower_left black|white, roi (optional: azimuth_deg, elevation_deg, range_m as [min, max])
    lidar:  model (optional: a name of ``lidars.MODEL_NAMES`` or generic; without it the scans'
            own beam table is used), vertical_angles_deg, horizontal_resolution_deg (generic:
            required; others: optional overrides), range_sigma_m (optional), calibration_file
            (optional: the unit's Ouster metadata JSON, Velodyne db.xml / YAML or Hesai CSV, path
            relative to the config file's folder), intensity_column (optional, CSV without header)
    camera: model (one of ``cameras.camera_kinds()``), width, height and the model's own keys
            (``cameras/<model>.py``, docs/config.md); or ``file``: the camera calibration tool's
            own file (ROS ost.yaml, Kalibr camchain, OpenCV FileStorage; ``camera_file.py``)
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from ..board import Board
from ..cameras import camera_from_config
from ..checks import MISSING, Checker
from ..errors import InputError
from ..io.files import load_yaml_text, not_a_file, read_bounded
from ..lidars import MODEL_NAMES, LidarModel, lidar_model, model_name, read_calibration_file
from .camera_file import camera_section
from .model import Config, Roi

log = logging.getLogger(__name__)

__all__ = ["TOP_KEYS", "intensity_column", "parse_board", "parse_lidar", "parse_ours", "parse_roi"]

TOP_KEYS = ("board", "lidar", "camera")
#: the largest LiDAR calibration file read (Velodyne db.xml ~50 kB, Ouster metadata ~100 kB)
LIDAR_FILE_MAX_BYTES = 8 << 20
_BOARD_KEYS = ("squares", "square_size", "margin", "lower_left", "roi")
_ROI_KEYS = ("azimuth_deg", "elevation_deg", "range_m")
_LIDAR_KEYS = (
    "model",
    "vertical_angles_deg",
    "horizontal_resolution_deg",
    "range_sigma_m",
    "calibration_file",
    "intensity_column",
)


def parse_board(c: Checker, d: dict) -> tuple[Board, Roi | None]:
    c.unknown(d, _BOARD_KEYS, "board")
    sq = d.get("squares", MISSING)
    if not isinstance(sq, (list, tuple)) or len(sq) != 2:
        raise c.fail("board.squares", sq, "[rows, cols]: squares along the short and the long side")
    rows, cols = (c.number(x, f"board.squares[{i}]", lo=2, hi=100, integer=True) for i, x in enumerate(sq))
    if rows > cols:
        raise c.fail("board.squares", sq, "[rows, cols] with rows <= cols (the short side first)")
    s = c.number(d.get("square_size", MISSING), "board.square_size", lo=0.0, hi=1.0, lo_open=True)
    m = d.get("margin", 0.0)
    if isinstance(m, (list, tuple)):
        m_long, m_short = c.numbers(m, "board.margin", 2, lo=0.0, hi=2.0)
    else:
        m_long = m_short = c.number(m, "board.margin", lo=0.0, hi=2.0)
    lower_left = c.choice(d.get("lower_left", "black"), "board.lower_left", ("black", "white"))
    roi = None if d.get("roi") is None else parse_roi(c, d["roi"], "board.roi")
    return Board(rows, cols, s, m_long, m_short, lower_left), roi


def parse_roi(c: Checker, v: Any, key: str) -> Roi | None:
    """A ``roi`` section (azimuth_deg, elevation_deg, range_m as [min, max]) at ``key``; None when empty."""
    r = c.section(v, key)
    c.unknown(r, _ROI_KEYS, key)
    roi = Roi(
        azimuth_deg=None
        if r.get("azimuth_deg") is None
        else c.interval(r["azimuth_deg"], f"{key}.azimuth_deg", -180.0, 180.0, wrap=True),
        elevation_deg=None
        if r.get("elevation_deg") is None
        else c.interval(r["elevation_deg"], f"{key}.elevation_deg", -90.0, 90.0),
        range_m=None if r.get("range_m") is None else c.interval(r["range_m"], f"{key}.range_m", 0.0, 1000.0),
    )
    return None if roi.is_empty() else roi


def _model_name(c: Checker, written: Any) -> str:
    """Our table's name for ``lidar.model`` as the user wrote it (``lidars.model_name``: ``VLP-16``,
    ``Velodyne HDL-32E``, ``OS1-128``); one warning when it picks one revision of several."""
    name, others = model_name(written) if isinstance(written, str) else (None, ())
    if name is None:
        why = "case, spaces, '-', '_' and the vendor's name do not matter"
        raise c.fail("lidar.model", written, f"one of {list(MODEL_NAMES)} ({why})")
    if others:
        log.warning(
            "%s: lidar.model %r read as %s (also %s); the scans' own beam table is measured and used where "
            "it differs", c.source, written, name, ", ".join(others),
        )  # fmt: skip
    return name


def parse_lidar(c: Checker, d: dict, base: Path | None = None) -> tuple[LidarModel | None, int | None]:
    c.unknown(d, _LIDAR_KEYS, "lidar")
    name = None if d.get("model") is None else _model_name(c, d["model"])
    angles = d.get("vertical_angles_deg")
    res = d.get("horizontal_resolution_deg")
    if name == "generic":
        if angles is None:
            raise c.fail(
                "lidar.vertical_angles_deg", MISSING, "a list of beam elevations in degrees (generic)"
            )
        if res is None:
            raise c.fail("lidar.horizontal_resolution_deg", MISSING, "a number in (0, 10] degrees (generic)")
    if angles is not None:
        if not isinstance(angles, (list, tuple)) or len(angles) < 1:
            raise c.fail(
                "lidar.vertical_angles_deg", angles, "a non-empty list of numbers in (-90, 90) degrees"
            )
        a = c.numbers(angles, "lidar.vertical_angles_deg", None, lo=-89.999, hi=89.999)
        if len(set(a)) != len(a):
            raise c.fail("lidar.vertical_angles_deg", angles, "distinct beam elevations")
        if name != "generic" and any(x >= y for x, y in zip(a, a[1:], strict=False)):
            raise c.fail("lidar.vertical_angles_deg", angles, "ascending beam elevations (index = ring)")
        angles = a
    if res is not None:
        res = c.number(res, "lidar.horizontal_resolution_deg", lo=0.0, hi=10.0, lo_open=True)
    sigma = d.get("range_sigma_m")
    if sigma is not None:
        sigma = c.number(sigma, "lidar.range_sigma_m", lo=0.0, hi=1.0, lo_open=True)
    col = d.get("intensity_column")
    if col is not None:
        col = intensity_column(c, col, "lidar.intensity_column")
    calib = d.get("calibration_file")
    if calib is not None and not isinstance(calib, str):
        raise c.fail("lidar.calibration_file", calib, "a file path (relative to the config file's folder)")
    if name is None and (angles is not None or res is not None) and calib is None:
        raise c.fail(
            "lidar.model",
            MISSING,
            "a model name (or generic) when vertical_angles_deg or horizontal_resolution_deg are given",
        )
    model = None if name is None else lidar_model(name, angles, res, sigma)
    if calib is not None:
        path = Path(calib) if base is None or Path(calib).is_absolute() else base / calib
        problem = not_a_file(path)
        if problem is not None:
            raise c.fail("lidar.calibration_file", calib, f"an existing file ({path} {problem})")
        ref = model
        ref_res = 0.2 if ref is None else ref.horizontal_resolution_deg
        model = read_calibration_file(
            path,
            text=_lidar_file_text(path),
            load_yaml=lambda text: load_yaml_text(text, str(path)),
            name="measured" if ref is None else ref.name,
            default_resolution_deg=res if res is not None else ref_res,
            range_sigma_m=sigma if sigma is not None else (0.03 if ref is None else ref.range_sigma_m),
            beam_divergence_rad=3e-3 if ref is None else ref.beam_divergence_rad,
        )
    return model, col


def _lidar_file_text(path: Path) -> str:
    """A LiDAR's calibration file read with a bound (``io.read_bounded``: a folder, a FIFO or a device
    named for what it is; an Ouster metadata JSON is some 100 kB)."""
    raw = read_bounded(path, "LiDAR calibration file", LIDAR_FILE_MAX_BYTES)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise InputError(f"{path}: cannot read the LiDAR calibration file ({e})") from None


def intensity_column(c: Checker, v: Any, key: str) -> int:
    col = c.number(v, key, lo=0, hi=1000, integer=True)
    if col < 3:
        raise c.fail(key, v, "a column index >= 3 (columns 0, 1, 2 hold x, y, z)")
    return int(col)


def parse_ours(c: Checker, d: dict, source: str, base: Path | None = None) -> Config:
    c.unknown(d, TOP_KEYS, "")
    board, roi = parse_board(c, c.section(d.get("board", MISSING), "board"))
    section = d.get("lidar")
    lidar, col = parse_lidar(c, {} if section is None else c.section(section, "lidar"), base)
    camera = camera_from_config(camera_section(c, d.get("camera", MISSING), base), source)
    return Config(board, lidar, camera, roi, col, source, "ilcc_graph")
