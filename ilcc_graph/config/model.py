"""A resolved configuration: :class:`Config` (ready model objects) and :class:`Roi`; back to our schema
with ``config_to_dict``.

Roi: azimuth = ``atan2(y, x)`` in degrees, elevation = ``atan2(z, hypot(x, y))`` in degrees,
range = ``|p|`` in metres, all in the LiDAR frame. ``azimuth_deg`` with min > max is an interval
that wraps through +-180 deg (e.g. ``[170, -170]`` is the 20 deg sector behind the sensor).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..board import Board
from ..cameras import CameraModel
from ..lidars import LidarModel
from ..types import to_plain

__all__ = ["Config", "Roi", "config_to_dict"]


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
    table is used, see run.source.resolve_lidar). roi: board-search limits or None.
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
    camera = to_plain(cfg.camera.to_dict())
    return {"board": board, "lidar": lidar, "camera": camera}
