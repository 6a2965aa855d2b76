"""GTSAM factors for LiDAR-camera calibration; depends on gtsam and numpy only (never on ilcc_graph).

``factors.bearing``: spherical bearing factors on the tangent plane of the measured bearing.
``factors.testing``: Jacobian checks against central differences on the manifold.
"""

from factors.bearing import (
    BEARING_DOF,
    POSE3_DOF,
    FrameBearingFactor,
    bearing_error,
    bearing_factor,
    bearing_point_factor,
    board_bearing_error,
    sqrt_information,
    tangent_bases,
)
from factors.range_offset import RangeOffsetBoardFactor

__all__ = [
    "BEARING_DOF",
    "POSE3_DOF",
    "FrameBearingFactor",
    "RangeOffsetBoardFactor",
    "bearing_error",
    "bearing_factor",
    "bearing_point_factor",
    "board_bearing_error",
    "sqrt_information",
    "tangent_bases",
]
