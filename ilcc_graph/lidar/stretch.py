"""How far a correction of a LiDAR's ranges stretches the boards it fitted, and whether that matters.

The LiDAR stage fits each board on the measured returns; a graph that estimates the LiDAR's own
range errors (a global offset, per-beam offsets, a scale) gives a ``types.RangeCorrection``. A large
offset (a unit reading 20 mm long) changes the intensity fit itself: the pattern seen on a plane 20
mm too far is 1 % too large at 2 m, and the in-plane poses then move in common, beyond what their
covariance states (docs/bench_sensor_model.md, finding 3). ``correction_of(sensors)`` reads the
correction from a calibration's ``sensors`` (``lidar_errors``); ``stretch_ratio`` is the stretch of
one board in its in-plane sigmas; ``significant`` says whether some used board is stretched by more
than ``REFIT_RATIO``, when the run fits the boards again (``run.range_refit``).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.types import FrameResult, RangeCorrection

__all__ = ["REFIT_RATIO", "correction_of", "largest_stretch", "significant", "stretch_ratio"]

#: the boards are fitted again when the correction stretches some board's pattern by more than this
#: many of its in-plane sigmas. The first-order coupling handles smaller ones: the bias it leaves
#: grows with the stretch, 0.4 extrinsic sigma in tz at a 20 mm offset on the simulated HDL-32E
#: sets (a stretch of 14-19 in-plane sigmas), so about 0.1 sigma here; per-beam offsets of a few mm
#: without a common offset stretch the boards by 0.2-1 (docs/bench_sensor_model.md)
REFIT_RATIO = 3.0

_BEAM = re.compile(r"offset\[(\d+)\]")


def correction_of(sensors: Mapping[str, Any]) -> RangeCorrection | None:
    """The range correction in a calibration's ``sensors`` (its ``lidar_errors``: ``offset``,
    ``offset[b]``, ``scale``; metres), or None when the graph estimated none."""
    le = sensors.get("lidar_errors")
    if not le:
        return None
    offset, scale, beams = 0.0, 0.0, []
    for name, value in zip(le["names"], le["values"], strict=True):
        if name == "offset":
            offset = float(value)
        elif name == "scale":
            scale = float(value)
        elif m := _BEAM.fullmatch(name):
            beams.append((int(m.group(1)), float(value)))
    if offset == 0.0 and scale == 0.0 and not beams:
        return None
    return RangeCorrection(offset, tuple(beams), scale)


def stretch_ratio(fit_returns: Any, correction: RangeCorrection, board: Board) -> float:
    """How far the correction stretches a board's pattern (its mean over the board's returns over
    their range, times the board's half diagonal) in units of the board's in-plane position sigma."""
    P = np.asarray(fit_returns.points, dtype=np.float64)
    if len(P) == 0:
        return 0.0
    rho = np.linalg.norm(P, axis=1)
    c = float(np.mean(correction.along_ray(fit_returns.ring, rho)))
    x0, x1, y0, y1 = board.extent()
    stretch = abs(c) / float(np.mean(rho)) * 0.5 * float(np.hypot(x1 - x0, y1 - y0))
    sigma = float(np.sqrt(max(np.linalg.eigvalsh(np.asarray(fit_returns.inplane_cov)[1:, 1:]).max(), 1e-18)))
    return stretch / sigma


def largest_stretch(frames: Sequence[FrameResult], correction: RangeCorrection | None, board: Board) -> float:
    """The largest ``stretch_ratio`` of ``correction`` over the used boards with returns (0: none)."""
    if correction is None:
        return 0.0
    ratios = [
        stretch_ratio(f.board.returns, correction, board)
        for f in frames
        if f.used and f.board is not None and f.board.returns is not None
    ]
    return max(ratios, default=0.0)


def significant(frames: Sequence[FrameResult], correction: RangeCorrection | None, board: Board) -> bool:
    """Whether ``correction`` stretches some used board's pattern by more than ``REFIT_RATIO`` of
    its in-plane sigmas."""
    return largest_stretch(frames, correction, board) > REFIT_RATIO
