"""A calibration judged on a data set's frames (the ``evaluate`` command): observe, then the metric.

The frames may be ones the calibration did not use (hold-out frames of another recording); the
paper's intensity re-projection error and the corner errors come from ``evaluation.metric``.
"""

from __future__ import annotations

import logging

import numpy as np

from ilcc_graph.cameras import RefinedIntrinsics
from ilcc_graph.config.rig_config import as_calibrated
from ilcc_graph.datasets import FrameSource
from ilcc_graph.evaluation import Evaluation, eval_frames, evaluate
from ilcc_graph.run.observe import Progress, observe
from ilcc_graph.run.stages import StageOptions

__all__ = ["evaluate_on"]

log = logging.getLogger(__name__)


def evaluate_on(
    source: FrameSource,
    T_cam_lidar: np.ndarray,
    stages: StageOptions = StageOptions(),
    progress: Progress | None = None,
    refined: RefinedIntrinsics | None = None,
) -> tuple[Evaluation, list[tuple[str, str]]]:
    """(the metric of ``T_cam_lidar`` (4, 4) on the source's frames, [(frame, why not evaluated)]);
    ``refined``: the camera's intrinsics the calibration refined, taken where the source states the
    ones it was made with (``config.rig_config.as_calibrated``; else said)."""
    obs = observe(source, stages, progress)
    skipped = [(r.name, r.reason or "no board") for r in obs.frames if r.board is None or r.corners is None]
    config = obs.pair_config
    camera, note = as_calibrated(config.camera, refined, "camera") if refined else (config.camera, None)
    if note:
        log.warning("%s", note)
    ev = evaluate(eval_frames(obs.frames), camera, config.board, np.asarray(T_cam_lidar))
    return ev, skipped
