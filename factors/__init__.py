"""GTSAM factors for LiDAR-camera calibration; depends on gtsam and numpy only (never on ilcc_graph).

``factors.bearing``: spherical bearing factors on the tangent plane of the measured bearing.
``factors.pixel``: pixel reprojection factor of a view, with the camera intrinsics as a variable.
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
from factors.pixel import PIXEL_DOF, FramePixelFactor
from factors.range_offset import RangeOffsetBoardFactor

__all__ = [
    "BEARING_DOF",
    "POSE3_DOF",
    "FrameBearingFactor",
    "FramePixelFactor",
    "PIXEL_DOF",
    "RangeOffsetBoardFactor",
    "bearing_error",
    "bearing_factor",
    "bearing_point_factor",
    "board_bearing_error",
    "sqrt_information",
    "tangent_bases",
]
