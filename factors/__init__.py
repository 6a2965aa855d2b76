"""GTSAM factors for LiDAR-camera calibration; depends on gtsam and numpy only (never on ilcc_graph).

``factors.bearing``: spherical bearing factors on the tangent plane of the measured bearing.
``factors.pixel``: pixel reprojection factor of a view, with the camera intrinsics as a variable.
``factors.board_points``: a board's LiDAR returns with the LiDAR's own errors as variables.
``factors.board_moments``: the same returns' cost from their moments (few rows), for optimising.
``factors.range_offset``: the board-pose prior with a LiDAR range offset.
``factors.grouped``: what the grouped factors share (the CustomFactor wrapper, per-corner whitening
and m-estimator, the pose chain).
``factors.testing``: Jacobian checks against central differences on the manifold.
"""

from factors.bearing import (
    BEARING_DOF,
    FrameBearingFactor,
    bearing_error,
    bearing_factor,
    bearing_point_factor,
    board_bearing_error,
    tangent_bases,
)
from factors.grouped import POSE3_DOF, sqrt_information
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
