"""The one reader of ``config.yaml``: our schema (interface.md) and ILCC's.

``load_config(path)`` returns a :class:`Config` of ready objects (``Board``, ``LidarModel``,
``CameraModel``, optional ``Roi``). Every key is checked; a wrong file raises ``InputError`` whose
message names the file, the key path (``board.squares``), the value found and what was expected.

Our schema (see interface.md)::

    board:  squares [rows, cols] (rows <= cols), square_size m, margin m or [long, short],
            lower_left black|white, roi (optional: azimuth_deg, elevation_deg, range_m as [min, max])
    lidar:  model (optional: a name of ``lidars.MODEL_NAMES`` or generic; without it the scans'
            own beam table is used), vertical_angles_deg, horizontal_resolution_deg (generic:
            required; others: optional overrides), range_sigma_m (optional), calibration_file
            (optional: the unit's Ouster metadata JSON, Velodyne db.xml / YAML or Hesai CSV, path
            relative to the config file's folder), intensity_column (optional, CSV without header)
    camera: model (one of ``cameras.camera_kinds()``), width, height and the model's own keys
            (``cameras/<model>.py``, docs/config.md)

ILCC's schema (mfxox/ILCC ``config.yaml``; its tuples are often strings such as ``'(6,8)'``):

- ``pattern_size`` (rows, cols) squares, short side first -> ``board.squares``
- ``grid_length`` square size in metres -> ``board.square_size`` (margin 0: ILCC has none)
- ``start_pattern_corner`` 0 black / 1 white -> ``board.lower_left``
- ``LiDAR_type`` ``hdl32`` | ``hdl64`` | ``vlp16_puck`` -> ``lidar.model`` (when absent, from
  ``laser_beams_num`` 16/32/64)
- ``intensity_col_ind`` -> ``lidar.intensity_column`` (used only for CSV files without header)
- ``camera_type`` ``panoramic`` (default) -> equirectangular of ``image_res`` = (height, width);
  ``perspective`` -> pinhole with ``instrinsic_para`` (9 numbers, row-major K) and no
  distortion; its size is read from the first image in ``<config dir>/img`` or else ``image_res``.
- ILCC's processing keys (``backend``, ``multi_proc``, ``jdc_thre_ratio``, ...) are accepted and ignored;
  so is ``marker_range_limit`` (ILCC tests it on segment centroids; as a point ROI it would clip boards).

Roi: azimuth = ``atan2(y, x)`` in degrees, elevation = ``atan2(z, hypot(x, y))`` in degrees,
range = ``|p|`` in metres, all in the LiDAR frame. ``azimuth_deg`` with min > max is an interval
that wraps through +-180 deg (e.g. ``[170, -170]`` is the 20 deg sector behind the sensor).
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .board import Board
from .cameras import CameraModel, camera_from_config
from .checks import MISSING, Checker
from .errors import InputError
from .lidars import ILCC_ALIASES, MODEL_NAMES, LidarModel, lidar_model, read_calibration_file

__all__ = ["Roi", "Config", "load_config", "parse_config", "config_to_dict"]


@dataclass(frozen=True)
class Roi:
    """Limits that narrow the board search in the cloud (LiDAR frame); None = no limit.

    azimuth_deg: (lo, hi) of atan2(y, x) in degrees, lo > hi wraps through +-180.
    elevation_deg: (lo, hi) of atan2(z, hypot(x, y)) in degrees.
    range_m: (lo, hi) of the point's distance from the origin, metres.
    """

    azimuth_deg: tuple[float, float] | None = None
    elevation_deg: tuple[float, float] | None = None
    range_m: tuple[float, float] | None = None

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) LiDAR-frame points -> (N,) bool, True inside every limit given (bounds inclusive)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        keep = np.ones(p.shape[0], dtype=bool)
        if self.azimuth_deg is not None:
            lo, hi = self.azimuth_deg
            az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
            keep &= ((az >= lo) & (az <= hi)) if lo <= hi else ((az >= lo) | (az <= hi))
        if self.elevation_deg is not None:
            lo, hi = self.elevation_deg
            el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
            keep &= (el >= lo) & (el <= hi)
        if self.range_m is not None:
            lo, hi = self.range_m
            r = np.linalg.norm(p, axis=1)
            keep &= (r >= lo) & (r <= hi)
        return keep

    def is_empty(self) -> bool:
        return self.azimuth_deg is None and self.elevation_deg is None and self.range_m is None

    def to_dict(self) -> dict:
        return {
            k: [float(v[0]), float(v[1])]
            for k, v in (
                ("azimuth_deg", self.azimuth_deg),
                ("elevation_deg", self.elevation_deg),
                ("range_m", self.range_m),
            )
            if v is not None
        }


@dataclass(frozen=True)
class Config:
    """A resolved configuration.

    board, lidar, camera: ready model objects (lidar None: no model named, the scans' own beam
    table is used, see observe.resolve_lidar). roi: board-search limits or None.
    intensity_column: CSV column of intensity for files without header (None: not given).
    source: the file it came from (for messages). schema: ``"ilcc_graph"`` or ``"ILCC"``.
    """

    board: Board
    lidar: LidarModel | None
    camera: CameraModel
    roi: Roi | None = None
    intensity_column: int | None = None
    source: str = ""
    schema: str = "ilcc_graph"


# --------------------------------------------------------------------------- our schema
_TOP_KEYS = ("board", "lidar", "camera")
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


def _parse_board(c: Checker, d: dict) -> tuple[Board, Roi | None]:
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
    roi = None
    if d.get("roi") is not None:
        r = c.section(d["roi"], "board.roi")
        c.unknown(r, _ROI_KEYS, "board.roi")
        roi = Roi(
            azimuth_deg=None
            if r.get("azimuth_deg") is None
            else c.interval(r["azimuth_deg"], "board.roi.azimuth_deg", -180.0, 180.0, wrap=True),
            elevation_deg=None
            if r.get("elevation_deg") is None
            else c.interval(r["elevation_deg"], "board.roi.elevation_deg", -90.0, 90.0),
            range_m=None
            if r.get("range_m") is None
            else c.interval(r["range_m"], "board.roi.range_m", 0.0, 1000.0),
        )
        if roi.is_empty():
            roi = None
    return Board(rows, cols, s, m_long, m_short, lower_left), roi


def _parse_lidar(c: Checker, d: dict, base: Path | None = None) -> tuple[LidarModel | None, int | None]:
    c.unknown(d, _LIDAR_KEYS, "lidar")
    raw_name = d.get("model")
    name = None if raw_name is None else c.choice(raw_name, "lidar.model", MODEL_NAMES)
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
        col = _intensity_column(c, col, "lidar.intensity_column")
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
        ref = model
        ref_res = 0.2 if ref is None else ref.horizontal_resolution_deg
        model = read_calibration_file(
            path,
            name="measured" if ref is None else ref.name,
            default_resolution_deg=res if res is not None else ref_res,
            range_sigma_m=sigma if sigma is not None else (0.03 if ref is None else ref.range_sigma_m),
            beam_divergence_rad=3e-3 if ref is None else ref.beam_divergence_rad,
        )
    return model, col


def _intensity_column(c: Checker, v: Any, key: str) -> int:
    col = c.number(v, key, lo=0, hi=1000, integer=True)
    if col < 3:
        raise c.fail(key, v, "a column index >= 3 (columns 0, 1, 2 hold x, y, z)")
    return int(col)


def _parse_ours(c: Checker, d: dict, source: str, base: Path | None = None) -> Config:
    c.unknown(d, _TOP_KEYS, "")
    board, roi = _parse_board(c, c.section(d.get("board", MISSING), "board"))
    section = d.get("lidar")
    lidar, col = _parse_lidar(c, {} if section is None else c.section(section, "lidar"), base)
    camera = camera_from_config(d.get("camera", MISSING), source)
    return Config(board, lidar, camera, roi, col, source, "ilcc_graph")


# --------------------------------------------------------------------------- ILCC's schema
_ILCC_USED = (
    "pattern_size",
    "grid_length",
    "LiDAR_type",
    "camera_type",
    "instrinsic_para",
    "image_res",
    "start_pattern_corner",
    "intensity_col_ind",
    "laser_beams_num",
)
_ILCC_IGNORED = (
    "base_dir",
    "image_format",
    "backend",
    "output_img_with_dectected_corners",
    "back_proj_corners",
    "file_name_digits",
    "jdc_thre_ratio",
    "agglomerative_cluster_th_ratio",
    "chessboard_detect_planar_PCA_ratio",
    "multi_proc",
    "proc_num",
    "poses_num",
    "not_segmented",
    "marker_range_limit",
)
_ILCC_BEAMS = {16: "vlp16", 32: "hdl32", 64: "hdl64"}


def _ilcc_tuple(c: Checker, v: Any, key: str) -> Any:
    """ILCC writes tuples as YAML strings ``'(6,8)'``; turn them into lists of literals."""
    if isinstance(v, str):
        try:
            v = ast.literal_eval(v.strip())
        except (ValueError, SyntaxError):
            raise c.fail(key, v, "a tuple of numbers such as (6,8)") from None
    if isinstance(v, tuple):
        v = list(v)
    return v


def _image_size_from_dir(img_dir: Path) -> tuple[int, int] | None:
    """(width, height) of the first image in ``img_dir`` (natural order), or None."""
    if not img_dir.is_dir():
        return None
    files = sorted(p for p in img_dir.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg", ".bmp"))
    for p in files:
        import cv2

        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is not None:
            return int(img.shape[1]), int(img.shape[0])
    return None


def _parse_ilcc(c: Checker, d: dict, source: str, base: Path | None) -> Config:
    c.unknown(d, _ILCC_USED + _ILCC_IGNORED, "")
    if "pattern_size" not in d:
        raise c.fail("pattern_size", MISSING, "(rows, cols): squares along the short and long side")
    if "grid_length" not in d:
        raise c.fail("grid_length", MISSING, "the square size in metres")
    board_d: dict[str, Any] = {
        "squares": _ilcc_tuple(c, d["pattern_size"], "pattern_size"),
        "square_size": d["grid_length"],
        "margin": 0.0,
    }
    spc = d.get("start_pattern_corner", 0)
    if isinstance(spc, bool) or spc not in (0, 1):
        raise c.fail("start_pattern_corner", spc, "0 (black) or 1 (white)")
    board_d["lower_left"] = "black" if spc == 0 else "white"
    try:
        board, roi = _parse_board(c, board_d)
    except InputError as e:  # rename our keys back to ILCC's in the message
        msg = str(e).replace("board.squares", "pattern_size").replace("board.square_size", "grid_length")
        raise InputError(msg) from None

    if d.get("LiDAR_type") is not None:
        lt = d["LiDAR_type"]
        if not isinstance(lt, str) or lt.lower() not in ILCC_ALIASES:
            raise c.fail("LiDAR_type", lt, f"one of {sorted(ILCC_ALIASES)}")
        name = ILCC_ALIASES[lt.lower()]
    elif d.get("laser_beams_num") is not None:
        n = c.number(d["laser_beams_num"], "laser_beams_num", integer=True)
        if n not in _ILCC_BEAMS:
            raise c.fail("laser_beams_num", n, f"one of {sorted(_ILCC_BEAMS)} when LiDAR_type is absent")
        name = _ILCC_BEAMS[int(n)]
    else:
        raise c.fail("LiDAR_type", MISSING, f"one of {sorted(ILCC_ALIASES)}")
    col = None
    if d.get("intensity_col_ind") is not None:
        col = _intensity_column(c, d["intensity_col_ind"], "intensity_col_ind")

    ctype = d.get("camera_type", "panoramic")
    if ctype not in ("panoramic", "perspective"):
        raise c.fail("camera_type", ctype, "'panoramic' or 'perspective'")
    res = None
    if d.get("image_res") is not None:
        r = _ilcc_tuple(c, d["image_res"], "image_res")
        hw = c.numbers(r, "image_res", 2, lo=1, hi=100000, integer=True)
        res = (int(hw[1]), int(hw[0]))  # ILCC writes (height, width)
    if ctype == "panoramic":
        if res is None:
            raise c.fail("image_res", MISSING, "(height, width) of the panoramic images")
        if res[0] != 2 * res[1]:
            raise c.fail(
                "image_res", d["image_res"], "(height, width) with width = 2 * height (equirectangular)"
            )
        cam_d: dict[str, Any] = {"model": "equirectangular", "width": res[0], "height": res[1]}
    else:
        if d.get("instrinsic_para") is None:
            raise c.fail("instrinsic_para", MISSING, "9 numbers of K, row-major, for a perspective camera")
        k = c.numbers(_ilcc_tuple(c, d["instrinsic_para"], "instrinsic_para"), "instrinsic_para", 9)
        size = _image_size_from_dir(base / "img") if base is not None else None
        size = size or res
        if size is None:
            raise c.fail("image_res", MISSING, "(height, width) of the images (no image found in img/)")
        cam_d = {"model": "pinhole", "width": size[0], "height": size[1], "K": k, "dist": [0.0] * 5}
    try:
        camera = camera_from_config(cam_d, source)
    except InputError as e:
        msg = str(e).replace("camera.K", "instrinsic_para").replace("camera.width", "image_res")
        raise InputError(msg) from None
    return Config(board, lidar_model(name), camera, roi, col, source, "ILCC")


# --------------------------------------------------------------------------- public API
def _is_ilcc(d: dict) -> bool:
    return any(k in d for k in _ILCC_USED + _ILCC_IGNORED)


def parse_config(d: Any, source: str = "<config>", base_dir: Path | str | None = None) -> Config:
    """Validate a loaded YAML mapping (ours or ILCC's schema) into a :class:`Config`.

    source names the file in messages; base_dir is the data folder (ILCC perspective cameras
    read their image size from ``base_dir/img``).
    """
    c = Checker(source)
    if not isinstance(d, dict):
        raise InputError(
            f"{source}: expected a mapping with sections board, lidar, camera; got {type(d).__name__}"
        )
    if _is_ilcc(d):
        ours = [k for k in d if k in _TOP_KEYS]
        if ours:
            raise c.fail(
                ours[0], d[ours[0]], "either our schema (board, lidar, camera) or ILCC's keys, not both"
            )
        return _parse_ilcc(c, d, source, Path(base_dir) if base_dir is not None else None)
    return _parse_ours(c, d, source, Path(base_dir) if base_dir is not None else None)


def load_config(path: str | Path) -> Config:
    """Read and validate ``config.yaml`` (ours or ILCC's). Raises ``InputError`` naming file and key."""
    import yaml

    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{p}: config file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: cannot read config file ({e})") from None
    try:
        d = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise InputError(f"{p}: not valid YAML ({' '.join(str(e).split())})") from None
    if d is None:
        raise InputError(f"{p}: config file is empty; expected sections board, lidar, camera")
    return parse_config(d, str(p), p.parent)


def config_to_dict(cfg: Config) -> dict:
    """The resolved configuration in our schema (plain Python types), e.g. to write beside results."""
    b = cfg.board
    margin: float | list[float] = (
        float(b.margin_long)
        if b.margin_long == b.margin_short
        else [float(b.margin_long), float(b.margin_short)]
    )
    board: dict[str, Any] = {
        "squares": [int(b.rows), int(b.cols)],
        "square_size": float(b.square_size),
        "margin": margin,
        "lower_left": str(b.lower_left),
    }
    if cfg.roi is not None and not cfg.roi.is_empty():
        board["roi"] = cfg.roi.to_dict()
    lidar = {} if cfg.lidar is None else cfg.lidar.to_dict()
    if cfg.intensity_column is not None:
        lidar["intensity_column"] = int(cfg.intensity_column)
    camera = _plain(cfg.camera.to_dict())
    return {"board": board, "lidar": lidar, "camera": camera}


def _plain(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating):
        return float(x)
    return x
