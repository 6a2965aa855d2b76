"""The boards fitted again on ranges corrected by what the graph found the LiDAR reads too long.

The LiDAR stage fits each board on the measured returns; the graph then estimates the LiDAR's own
range errors (a global offset, per-beam offsets, a scale: ``estimation.lidar_errors``) and relates
each board's in-plane pose to the corrected plane through its first-order coupling ``K``. A large
offset (a unit reading 20 mm long) also changes the intensity fit itself: the pattern seen on a
plane 20 mm too far is 1 % too large at 2 m, and the in-plane poses then move in common, beyond what
their covariance states (docs/bench_sensor_model.md, finding 3). So when the estimated correction
stretches some board's pattern by more than ``REFIT_RATIO`` in-plane sigmas, every board is
found and fitted again on its scan corrected by it (near where it was found), and the data solved
again. The fits keep the measured returns, so that the graph estimates the same range errors.

``correction_of(sensors)`` reads the correction from a calibration's ``sensors``;
``significant(frames, correction, board)`` says whether it matters; ``refit_pass(observation,
calibration, stages)`` gives the observation with its boards fitted again, or None.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ilcc_graph import workers
from ilcc_graph.board import Board
from ilcc_graph.config import Config
from ilcc_graph.datasets import FrameRef, FrameSource
from ilcc_graph.errors import FrameError
from ilcc_graph.lidar import LidarOptions
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.stages import StageOptions, attempt, observe_lidar
from ilcc_graph.types import BoardFit, Calibration, ExpectedBoard, FrameResult, RangeCorrection

log = logging.getLogger(__name__)

__all__ = [
    "REFIT_RATIO",
    "correction_of",
    "largest_stretch",
    "refit_frames",
    "refit_pass",
    "significant",
    "stretch_ratio",
]

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


def _refit_one(source: FrameSource, ref: FrameRef, config: Config, options: LidarOptions,
               expected: ExpectedBoard, correction: RangeCorrection) -> object:  # fmt: skip
    return attempt(observe_lidar, source, ref, config, options, expected, False, correction)


def refit_frames(frames: Sequence[FrameResult], fits: Mapping[str, object]) -> list[FrameResult]:
    """The frames with the boards ``fits[name]`` fitted again; a frame whose board the corrected
    scan does not give (a FrameError) keeps its first fit."""
    out = []
    for f in frames:
        res = fits.get(f.name)
        if res is None or isinstance(res, FrameError) or f.board is None:
            out.append(f)
        else:
            out.append(dataclasses.replace(f, board=res))  # type: ignore[arg-type]
    return out


def refit_pass(obs: Observation, cal: Calibration, stages: StageOptions) -> Observation | None:
    """The observation with every board fitted again on its scan corrected by ``cal``'s estimate of
    the LiDAR's range errors, or None when that correction is not ``significant``."""
    correction = correction_of(cal.sensors)
    ratio = largest_stretch(obs.frames, correction, obs.config.board)
    log.debug("the LiDAR's estimated range errors stretch a board by %.2f of its in-plane sigma", ratio)
    source = obs.pair_source  # None: frames observed without their source (pipeline.solve_observed)
    if correction is None or source is None or ratio <= REFIT_RATIO:
        return None
    refs = {r.name: r for r in source.frames()}
    names, items = [], []
    for f in obs.frames:
        if f.board is not None and f.name in refs:
            names.append(f.name)
            expected = ExpectedBoard(f.board.T_lidar_board)
            items.append((source, refs[f.name], obs.config, stages.lidar, expected, correction))
    fits = dict(zip(names, workers.map_processes(_refit_one, items, stages.jobs, None), strict=True))
    lost = [n for n, r in fits.items() if isinstance(r, FrameError)]
    moved = [r.diagnostics.get("range_correction_mm", 0.0) for r in fits.values() if isinstance(r, BoardFit)]
    log.info(
        "the boards fitted again on their ranges corrected by the LiDAR's estimated errors "
        "(%.1f mm on average)%s", float(np.mean(moved)) if moved else 0.0,
        f"; the first fit kept for {', '.join(lost)} ({fits[lost[0]]})" if lost else "",
    )  # fmt: skip
    return dataclasses.replace(obs, frames=refit_frames(obs.frames, fits))
