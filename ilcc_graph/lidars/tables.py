"""Beam tables of the spinning LiDARs we support, and ring assignment from elevation.

A :class:`LidarModel` lists the beams' vertical angles in degrees, ascending, so that the index
in the table is the ring (0 = lowest beam). Elevation of a point is ``atan2(z, hypot(x, y))`` in
the LiDAR frame (x forward, y left, z up).

Sources of the numbers (nominal values; a unit's own calibration file differs by ~0.1 deg):

- ``hdl32``: Velodyne HDL-32E User's Manual, vertical angles -30.67 .. +10.67 deg in steps of
  1.33 deg (41.34 deg over 31 gaps). 10 Hz: ~0.16 deg azimuth step. Data sheet accuracy
  "< 2 cm" (one sigma at 25 m) -> ``range_sigma_m = 0.02``. Beam divergence ~2.8 mrad
  (0.16 deg; manual's spot size figure).
- ``hdl64``: HDL-64E S2/S3 nominal two-block model: upper block 32 lasers from +2.0 deg down in
  1/3 deg steps (to -8.33), lower block 32 lasers from -8.83 deg down in 1/2 deg steps (to -24.33).
  Per-unit tables differ (e.g. KITTI's unit spans +2 .. -24.8). 10 Hz: ~0.17 deg. Accuracy
  "< 2 cm" (1 sigma) -> 0.02 m. Divergence ~2 mrad.
- ``vlp16``: VLP-16 (Puck) manual, -15 .. +15 deg step 2 deg; 10 Hz: 0.2 deg. Accuracy "+-3 cm
  typical" -> 0.03 m. Divergence 3.0 mrad horizontal, 1.5 mrad vertical (we keep the larger).
- ``vlp32c``: VLP-32C (Ultra Puck) manual, non-uniform table -25 .. +15 deg, densest (1/3 deg)
  around the horizon. 10 Hz: 0.2 deg. Accuracy "+-3 cm typical" -> 0.03 m. Divergence ~3 mrad.
- ``os1-64``: Ouster OS1-64 gen 1, 64 beams spread uniformly over +-16.6 deg (33.2 deg field,
  0.53 deg spacing; real units report their own ``beam_altitude_angles``). 2048x10 mode:
  360/2048 deg. Accuracy "+-3 cm" (Lambertian targets) -> 0.03 m. Divergence ~0.13 deg FWHM
  (~2.3 mrad).
- Later Ouster units (uniform beam spacing; the sensor's metadata JSON has the exact angles, see
  calibration_files.py), all at the default ``1024x10`` mode (360/1024 deg), accuracy "+-3 cm"
  -> 0.03 m, divergence 2.3 mrad as gen 1:
  ``os1-64-gen2`` / ``os1-32-gen2`` / ``os1-128-gen2``: OS1 Rev C (gen 2) data sheet, 45 deg
  vertical field (+22.5 .. -22.5). ``os1-64-rev6`` / ``os1-32-rev6`` / ``os1-128-rev6``: OS1 Rev6
  (and Rev7) data sheet, 42.4 deg (+21.2 .. -21.2; the ACFR unit in ../shared measures
  +21.4 .. -20.8). ``os0-64`` / ``os0-128``: OS0, 90 deg (+-45). ``os2-64`` / ``os2-128``: OS2,
  22.5 deg (+-11.25).
- ``pandar40p``: Hesai Pandar40P, the 40 channels' nominal elevations (+15 .. -25, 1/3 deg
  around the horizon) as Hesai's own ROS driver lists them (``pandar40p_elev_angle_map``,
  HesaiTechnology HesaiLidar_General_ROS); 10 Hz: 0.2 deg; accuracy "+-2 cm" -> 0.02 m.
- ``pandar64``: Hesai Pandar64, 64 channels +14.882 .. -24.897 (0.167 deg around the horizon),
  the same driver's ``pandarGeneral_elev_angle_map``; 10 Hz: 0.2 deg; "+-2 cm" -> 0.02 m.
- ``pandar-xt32``: Hesai PandarXT-32, 32 channels +15 .. -16 deg in 1 deg steps (data sheet);
  10 Hz: 0.18 deg; accuracy "+-1 cm" -> 0.01 m.
  Hesai divergence is not on those sheets: 3 mrad assumed.
- ``generic``: the user's ``vertical_angles_deg`` and ``horizontal_resolution_deg``; range sigma
  0.03 m and divergence 3 mrad unless given.
- Scanline-free units (``pattern="non-repetitive"``: Livox's Risley-prism rosettes; the returns lie on
  no beams, so there is no ring): ``livox-mid40``, Livox Mid-40 data sheet: 38.4 deg circular field
  of view, 100,000 points/s, range precision 2 cm (1 sigma at 20 m) -> 0.02 m, beam divergence
  0.28 x 0.03 deg (we keep the larger, 4.9 mrad). ``livox-mid70``, Mid-70 data sheet: the same but a
  70.4 deg circular field. Their ``vertical_angles_deg`` are the field's lowest and highest elevation
  (the cone about x), ``horizontal_resolution_deg`` the mean angular spacing of the returns of one
  0.1 s frame (10,000 returns over the cone's solid angle). The LiDAR stage measures the real
  density from each scan (lidar/ringless.py); a scan without ring field and scanlines is recognised
  as such whatever model is named (``lidars.measure``).

Rule used for ``range_sigma_m``: the data sheet's accuracy figure is taken as one sigma
(conservative when the sheet quotes a typical bound).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, quote

__all__ = [
    "LidarModel", "lidar_model", "ring_from_points", "MODEL_NAMES", "ILCC_ALIASES", "LASER_ID_ELEVATIONS_DEG",
    "NON_REPETITIVE", "PATTERNS", "model_name",
]  # fmt: skip

#: scan patterns a LidarModel may have
PATTERNS = ("spinning", "non-repetitive")


@dataclass(frozen=True, eq=False)
class LidarModel:
    """A spinning multi-beam LiDAR.

    name: model name (one of ``MODEL_NAMES``, or ``measured`` for a table measured from a scan or
        read from a calibration file).
    vertical_angles_deg: (n,) float64, ascending; index = ring, 0 = lowest beam.
    horizontal_resolution_deg: azimuth step between successive firings of one beam.
    range_sigma_m: one-sigma range noise, metres.
    beam_divergence_rad: full beam divergence, radians.
    source: where the table came from, for messages (``"table"``, a calibration file, a scan).
    beam_origin_z_m: height of the beams' origin above the points' origin (metres; 0 for the
        named tables). Ouster clouds are given in a frame ~36 mm below the beams' origin, which a
        table measured by clustering elevations finds; ring from elevation uses ``z - beam_origin_z_m``.
    pattern: ``"spinning"`` (beams at ``vertical_angles_deg``) or ``"non-repetitive"`` (no scanlines,
        e.g. Livox; ``vertical_angles_deg`` is then the field's (lowest, highest) elevation, every
        return is on one pseudo-beam 0 and ``horizontal_resolution_deg`` is a nominal spacing).
    """

    name: str
    vertical_angles_deg: np.ndarray
    horizontal_resolution_deg: float
    range_sigma_m: float = 0.03
    beam_divergence_rad: float = 3e-3
    source: str = "table"
    beam_origin_z_m: float = 0.0
    pattern: str = "spinning"

    def __post_init__(self) -> None:
        if self.pattern not in PATTERNS:
            raise ValueError(f"pattern must be one of {PATTERNS}, got {self.pattern!r}")
        a = np.asarray(self.vertical_angles_deg, dtype=np.float64).reshape(-1)
        if a.size < 1 or not np.all(np.isfinite(a)):
            raise ValueError(
                f"vertical_angles_deg must be finite numbers, got {quote(self.vertical_angles_deg)}"
            )
        if np.any(np.diff(a) <= 0):
            raise ValueError(f"vertical_angles_deg must be strictly ascending, got {a.tolist()}")
        if np.any(np.abs(a) >= 90):
            raise ValueError(f"vertical_angles_deg must lie in (-90, 90), got {a.tolist()}")
        if not (np.isfinite(self.horizontal_resolution_deg) and 0 < self.horizontal_resolution_deg <= 10):
            raise ValueError(
                f"horizontal_resolution_deg must be in (0, 10], got {self.horizontal_resolution_deg}"
            )
        if not (self.range_sigma_m > 0 and self.beam_divergence_rad >= 0):
            raise ValueError("range_sigma_m must be > 0 and beam_divergence_rad >= 0")
        a.setflags(write=False)
        object.__setattr__(self, "vertical_angles_deg", a)
        object.__setattr__(self, "horizontal_resolution_deg", float(self.horizontal_resolution_deg))
        object.__setattr__(self, "range_sigma_m", float(self.range_sigma_m))
        object.__setattr__(self, "beam_divergence_rad", float(self.beam_divergence_rad))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LidarModel):
            return NotImplemented
        return (
            self.name == other.name
            and np.array_equal(self.vertical_angles_deg, other.vertical_angles_deg)
            and self.horizontal_resolution_deg == other.horizontal_resolution_deg
            and self.range_sigma_m == other.range_sigma_m
            and self.beam_divergence_rad == other.beam_divergence_rad
            and self.pattern == other.pattern
        )

    # unhashable, as its __eq__ compares arrays (typeshed has object.__hash__ as a method: mypy
    # cannot see None assigned to it, Python's documented way to say unhashable)
    __hash__ = None  # type: ignore[assignment]

    @property
    def n_beams(self) -> int:
        """Number of beams (a scanline-free pattern: its one pseudo-beam)."""
        return 1 if self.ringless else int(self.vertical_angles_deg.size)

    @property
    def ringless(self) -> bool:
        """True for a scanline-free pattern (no ring, no beam table)."""
        return self.pattern == "non-repetitive"

    @property
    def vertical_angles_rad(self) -> np.ndarray:
        """(n,) beam elevations in radians, ascending."""
        return np.deg2rad(self.vertical_angles_deg)

    def ring_from_points(self, points: np.ndarray) -> np.ndarray:
        """Nearest beam by elevation for each point.

        points: (N, 3) LiDAR frame. Returns (N,) int32 ring indices (0 = lowest beam).
        """
        return ring_from_points(points, self)

    def to_dict(self) -> dict:
        """Our config schema's ``lidar`` section (without ``intensity_column``); a named model
        lists only what differs from its table (angles, resolution, range sigma). A scanline-free
        pattern measured from the scans has no table to write: ``{}`` (measured again)."""
        ref = _TABLES.get(self.name)
        if self.ringless:
            d_ringless: dict = {} if ref is None else {"model": self.name}
            if ref is not None and self.range_sigma_m != ref[2]:
                d_ringless["range_sigma_m"] = self.range_sigma_m
            return d_ringless
        d: dict = {"model": self.name if ref is not None else "generic"}
        if ref is None or not np.array_equal(ref[0], self.vertical_angles_deg):
            d["vertical_angles_deg"] = [float(v) for v in self.vertical_angles_deg]
        if ref is None or ref[1] != self.horizontal_resolution_deg:
            d["horizontal_resolution_deg"] = self.horizontal_resolution_deg
        if self.range_sigma_m != (0.03 if ref is None else ref[2]):
            d["range_sigma_m"] = self.range_sigma_m
        return d


def ring_from_points(points: np.ndarray, model: LidarModel) -> np.ndarray:
    """Assign each point the beam whose vertical angle is nearest its elevation (vectorised).

    points: (N, 3) LiDAR frame, metres. Returns (N,) int32 in [0, n_beams).
    A point at the origin has elevation 0 and gets the beam nearest the horizon. A scanline-free
    model puts every point on its one pseudo-beam 0.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if model.ringless:
        return np.zeros(p.shape[0], dtype=np.int32)
    el = np.degrees(np.arctan2(p[:, 2] - model.beam_origin_z_m, np.hypot(p[:, 0], p[:, 1])))
    a = model.vertical_angles_deg
    if a.size == 1:
        return np.zeros(p.shape[0], dtype=np.int32)
    mid = 0.5 * (a[1:] + a[:-1])  # decision boundaries between neighbouring beams
    return np.searchsorted(mid, el, side="left").astype(np.int32)


