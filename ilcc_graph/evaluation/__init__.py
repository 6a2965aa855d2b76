"""Is the result right? The paper's intensity-based re-projection metric and the studies on subsets
of frames: computations on typed results, no drawing and no files (``report`` draws them, the run's
``run.refit_studies`` hands the studies their solver).

- :mod:`.metric`: the paper's intensity-based re-projection error (Eq. 14) per point and frame;
- :mod:`.frame_errors`: ``evaluate(frames, camera, board, T_cam_lidar) -> Evaluation`` (per frame and
  overall, with corner errors in px and mrad), from the run's results or a calibration file's scans;
- :mod:`.pattern_check`: does the checker pattern go on beyond the corners found (a set-up mistake's
  evidence, run by the image stage's worker);
- :mod:`.studies`: ``cross_validate``, ``frames_vs_accuracy`` (a solver callable
  ``solve(frames) -> (T, cov)`` handed in) and the ``valley`` study (no solve).
"""

from __future__ import annotations

from .frame_errors import (
    board_points_from_scan,
    eval_frame,
    eval_frame_with_scan,
    eval_frames,
    evaluate,
    evaluate_calibration,
    evaluation_rows,
    evaluation_to_dict,
)
from .metric import EPSILON_G, EvalFrame, Evaluation, FrameEvaluation, metric_points
from .studies import CrossValidation, FramesCurve, cross_validate, frames_vs_accuracy, pose_difference

__all__ = [
    "EPSILON_G",
    "CrossValidation",
    "EvalFrame",
    "Evaluation",
    "FrameEvaluation",
    "FramesCurve",
    "board_points_from_scan",
    "cross_validate",
    "eval_frame",
    "eval_frame_with_scan",
    "eval_frames",
    "evaluate",
    "evaluate_calibration",
    "evaluation_rows",
    "evaluation_to_dict",
    "frames_vs_accuracy",
    "metric_points",
    "pose_difference",
]
