"""Can these board poses calibrate? Repeated poses, and orientations that leave the extrinsic loose.

Frames that show the board in the same place are one observation, not several: what is wrong with
that placement (a range bias along its normal, a warp of the print) is the same in all of them, so
counting them as independent would shrink the covariance for nothing. ``board_geometry`` groups
such frames (board centres within ``same_mm``, normals within ``same_deg``, long sides within
``same_deg`` modulo a half turn).

At least three distinct poses are needed (each pose gives the board's full pose in both sensors,
but what is wrong with one placement cannot be told from the extrinsic without others). Each
distinct pose's LiDAR estimate is least sure along its own normal (range errors): when all the
normals are parallel, a range error of the LiDAR moves the extrinsic along that normal unseen, so a
warning says so (``parallel``); it is not refused, because the intensity fit fixes the boards
in-plane and a modelled range error (``lidar_errors``) shows up in the covariance. ``spread`` is
the square root of the smallest eigenvalue of the mean of ``n n^T`` over the distinct poses (0:
all normals parallel or in one plane; 0.58: three orthogonal ones).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ilcc_graph.types import GraphFrame

__all__ = [
    "MAX_PARALLEL_DEG", "MIN_DISTINCT_POSES", "SAME_DEG", "SAME_MM",
    "Geometry", "board_geometry", "same_pose",
]  # fmt: skip

MIN_DISTINCT_POSES = 3
#: normals all within this angle of their mean count as parallel (a warning)
MAX_PARALLEL_DEG = 5.0
#: two board poses are one when their centres are within this many mm ...
SAME_MM = 30.0
#: ... and their normals and long sides (modulo a half turn) within this many degrees
SAME_DEG = 3.0


@dataclass(frozen=True)
class Geometry:
    """groups: frame names per distinct board pose, in input order (the first of each is kept).
    normals: (G, 3) board normals of the distinct poses, LiDAR frame. spread: see the module.
    ok: whether they can determine the extrinsic; reason and advice when not. parallel: a warning
    when every normal is within ``MAX_PARALLEL_DEG`` of their mean."""

    groups: list[list[str]]
    normals: np.ndarray
    spread: float
    ok: bool
    reason: str | None = None
    advice: str | None = None
    parallel: str | None = None

    @property
    def repeats(self) -> dict[str, str]:
        """frame name -> the frame of the same pose it repeats (for every frame but the first of a group)."""
        return {n: g[0] for g in self.groups for n in g[1:]}


def same_pose(
    a: np.ndarray, b: np.ndarray, c_a: np.ndarray, c_b: np.ndarray, mm: float = SAME_MM, deg: float = SAME_DEG
) -> bool:
    """Whether board poses ``a`` and ``b`` ((4, 4), one frame) with centres ``c_a``, ``c_b`` (m) are
    the same placement (module docstring)."""
    if np.linalg.norm(c_a - c_b) > 1e-3 * mm:
        return False
    cos = np.cos(np.radians(deg))
    return bool(a[:3, 2] @ b[:3, 2] > cos and abs(a[:3, 0] @ b[:3, 0]) > cos)


def board_geometry(
    frames: Sequence[GraphFrame], same_mm: float = SAME_MM, same_deg: float = SAME_DEG
) -> Geometry:
    """Group frames by board pose and judge whether the distinct poses can calibrate (module docstring)."""
    T = [np.asarray(f.T_lidar_board, dtype=np.float64) for f in frames]
    centres = [t[:3, :3] @ f.points_board.mean(axis=0) + t[:3, 3] for t, f in zip(T, frames, strict=True)]
    groups: list[list[int]] = []
    for i in range(len(frames)):
        for g in groups:
            if same_pose(T[g[0]], T[i], centres[g[0]], centres[i], same_mm, same_deg):
                g.append(i)
                break
        else:
            groups.append([i])
    names = [[frames[i].name for i in g] for g in groups]
    normals = np.array([T[g[0]][:3, 2] for g in groups]) if groups else np.zeros((0, 3))
    spread = (
        float(np.sqrt(max(np.linalg.eigvalsh(normals.T @ normals / len(normals)).min(), 0.0)))
        if groups
        else 0.0
    )
    repeated = [g for g in names if len(g) > 1]
    said = "; ".join(f"{', '.join(g)} show one pose" for g in repeated)
    if len(groups) < MIN_DISTINCT_POSES:
        return Geometry(
            names, normals, spread, False,
            f"{len(frames)} frame(s) show only {len(groups)} distinct board pose(s)"
            + (f" ({said})" if said else "")
            + f"; at least {MIN_DISTINCT_POSES} are needed: with fewer, nothing in the data could reveal "
            "a placement's errors (a bent print, a range bias)",
            "capture the board in more places (left, right, near, far) and tilted differently "
            "(turned left/right and up/down by 20-40 degrees)",
        )  # fmt: skip
    mean = normals.mean(axis=0)
    mean /= np.linalg.norm(mean)
    parallel = None
    if np.degrees(np.arccos(np.clip(normals @ mean, -1.0, 1.0))).max() < MAX_PARALLEL_DEG:
        parallel = (
            f"the {len(groups)} distinct board poses all face one way "
            f"(normals within {MAX_PARALLEL_DEG:g} deg): a range error of the LiDAR moves the extrinsic "
            "along that direction unseen; tilt the board between captures"
        )
    return Geometry(names, normals, spread, True, parallel=parallel)