_HDL32 = np.array([
    -30.67, -29.33, -28.00, -26.67, -25.33, -24.00, -22.67, -21.33, -20.00, -18.67, -17.33,
    -16.00, -14.67, -13.33, -12.00, -10.67, -9.33, -8.00, -6.67, -5.33, -4.00, -2.67,
    -1.33, 0.00, 1.33, 2.67, 4.00, 5.33, 6.67, 8.00, 9.33, 10.67,
])  # fmt: skip
# lower block: -24.33 .. -8.83 deg in 0.5 deg steps; upper block: -8.33 .. +2.0 deg in 1/3 deg steps
_HDL64 = np.concatenate([-24.33 + 0.5 * np.arange(32), 2.0 - (31 - np.arange(32)) / 3.0])
_VLP16 = np.arange(-15.0, 15.0 + 1e-9, 2.0)
_VLP32C = np.array([
    -25.0, -15.639, -11.31, -8.843, -7.254, -6.148, -5.333, -4.667, -4.0, -3.667, -3.333,
    -3.0, -2.667, -2.333, -2.0, -1.667, -1.333, -1.0, -0.667, -0.333, 0.0, 0.333,
    0.667, 1.0, 1.333, 1.667, 2.333, 3.333, 4.667, 7.0, 10.333, 15.0,
])  # fmt: skip
_OS1_64 = np.linspace(-16.611, 16.611, 64)
_PANDAR40P = np.array([
    15.0, 11.0, 8.0, 5.0, 3.0, 2.0, 1.67, 1.33, 1.0, 0.67, 0.33, 0.0, -0.33, -0.67, -1.0, -1.33,
    -1.66, -2.0, -2.33, -2.67, -3.0, -3.33, -3.67, -4.0, -4.33, -4.67, -5.0, -5.33, -5.67, -6.0,
    -7.0, -8.0, -9.0, -10.0, -11.0, -12.0, -13.0, -14.0, -19.0, -25.0,
])[::-1]  # fmt: skip
_PANDAR64 = np.array([
    14.882, 11.032, 8.059, 5.057, 3.04, 2.028, 1.86, 1.688, 1.522, 1.351, 1.184, 1.013, 0.846,
    0.675, 0.508, 0.337, 0.169, 0.0, -0.169, -0.337, -0.508, -0.675, -0.845, -1.013, -1.184,
    -1.351, -1.522, -1.688, -1.86, -2.028, -2.198, -2.365, -2.536, -2.7, -2.873, -3.04, -3.21,
    -3.375, -3.548, -3.712, -3.884, -4.05, -4.221, -4.385, -4.558, -4.72, -4.892, -5.057, -5.229,
    -5.391, -5.565, -5.726, -5.898, -6.061, -7.063, -8.059, -9.06, -9.885, -11.032, -12.006,
    -12.974, -13.93, -18.889, -24.897,
])[::-1]  # fmt: skip
_OUSTER_1024 = 360.0 / 1024.0


