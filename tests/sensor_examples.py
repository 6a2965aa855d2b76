"""An example of ``Calibration.sensors["lidar_errors"]`` shared by the tests of calibration.yaml and of
the report (two beams, the dark offset, one beam left out, the boards' estimated plane and beams)."""

from __future__ import annotations

import numpy as np


def lidar_errors_example() -> dict:
    """A fresh copy of the example (SI units, as the core writes it)."""
    return {
        "names": ["offset[3]", "offset[4]", "dark"],
        "values": np.array([0.0021, -0.0013, 0.0123]),
        "sigmas": np.array([0.0004, 0.0005, 0.0002]),
        "left_out": [["beam 9", "12 returns on 1 board(s): too few to estimate its terms"]],
        "elevation_deg": {"offset[3]": -9.0, "offset[4]": 7.0},
        "board_plane": {
            "offset_m": 0.0068, "tilt_rad": 0.0079, "offset_sd": 0.0012, "tilt_sd": 0.001,
            "estimated": True, "note": "", "beam_m": 0.0024, "beam_sd": 0.00017,
        },
    }  # fmt: skip
