"""Variable keys and dimensions of the estimation core.

``X(e)``: extrinsic e, ``T_cam_lidar`` (Pose3, ``p_cam = T_cam_lidar * p_lidar``); one per data set,
session or camera. ``B(i)``: board i's ``T_lidar_board`` (Pose3, ``p_lidar = T_lidar_board *
p_board``). ``O(l)``: LiDAR l's range offset (Vector1, metres, measured minus true range).
``L(l)``: LiDAR l's own errors (Vector, layout in ``lidar_errors.LidarLayout``). ``I(c)``: camera c's
intrinsics (Vector, ``camera.intrinsic_names``). The dimension of L and I is the assembly's
(``assembly.Assembly.dim``).
"""

from __future__ import annotations

import gtsam
from gtsam.symbol_shorthand import B, I, L, O, X

__all__ = ["B", "I", "L", "O", "POSE3_DOF", "X", "is_board", "key_dim"]

POSE3_DOF = 6
_DIMS = {"x": POSE3_DOF, "b": POSE3_DOF, "o": 1}  # symbol_shorthand letters are lower case


def key_dim(key: int) -> int:
    """Tangent dimension of a Pose3 or range-offset variable behind ``key`` (L(l): ``Assembly.dim``)."""
    return _DIMS[chr(gtsam.Symbol(key).chr()).lower()]


def is_board(key: int) -> bool:
    """True for a board variable ``B(i)`` (the local variables of the arrow-shaped systems)."""
    return chr(gtsam.Symbol(key).chr()).lower() == "b"
