"""Does the checker pattern go on beyond the corners found? (a part of a bigger print was detected)

Run by the image stage's worker on the image it has in memory (``run.stages.observe_image`` keeps the
answer in ``ImageCorners.diagnostics``), read by ``run.setup_mistakes`` for the ``board.squares``
diagnosis. Computation only: an image, the board and the camera in, a count of squares out.
"""

from __future__ import annotations

import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.cameras import CameraModel
from ilcc_graph.init import upnp
from ilcc_graph.types import ImageCorners

__all__ = ["KEYS", "extra_squares", "pattern_continues"]

#: the ImageCorners.diagnostics keys of the answer
KEYS = ("pattern_extra_rows", "pattern_extra_cols")


def pattern_continues(
    image: np.ndarray, board: Board, camera: CameraModel, corners: ImageCorners
) -> tuple[int, int]:
    """(extra rows, extra cols) of squares the image shows beyond the board's pattern (0, 0 when none).

    The pattern's pose comes from the image corners (UPnP); the grey level at the centre of each
    square of the ring just outside the pattern is classed against the pattern's own black and white
    squares. A side whose ring continues the checker colours (>= 85 % of its squares; a margin,
    the board's edge or the background match about half) counts as one more row or column.
    """
    b = corners.bearings / np.linalg.norm(corners.bearings, axis=1, keepdims=True)
    if not np.all(np.isfinite(b)):
        return 0, 0
    T = upnp(board.corners_board(), b, prefer_front=True)[0].T_cam_points
    h, w = image.shape[:2]
    s, R, C = board.square_size, board.rows, board.cols

    def sample(rc: np.ndarray) -> np.ndarray:
        xy = (rc[:, ::-1] + 0.5) * s  # square (r, c) centre: x along the columns, y along the rows
        p = np.c_[xy, np.zeros(len(xy))] @ T[:3, :3].T + T[:3, 3]
        uv = camera.project(p)
        out = np.full(len(rc), np.nan)
        ok = np.all(np.isfinite(uv), axis=1) & camera.in_image(uv)
        if ok.any():
            u, v = np.round(uv[ok]).astype(int).T
            px = image[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)].astype(np.float64)  # only these pixels
            out[ok] = px.mean(axis=1) if px.ndim == 2 else px
        return out

    inside = np.array([(r, c) for r in range(R) for c in range(C)])
    black = (inside.sum(axis=1) % 2 == 0) == (board.lower_left == "black")
    level = sample(inside)
    if not (np.isfinite(level).all() and np.nanmean(level[~black]) > np.nanmean(level[black]) + 20):
        return 0, 0  # the pattern itself is not seen clearly enough to judge
    split = 0.5 * (np.nanmean(level[~black]) + np.nanmean(level[black]))
    sides = {
        "top": np.array([(-1, c) for c in range(C)]),
        "bottom": np.array([(R, c) for c in range(C)]),
        "left": np.array([(r, -1) for r in range(R)]),
        "right": np.array([(r, C) for r in range(R)]),
    }
    going_on = {}
    for name, rc in sides.items():
        g = sample(rc)
        ok = np.isfinite(g)
        want_black = (rc.sum(axis=1) % 2 == 0) == (board.lower_left == "black")
        going_on[name] = ok.sum() >= 0.8 * len(rc) and np.mean((g[ok] < split) == want_black[ok]) >= 0.85
    return int(going_on["top"]) + int(going_on["bottom"]), int(going_on["left"]) + int(going_on["right"])


def extra_squares(corners: ImageCorners) -> tuple[int, int] | None:
    """The answer the image stage kept for these corners, or None (not looked at)."""
    d = corners.diagnostics
    return (int(d[KEYS[0]]), int(d[KEYS[1]])) if all(k in d for k in KEYS) else None