def _uniform(half_fov_deg: float, n: int) -> np.ndarray:
    return np.linspace(-half_fov_deg, half_fov_deg, n)


def _cone_spacing_deg(half_angle_deg: float, n: int) -> float:
    """Mean angular spacing (deg) of ``n`` returns spread over a cone of that half-angle."""
    solid = 2 * np.pi * (1 - np.cos(np.deg2rad(half_angle_deg)))
    return float(np.degrees(np.sqrt(solid / n)))


_TABLES: dict[str, tuple[np.ndarray, float, float, float]] = {
    # name: (vertical angles deg, horizontal resolution deg @10 Hz, range sigma m, divergence rad)
    "hdl32": (_HDL32, 0.16, 0.02, 2.8e-3),
    "hdl64": (_HDL64, 0.1728, 0.02, 2.0e-3),
    "vlp16": (_VLP16, 0.2, 0.03, 3.0e-3),
    "vlp32c": (_VLP32C, 0.2, 0.03, 3.0e-3),
    "os1-64": (_OS1_64, 360.0 / 2048.0, 0.03, 2.3e-3),
    **{
        f"{unit}-{n}{suffix}": (_uniform(half, n), _OUSTER_1024, 0.03, 2.3e-3)
        for unit, suffix, half in (
            ("os1", "-gen2", 22.5),
            ("os1", "-rev6", 21.2),
            ("os0", "", 45.0),
            ("os2", "", 11.25),
        )
        for n in ((32, 64, 128) if unit == "os1" else (64, 128))
    },
    "pandar40p": (_PANDAR40P, 0.2, 0.02, 3.0e-3),
    "pandar64": (_PANDAR64, 0.2, 0.02, 3.0e-3),
    "pandar-xt32": (np.arange(-16.0, 15.0 + 1e-9, 1.0), 0.18, 0.01, 3.0e-3),
    **{
        name: (np.array([-half, half]), _cone_spacing_deg(half, 10_000), 0.02, np.deg2rad(0.28))
        for name, half in (("livox-mid40", 19.2), ("livox-mid70", 35.2))
    },
}
#: the named scanline-free (non-repetitive) models
NON_REPETITIVE: tuple[str, ...] = ("livox-mid40", "livox-mid70")

