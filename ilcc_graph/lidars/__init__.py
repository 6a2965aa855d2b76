"""Beam tables of spinning LiDARs: named models, tables read from a unit's calibration file, and
tables measured from a scan.

- tables.py: :class:`LidarModel`, the named tables (data sheets cited there), ring from elevation.
- calibration_files.py: Ouster metadata JSON, Velodyne ``db.xml`` and ROS YAML, Hesai CSV.
- measure.py: the table a scan shows (ring field, organised rows, or clusters of elevations; or
  none: a scanline-free pattern), the scan's rings renumbered onto a table, and the comparison
  with a named table; a cropped scan's own table.
- scan_rings.py: elevations from the sharpest beam origin, a cropped scan's azimuth window, an
  intensity that is the ring number.
- footprint.py: a beam's footprint as points evenly covering the unit disc (for ray casters).
"""

from .calibration_files import CalibrationTable, read_calibration_file, read_calibration_table
from .measure import (
    MeasuredBeams,
    beam_index,
    choose_model,
    cropped_table,
    measure_beams,
    scanline_free,
    table_difference,
)  # fmt: skip
from .scan_rings import CROPPED_BELOW_DEG, azimuth_coverage_deg, intensity_ring, with_intensity_ring
from .tables import (
    ILCC_ALIASES,
    LASER_ID_ELEVATIONS_DEG,
    MODEL_NAMES,
    NON_REPETITIVE,
    LidarModel,
    lidar_model,
    model_name,
    ring_from_points,
)

__all__ = [
    "LidarModel", "lidar_model", "ring_from_points", "MODEL_NAMES", "ILCC_ALIASES", "model_name",
    "LASER_ID_ELEVATIONS_DEG", "MeasuredBeams", "measure_beams", "beam_index", "table_difference",
    "choose_model", "scanline_free", "NON_REPETITIVE", "read_calibration_file", "read_calibration_table",
    "CalibrationTable", "CROPPED_BELOW_DEG", "azimuth_coverage_deg", "cropped_table", "with_intensity_ring",
    "intensity_ring",
]  # fmt: skip
