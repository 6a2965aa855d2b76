"""ILCC's schema of ``config.yaml`` (mfxox/ILCC), read into the same :class:`Config`.

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
"""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

from ..cameras import camera_from_config
from ..checks import MISSING, Checker
from ..errors import InputError
from ..lidars import ILCC_ALIASES, lidar_model
from .model import Config
from .ours import intensity_column, parse_board

__all__ = ["is_ilcc", "parse_ilcc"]

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
    """(width, height) of the first image in ``img_dir`` (sorted by name) whose header can be read
    (nothing decoded: ``io.image_size``), or None."""
    from ..io.images import image_size

    if not img_dir.is_dir():
        return None
    files = sorted(p for p in img_dir.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg", ".bmp"))
    for p in files:
        try:
            return image_size(p)
        except InputError:
            continue
    return None


def parse_ilcc(c: Checker, d: dict, source: str, base: Path | None) -> Config:
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
        board, roi = parse_board(c, board_d)
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
        col = intensity_column(c, d["intensity_col_ind"], "intensity_col_ind")

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


def is_ilcc(d: dict) -> bool:
    return any(k in d for k in _ILCC_USED + _ILCC_IGNORED)