#: Hardware laser numbering (the ``laser_id`` a Velodyne driver or VeloView writes): the elevation
#: (deg) of laser id 0, 1, ... The HDL-32E and VLP-16 manuals interleave lower and upper lasers.
LASER_ID_ELEVATIONS_DEG: dict[str, np.ndarray] = {
    "hdl32": np.array(
        [
            -30.67,
            -9.33,
            -29.33,
            -8.00,
            -28.00,
            -6.67,
            -26.67,
            -5.33,
            -25.33,
            -4.00,
            -24.00,
            -2.67,
            -22.67,
            -1.33,
            -21.33,
            0.00,
            -20.00,
            1.33,
            -18.67,
            2.67,
            -17.33,
            4.00,
            -16.00,
            5.33,
            -14.67,
            6.67,
            -13.33,
            8.00,
            -12.00,
            9.33,
            -10.67,
            10.67,
        ]
    ),  # fmt: skip
    "vlp16": np.array(
        [-15.0, 1.0, -13.0, 3.0, -11.0, 5.0, -9.0, 7.0, -7.0, 9.0, -5.0, 11.0, -3.0, 13.0, -1.0, 15.0]
    ),
}

MODEL_NAMES: tuple[str, ...] = (*_TABLES, "generic")
#: ILCC's ``LiDAR_type`` values -> our names.
ILCC_ALIASES: dict[str, str] = {"hdl32": "hdl32", "hdl64": "hdl64", "vlp16_puck": "vlp16", "vlp16": "vlp16"}
#: vendors' names a user may write before the model (ignored), and product names of our tables
_VENDORS = ("velodyne", "ouster", "hesai", "livox")
_PRODUCTS = {
    "hdl32e": "hdl32", "hdl64e": "hdl64", "puck": "vlp16", "ultrapuck": "vlp32c", "vlp32": "vlp32c",
    "xt32": "pandar-xt32", "pandarxt": "pandar-xt32", "mid40": "livox-mid40", "mid70": "livox-mid70",
}  # fmt: skip


