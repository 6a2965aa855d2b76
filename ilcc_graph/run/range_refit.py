"""The boards fitted again on ranges corrected by what the graph found the LiDAR reads too long.

The LiDAR stage fits each board on the measured returns; the graph then estimates the LiDAR's own
range errors (a global offset, per-beam offsets, a scale: ``estimation.lidar_errors``) and relates
each board's in-plane pose to the corrected plane through its first-order coupling ``K``. A large
offset also changes the intensity fit itself (``lidar.stretch``: the pattern stretched on a plane
read too far). So when the estimated correction stretches some board's pattern by more than
``REFIT_RATIO`` in-plane sigmas, every board is found and fitted again on its scan corrected by it
(near where it was found), and the data solved again. The fits keep the measured returns, so that
the graph estimates the same range errors. ``refit_pass(observation, calibration, stages)`` gives
the observation with its boards fitted again, or None.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping, Sequence

import numpy as np

from ilcc_graph import workers
from ilcc_graph.errors import FrameError
from ilcc_graph.lidar.stretch import REFIT_RATIO, correction_of, largest_stretch
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.stages import StageOptions, attempt, observe_lidar
from ilcc_graph.types import BoardFit, Calibration, ExpectedBoard, FrameResult

log = logging.getLogger(__name__)

__all__ = ["refit_frames", "refit_pass"]


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
            items.append((observe_lidar, source, refs[f.name], obs.config, stages, expected, correction))
    fits = dict(zip(names, workers.map_processes(attempt, items, stages.jobs, None), strict=True))
    lost = [n for n, r in fits.items() if isinstance(r, FrameError)]
    moved = [r.diagnostics.get("range_correction_mm", 0.0) for r in fits.values() if isinstance(r, BoardFit)]
    log.info(
        "the boards fitted again on their ranges corrected by the LiDAR's estimated errors "
        "(%.1f mm on average)%s", float(np.mean(moved)) if moved else 0.0,
        f"; the first fit kept for {', '.join(lost)} ({fits[lost[0]]})" if lost else "",
    )  # fmt: skip
    return dataclasses.replace(obs, frames=refit_frames(obs.frames, fits))
