"""Is the result right? The paper's re-projection metric, studies, overlays, coloured clouds, report.

- :mod:`.metric`: the paper's intensity-based re-projection error (Eq. 14) per point and frame;
  :mod:`.frame_errors`: ``evaluate(frames, camera, board, T_cam_lidar) -> Evaluation`` (per frame and
  overall, with corner errors in px and mrad).
- :mod:`.studies`: ``cross_validate`` and ``frames_vs_accuracy`` (take the observations and a
  solver callable ``solve(frames) -> (T, cov)``).
- :mod:`.overlays`: corners, LiDAR points on images with occlusion, coloured points.
- :mod:`.plots`: charts as PNG bytes.
- :mod:`.figures`: a frame's pictures (on the image stage's kept views, compressed);
  :mod:`.sections`: the page's parts; :mod:`.html`: ``build_report(...) -> {relative path: bytes}``
  (``index.html``, ``figures/``); :mod:`.next_pose_picture`: the rig and the next board pose,
  above and aside.
- A rig (several sensors): :mod:`.rig_verdict` (``rig_verdict``, ``rig_verdict_lines``), :mod:`.rig_report`
  (``rig_report_files``: its page's files), :mod:`.rig_pictures` (LiDAR boards on the images,
  ``board_share``).

Pure: nothing here reads or writes files; the command line writes what these return.
"""

from __future__ import annotations

from .figures import FigureOptions, FrameFigures, frame_figures
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
from .html import build_report
from .metric import EPSILON_G, EvalFrame, Evaluation, FrameEvaluation, metric_points
from .overlays import (
    OCCLUDED_RGB,
    OUTSIDE_RGB,
    ColouredPoints,
    Visibility,
    colour_points,
    crop_box,
    draw_corners,
    visible_points,
)
from .studies import CrossValidation, FramesCurve, cross_validate, frames_vs_accuracy, pose_difference

__all__ = [
    "EPSILON_G",
    "OCCLUDED_RGB",
    "OUTSIDE_RGB",
    "ColouredPoints",
    "CrossValidation",
    "EvalFrame",
    "Evaluation",
    "FigureOptions",
    "FrameEvaluation",
    "FrameFigures",
    "FramesCurve",
    "Visibility",
    "board_points_from_scan",
    "build_report",
    "colour_points",
    "crop_box",
    "cross_validate",
    "draw_corners",
    "eval_frame",
    "eval_frame_with_scan",
    "eval_frames",
    "evaluate",
    "evaluate_calibration",
    "evaluation_rows",
    "evaluation_to_dict",
    "frame_figures",
    "frames_vs_accuracy",
    "metric_points",
    "pose_difference",
    "visible_points",
]