def _key(name: str) -> str:
    """A model name as letters and digits only, lower case, without a vendor's name in front."""
    k = re.sub(r"[^a-z0-9]", "", str(name).lower())
    for v in _VENDORS:
        if k.startswith(v) and len(k) > len(v):
            return k[len(v) :]
    return k


def model_name(written: str) -> tuple[str | None, tuple[str, ...]]:
    """Our table's name for a LiDAR model as a user or a data sheet writes it: case, spaces, ``-``,
    ``_`` and a vendor's name do not matter (``Velodyne VLP-16``, ``HDL-32E``, ``OS1_64``). Returns
    (name, others): ``others`` the other revisions when the name fits a family of several (``OS1-128``:
    gen2 and rev6; the newest is taken), or (None, ()) when nothing fits."""
    k = _key(written)
    k = _key(_PRODUCTS.get(k, k))
    exact = [m for m in MODEL_NAMES if _key(m) == k]
    if exact:
        return exact[0], ()
    family = [
        m for m in MODEL_NAMES if _key(m).startswith(k) and re.fullmatch(r"(gen|rev)\d+", _key(m)[len(k) :])
    ]
    return (family[-1], tuple(family[:-1])) if family else (None, ())


def lidar_model(
    name: str,
    vertical_angles_deg: np.ndarray | list[float] | None = None,
    horizontal_resolution_deg: float | None = None,
    range_sigma_m: float | None = None,
) -> LidarModel:
    """The named model; ``generic`` needs ``vertical_angles_deg`` and ``horizontal_resolution_deg``.

    For a named model, given angles or resolution override the table (e.g. from a unit's own
    calibration file). Raises ``InputError`` for an unknown name or bad numbers.
    """
    key = str(name).lower()
    if key == "generic":
        if vertical_angles_deg is None or horizontal_resolution_deg is None:
            raise InputError(
                "lidar model 'generic' needs vertical_angles_deg (degrees) and horizontal_resolution_deg"
            )
        table, res, sigma, div = (
            np.asarray(vertical_angles_deg, float),
            float(horizontal_resolution_deg),
            0.03,
            3e-3,
        )
    elif key in _TABLES:
        table, res, sigma, div = _TABLES[key]
        if vertical_angles_deg is not None:
            table = np.asarray(vertical_angles_deg, float)
        if horizontal_resolution_deg is not None:
            res = float(horizontal_resolution_deg)
    else:
        raise InputError(f"unknown lidar model {quote(name)}; expected one of {list(MODEL_NAMES)}")
    if range_sigma_m is not None:
        sigma = float(range_sigma_m)
    pattern = "non-repetitive" if key in NON_REPETITIVE else "spinning"
    try:
        return LidarModel(
            key,
            np.sort(np.asarray(table, float)) if key == "generic" else table,
            res,
            sigma,
            div,
            pattern=pattern,
        )
    except ValueError as e:
        raise InputError(f"lidar model {quote(name)}: {e}") from None
