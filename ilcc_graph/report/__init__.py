"""What the run shows: overlays, pictures, charts and the report's files (presentation only; what is
right or wrong is computed in ``evaluation``).

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
from .html import build_report
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

__all__ = [
    "OCCLUDED_RGB",
    "OUTSIDE_RGB",
    "build_report",
    "colour_points",
    "crop_box",
    "draw_corners",
    "frame_figures",
    "visible_points",
    "ColouredPoints",
    "FigureOptions",
    "FrameFigures",
    "Visibility",
]
