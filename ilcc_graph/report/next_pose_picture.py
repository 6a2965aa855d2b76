"""The rig from above and from the side, with the boards so far and the proposed next one (PNG bytes)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..board import Board
from ..cameras import CameraModel
from .plots import _figure, _png

if TYPE_CHECKING:  # next_pose is report's neighbour: a name for the hint only
    from ..next_pose import Proposal

__all__ = ["next_pose_png", "plot_next_pose"]


def _corners(board: Board, T: np.ndarray) -> np.ndarray:
    """(5, 3) the board's physical corners (closed polygon) in the LiDAR frame."""
    x0, x1, y0, y1 = board.extent()
    c = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0], [x0, y0, 0]], dtype=np.float64)
    return c @ T[:3, :3].T + T[:3, 3]


def _fov_rays(camera: CameraModel, T_cam_lidar: np.ndarray) -> np.ndarray | None:
    """(2, 3) LiDAR-frame directions of the image's left and right edge at its middle row, or None
    for a panorama (it sees all round)."""
    if camera.periodic_u:
        return None
    uv = np.array([[0.0, (camera.height - 1) / 2], [camera.width - 1.0, (camera.height - 1) / 2]])
    b = camera.bearing(uv)
    if not np.all(np.isfinite(b)):
        return None
    return b @ np.asarray(T_cam_lidar)[:3, :3]


def plot_next_pose(
    board: Board,
    boards: list[np.ndarray] | tuple[np.ndarray, ...],
    proposal: np.ndarray,
    T_cam_lidar: np.ndarray,
    camera: CameraModel,
    vertical_angles_deg: np.ndarray,
    caption: str = "",
) -> bytes:
    """Top view (x, y) and side view (horizontal range, z) in the LiDAR frame: the LiDAR (triangle),
    the camera (square) with its horizontal field of view, the LiDAR's vertical field (side view),
    the boards so far (blue, numbered, a tick along the printed face's normal) and the proposal
    (red). ``boards`` and ``proposal``: (4, 4) ``T_lidar_board``."""
    fig, axes = _figure(12.0, 5.4, 1, 2)
    top, side = axes[0]
    cam = -np.asarray(T_cam_lidar)[:3, :3].T @ np.asarray(T_cam_lidar)[:3, 3]
    reach = 1.0
    items = [(T, "C0", str(i + 1)) for i, T in enumerate(boards)] + [(proposal, "red", "next")]
    for T, colour, label in items:
        T = np.asarray(T, dtype=np.float64)
        c = _corners(board, T)
        centre = c[:4].mean(axis=0)
        n = T[:3, 2]
        reach = max(reach, float(np.abs(c[:, :2]).max()))
        lw = 3.0 if label == "next" else 1.5
        r = np.hypot(c[:, 0], c[:, 1])
        for ax, xs, ys, tip in (
            (top, c[:, 0], c[:, 1], centre[:2] + 0.3 * n[:2]),
            (side, r, c[:, 2], (np.hypot(*(centre[:2] + 0.3 * n[:2])), centre[2] + 0.3 * n[2])),
        ):
            ax.plot(xs, ys, color=colour, lw=lw)
            cx, cy = (centre[0], centre[1]) if ax is top else (np.hypot(centre[0], centre[1]), centre[2])
            ax.plot([cx, tip[0]], [cy, tip[1]], color=colour, lw=1.0)
            # out of the layout: it need not measure each label (the same picture, faster)
            ax.annotate(
                label, (cx, cy), fontsize=8, color=colour, xytext=(3, 3), textcoords="offset points"
            ).set_in_layout(False)
    reach += 0.5
    rays = _fov_rays(camera, T_cam_lidar)
    if rays is not None:
        for d in rays:
            top.plot([cam[0], cam[0] + reach * d[0]], [cam[1], cam[1] + reach * d[1]], "k:", lw=0.8)
    top.plot(0, 0, "k^", ms=9, label="LiDAR")
    top.plot(cam[0], cam[1], "ks", ms=6, label="camera")
    top.set_aspect("equal")
    top.set_xlim(-reach, reach)
    top.set_ylim(-reach, reach)
    top.set_xlabel("x (m, LiDAR forward)")
    top.set_ylabel("y (m, LiDAR left)")
    top.set_title("from above" + ("" if rays is None else " (dotted: the camera's field of view)"))
    top.grid(alpha=0.3)
    top.legend(loc="lower right", fontsize=8)
    va = np.radians([float(np.min(vertical_angles_deg)), float(np.max(vertical_angles_deg))])
    for a in va:
        side.plot([0, reach * np.cos(a)], [0, reach * np.sin(a)], "k:", lw=0.8)
    side.plot(0, 0, "k^", ms=9)
    side.plot(np.hypot(cam[0], cam[1]), cam[2], "ks", ms=6)
    side.set_aspect("equal")
    side.set_xlim(0, reach)
    side.set_xlabel("horizontal distance from the LiDAR (m)")
    side.set_ylabel("height above the LiDAR (m)")
    side.set_title("from the side (dotted: the LiDAR's vertical field)")
    side.grid(alpha=0.3)
    if caption:
        fig.suptitle(caption, fontsize=9)
    return _png(fig)


def next_pose_png(proposal: Proposal) -> bytes:
    """``next_pose.png``: the rig from above and the side with the boards so far and the proposal;
    ValueError for a proposal without its rig."""
    import textwrap

    rig = proposal.rig
    if rig is None:
        raise ValueError("next_pose_png: the proposal carries no rig to draw")
    return plot_next_pose(
        rig.board,
        proposal.boards,
        proposal.T_lidar_board,
        rig.T_cam_lidar,
        rig.camera,
        rig.lidar.vertical_angles_deg,
        "\n".join(textwrap.wrap(proposal.describe(), 150)),
    )
