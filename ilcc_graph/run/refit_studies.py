"""The studies that solve again, as a step of the run: each parameter against the number of frames
and a 5-fold cross-validation of one session (``evaluation.studies`` computes them from a solver; the
solver here is the run's own, ``pipeline.solve_observed``, in batch mode). Every subset they ask for
is solved first, on the run's processes (``StageOptions.jobs``; they are independent solves, about a
second each on the standard set). The report draws what this returns; it never solves.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence

import numpy as np

from ilcc_graph import workers
from ilcc_graph.config import Config
from ilcc_graph.evaluation.studies import (
    CrossValidation,
    FramesCurve,
    Refused,
    cross_validate,
    frames_vs_accuracy,
    study_subsets,
    try_solve,
)
from ilcc_graph.run.pipeline import solve_observed
from ilcc_graph.run.result import Result, RunOptions, SessionResult
from ilcc_graph.types import FrameResult

__all__ = ["refit_studies"]

FOLDS = 5


def _solved(
    subset: Sequence[FrameResult], config: Config, options: RunOptions
) -> tuple[np.ndarray, np.ndarray] | str:
    """One subset solved by the batch strategy: (T_cam_lidar, covariance), or why not (a worker's
    item); the package's warnings kept quiet meanwhile (subsets of few frames warn by design)."""

    def solve(frames: Sequence[FrameResult]) -> tuple[np.ndarray, np.ndarray]:
        c = solve_observed(frames, config, options)
        return c.T_cam_lidar, c.covariance

    logger = logging.getLogger("ilcc_graph")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        return try_solve(solve, subset)
    finally:
        logger.setLevel(level)


def refit_studies(
    session: SessionResult, result: Result, truth: np.ndarray | None = None
) -> tuple[FramesCurve, CrossValidation] | None:
    """(frames against accuracy, cross-validation) of ``session``'s observed frames, every subset
    solved again by the batch strategy with the run's options, on ``StageOptions.jobs`` processes;
    None when the run gives no covariance (nothing to compare with). ``truth``: T_cam_lidar (4, 4)
    of a simulated set, for the curve's errors."""
    if result.covariance is None:
        return None
    config, cal = session.observation.pair_config, session.calibration
    options = dataclasses.replace(result.options, mode="graph")
    frames = session.observation.frames
    subsets = study_subsets(frames, FOLDS)
    items = [(s, config, options) for s in subsets]
    answers = workers.map_processes(_solved, items, options.stages.jobs)
    found = {tuple(f.name for f in s): a for s, a in zip(subsets, answers, strict=True)}

    def solve(subset: Sequence[FrameResult]) -> tuple[np.ndarray, np.ndarray]:
        answer = found.get(tuple(f.name for f in subset))
        if answer is None:  # a subset not foreseen: solved here
            answer = _solved(subset, config, options)
        if isinstance(answer, str):
            raise Refused(answer)
        return answer

    curve = frames_vs_accuracy(frames, solve, config.camera, config.board, truth)
    cv = cross_validate(frames, solve, config.camera, config.board, folds=FOLDS, T_all=cal.T_cam_lidar)
    return curve, cv
