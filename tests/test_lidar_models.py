"""Beam tables and ring assignment by elevation."""

from __future__ import annotations

import numpy as np
import pytest

from ilcc_graph.errors import InputError
from ilcc_graph.lidars import MODEL_NAMES, NON_REPETITIVE, LidarModel, lidar_model, ring_from_points

NAMED = [
    m for m in MODEL_NAMES if m != "generic" and m not in NON_REPETITIVE
]  # spinning (Livox: test_ringless)

# (beams, lowest, highest, horizontal resolution) from the data sheets named in lidars/tables.py
SPECS = {
    "hdl32": (32, -30.67, 10.67, 0.16),
    "hdl64": (64, -24.33, 2.0, 0.1728),
    "vlp16": (16, -15.0, 15.0, 0.2),
    "vlp32c": (32, -25.0, 15.0, 0.2),
    "os1-64": (64, -16.611, 16.611, 360 / 2048),
    **{f"os1-{n}-gen2": (n, -22.5, 22.5, 360 / 1024) for n in (32, 64, 128)},
    **{f"os1-{n}-rev6": (n, -21.2, 21.2, 360 / 1024) for n in (32, 64, 128)},
    **{f"os0-{n}": (n, -45.0, 45.0, 360 / 1024) for n in (64, 128)},
    **{f"os2-{n}": (n, -11.25, 11.25, 360 / 1024) for n in (64, 128)},
    "pandar40p": (40, -25.0, 15.0, 0.2),
    "pandar64": (64, -24.897, 14.882, 0.2),
    "pandar-xt32": (32, -16.0, 15.0, 0.18),
}


@pytest.mark.parametrize("name", NAMED)
def test_tables_match_data_sheets(name: str) -> None:
    m = lidar_model(name)
    n, lo, hi, res = SPECS[name]
    assert m.n_beams == n
    assert np.all(np.diff(m.vertical_angles_deg) > 0)
    assert m.vertical_angles_deg[0] == pytest.approx(lo, abs=1e-9)
    assert m.vertical_angles_deg[-1] == pytest.approx(hi, abs=1e-9)
    assert m.horizontal_resolution_deg == pytest.approx(res)
    assert 0.005 <= m.range_sigma_m <= 0.05
    assert 0 < m.beam_divergence_rad < 0.01


def test_specific_spacings() -> None:
    assert np.allclose(np.diff(lidar_model("vlp16").vertical_angles_deg), 2.0)
    assert np.allclose(np.diff(lidar_model("hdl32").vertical_angles_deg), 4 / 3, atol=0.008)
    d64 = np.diff(lidar_model("hdl64").vertical_angles_deg)
    assert np.allclose(d64[:31], 0.5) and np.allclose(d64[32:], 1 / 3)
    vlp32c = lidar_model("vlp32c").vertical_angles_deg
    assert np.min(np.diff(vlp32c)) == pytest.approx(0.333, abs=1e-3)  # dense around the horizon
    assert np.max(np.diff(vlp32c)) > 5  # sparse at the bottom


def _points_at(angles_deg: np.ndarray, rng: np.random.Generator, per_beam: int, jitter_deg: float) -> tuple:
    ring = np.repeat(np.arange(angles_deg.size), per_beam)
    el = np.deg2rad(angles_deg[ring] + rng.uniform(-jitter_deg, jitter_deg, ring.size))
    az = rng.uniform(-np.pi, np.pi, ring.size)
    r = rng.uniform(0.5, 80.0, ring.size)
    p = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=1)
    order = rng.permutation(ring.size)  # points need not be in scan order
    return p[order], ring[order]


@pytest.mark.parametrize("name", NAMED)
def test_ring_from_points_recovers_rings(name: str) -> None:
    rng = np.random.default_rng(7)
    m = lidar_model(name)
    jitter = 0.45 * np.min(np.diff(m.vertical_angles_deg))  # inside the half-gap to the next beam
    p, ring = _points_at(m.vertical_angles_deg, rng, 200, jitter)
    got = m.ring_from_points(p)
    assert got.dtype == np.int32
    np.testing.assert_array_equal(got, ring)


def test_ring_from_points_wrong_table_fails() -> None:
    """The assignment really depends on the table: HDL-32 points read with the VLP-16 table differ."""
    rng = np.random.default_rng(1)
    m32 = lidar_model("hdl32")
    p, ring = _points_at(m32.vertical_angles_deg, rng, 20, 0.1)
    assert not np.array_equal(lidar_model("vlp16").ring_from_points(p), ring)


def test_ring_outside_the_field_clamps_to_end_beams() -> None:
    m = lidar_model("vlp16")
    p = np.array([[1.0, 0.0, 5.0], [1.0, 0.0, -5.0], [1.0, 0.0, 0.001]])
    np.testing.assert_array_equal(ring_from_points(p, m), [15, 0, 8])


def test_generic_model() -> None:
    m = lidar_model("generic", [3.0, -1.0, 1.0], 0.25)
    np.testing.assert_array_equal(m.vertical_angles_deg, [-1.0, 1.0, 3.0])
    p = np.array([[10.0, 0.0, 10 * np.tan(np.deg2rad(2.9))], [10.0, 0.0, -0.5]])
    np.testing.assert_array_equal(m.ring_from_points(p), [2, 0])
    assert m.horizontal_resolution_deg == 0.25
    assert m == lidar_model("generic", [-1.0, 1.0, 3.0], 0.25)
    assert m != lidar_model("generic", [-1.0, 1.0, 3.5], 0.25)


@pytest.mark.parametrize(
    "args, words",
    [
        (("hdl16",), ["hdl16", "vlp16"]),
        (("generic",), ["vertical_angles_deg"]),
        (("generic", [1.0, 1.0], 0.2), ["ascending"]),
        (("generic", [1.0, 2.0], 0.0), ["horizontal_resolution_deg"]),
        (("generic", [1.0, 95.0], 0.2), ["(-90, 90)"]),
    ],
)
def test_bad_models_raise_input_error(args: tuple, words: list[str]) -> None:
    with pytest.raises(InputError) as e:
        lidar_model(*args)
    for w in words:
        assert w in str(e.value)


def test_model_is_frozen() -> None:
    m = lidar_model("vlp16")
    with pytest.raises(ValueError):
        m.vertical_angles_deg[0] = 3.0
    assert isinstance(m, LidarModel)


def test_recorded_vlp16_rings_match_table(acfr_data) -> None:
    """The recorded VLP-16 scan's ring field agrees with the elevation-based assignment."""
    from ilcc_graph.io import read_scan

    scan = read_scan(acfr_data / "pcd" / "pose01.pcd")
    got = lidar_model("vlp16").ring_from_points(scan.points)
    assert np.mean(got == scan.ring) > 0.99


def test_to_dict_lists_only_overrides() -> None:
    assert lidar_model("vlp16").to_dict() == {"model": "vlp16"}
    m = lidar_model("vlp16", horizontal_resolution_deg=0.4, range_sigma_m=0.01)
    assert m.to_dict() == {"model": "vlp16", "horizontal_resolution_deg": 0.4, "range_sigma_m": 0.01}
    g = lidar_model("generic", [0.0, 1.0], 0.5)
    assert g.to_dict() == {
        "model": "generic",
        "vertical_angles_deg": [0.0, 1.0],
        "horizontal_resolution_deg": 0.5,
    }
    assert lidar_model(**{("name" if k == "model" else k): v for k, v in g.to_dict().items()}) == g
