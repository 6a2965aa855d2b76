"""The studies that solve again, as a step of the run: each parameter against the number of frames
and a 5-fold cross-validation of one session (``evaluation.studies`` computes them from a solver; the
solver here is the run's own, ``pipeline.solve_observed``, in batch mode). The report draws what this
returns; it never solves.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence

import numpy as np

from ilcc_graph.evaluation.studies import CrossValidation, FramesCurve, cross_validate, frames_vs_accuracy
from ilcc_graph.run.pipeline import solve_observed
from ilcc_graph.run.result import Result, SessionResult
from ilcc_graph.types import FrameResult

__all__ = ["refit_studies"]


def refit_studies(
    session: SessionResult, result: Result, truth: np.ndarray | None = None
) -> tuple[FramesCurve, CrossValidation] | None:
    """(frames against accuracy, cross-validation) of ``session``'s observed frames, every subset
    solved again by the batch strategy with the run's options (their warnings kept quiet: subsets of
    few frames warn by design); None when the run gives no covariance (nothing to compare with).
    ``truth``: T_cam_lidar (4, 4) of a simulated set, for the curve's errors."""
    if result.covariance is None:
        return None
    config, cal = session.observation.pair_config, session.calibration
    options = dataclasses.replace(result.options, mode="graph")
    frames = session.observation.frames

    def solve(subset: Sequence[FrameResult]) -> tuple[np.ndarray, np.ndarray]:
        c = solve_observed(subset, config, options)
        return c.T_cam_lidar, c.covariance

    quiet = logging.getLogger("ilcc_graph")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        curve = frames_vs_accuracy(frames, solve, config.camera, config.board, truth)
        cv = cross_validate(frames, solve, config.camera, config.board, folds=5, T_all=cal.T_cam_lidar)
    finally:
        quiet.setLevel(level)
    return curve, cv
