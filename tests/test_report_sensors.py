"""The report's and the terminal's account of the sensors' own errors (ilcc_graph.report.sensors)."""

from __future__ import annotations

import numpy as np
from sensor_examples import lidar_errors_example

from ilcc_graph.report.sensors import sensors_html, sensors_text
from ilcc_graph.types import Calibration

SENSORS = {
    "lidar_errors": lidar_errors_example(),
    "camera_intrinsics": {
        "names": ["fx", "cx"],
        "stated": np.array([900.0, 640.0]),
        "values": np.array([903.0, 641.0]),
        "sigmas": np.array([1.5, 2.0]),
    },
    "effects": {
        "lidar_errors": {"rotation_deg": 0.0123, "translation_mm": 1.25, "mahalanobis": 2.5},
        "camera_intrinsics": {"rotation_deg": 0.002, "translation_mm": 0.4, "mahalanobis": 0.7},
    },
}


def _cal(sensors: dict) -> Calibration:
    return Calibration(np.eye(4), np.eye(6) * 1e-6, (), sensors=sensors)


def test_sections_show_terms_sigmas_left_out_and_effects() -> None:
    page = sensors_html(_cal(SENSORS))
    for text in ("offset[3]", "+2.10 mm", "0.40 mm", "+12.30 mm", "-9.00", "beam 9", "too few", "903",
                 "+2.0", "0.0123", "1.25", "2.5"):  # fmt: skip
        assert text in page, text
    lines = sensors_text(_cal(SENSORS))
    assert "2 beams, -1.3 .. +2.1 mm" in lines and "dark: +12.30 mm, sigma 0.20 mm" in lines
    assert "left out: beam 9" in lines and "1.25 mm (2.5 sigma)" in lines
    assert "offset 6.8 mm, tilt 0.45 deg (+- 1.2 mm, +- 0.06 deg)" in lines
    assert "each beam's range offset changing from board to board: 2.40 +- 0.17 mm" in lines


def test_nothing_without_sensor_terms() -> None:
    assert sensors_html(_cal({})) == "" and sensors_text(_cal({})) == ""
