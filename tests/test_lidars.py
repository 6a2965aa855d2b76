"""Beam tables measured from scans, rings renumbered onto tables, calibration files, organised PCDs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ilcc_graph.config import load_config
from ilcc_graph.errors import InputError
from ilcc_graph.io import read_scan, write_pcd
from ilcc_graph.lidars import (
    LASER_ID_ELEVATIONS_DEG,
    beam_index,
    choose_model,
    lidar_model,
    measure_beams,
    read_calibration_file,
    table_difference,
)
from ilcc_graph.lidars.measure import _clusters_on_beams
from ilcc_graph.simulate import SimulationSpec, simulate_frame
from ilcc_graph.simulate.lidar import laser_ids
from ilcc_graph.types import Scan


def _sim(lidar: str, fmt: str = "plain") -> tuple[SimulationSpec, Scan]:
    spec = SimulationSpec(lidar=lidar, n_frames=1, sensor_format=fmt, seed=1)
    return spec, simulate_frame(spec, 0).scan


def test_ouster_like_scan_measures_its_own_table_and_top_first_rings() -> None:
    spec, scan = _sim("os1-64-rev6", "ouster")
    assert scan.columns == 1024 and len(scan) == 64 * 1024  # organised, (0, 0, 0) for lost returns
    m = measure_beams(scan)
    assert m is not None and m.model.n_beams == 64
    assert np.allclose(m.model.vertical_angles_deg, spec.lidar_model.vertical_angles_deg, atol=0.02)
    assert m.model.horizontal_resolution_deg == pytest.approx(360 / 1024)
    # ring 0 is the top beam in the file; the stage's index 0 is the lowest
    valid = (scan.points != 0).any(axis=1)
    idx = beam_index(Scan(scan.points[valid], scan.intensity[valid], scan.ring[valid]), m.model)
    assert np.array_equal(idx, 63 - scan.ring[valid])
    # the named gen-1 table is contradicted, in one sentence that names both
    msg = table_difference(m, lidar_model("os1-64"))
    assert msg is not None and "+21.2 .. -21.2" in msg and "os1-64 table" in msg and "+-16.6" in msg
    assert table_difference(m, lidar_model("os1-64-rev6")) is None
    used, warning = choose_model(m, lidar_model("os1-64"), "pcd/0001.pcd")
    assert warning.startswith("pcd/0001.pcd: ") and used.n_beams == 64 and used.name == "os1-64"


@pytest.mark.parametrize("name", ["hdl32", "vlp16"])
def test_hardware_laser_ids_are_renumbered_by_elevation(name: str) -> None:
    spec, scan = _sim(name, "velodyne-csv")
    ids = laser_ids(spec.lidar_model)
    assert not np.array_equal(ids, np.arange(ids.size))  # interleaved
    assert np.allclose(LASER_ID_ELEVATIONS_DEG[name][ids], spec.lidar_model.vertical_angles_deg, atol=0.01)
    truth = np.argsort(ids)[scan.ring]  # beam (ascending) of each laser id
    m = measure_beams(scan)
    assert m.method == "ring field" and np.array_equal(beam_index(scan, m.model), truth)
    assert np.array_equal(beam_index(scan, spec.lidar_model), truth)


def test_elevation_clusters_give_the_table_without_a_ring_field() -> None:
    spec, scan = _sim("hdl32")
    m = measure_beams(Scan(scan.points, scan.intensity, None))
    assert m.method == "elevation clusters" and m.ring_values is None
    assert m.model.n_beams <= 32
    near = np.abs(m.model.vertical_angles_deg[:, None] - spec.lidar_model.vertical_angles_deg).min(axis=1)
    assert near.max() < 0.05 and m.model.n_beams >= 28  # the top beams may see nothing
    assert table_difference(m, spec.lidar_model) is None
    assert table_difference(m, lidar_model("vlp16")) is not None


def test_two_beams_merged_into_one_cluster_keep_the_named_table() -> None:
    """An OS1-64 scan without its ring field: beams 0.53 deg apart, some neighbours found as one
    elevation cluster between them. The named table stays (it did not: the scan's merged table
    replaced it and the board tests then failed on 7 of 12 simulated frames); a table that only
    some clusters fit, or whose clusters all sit between its beams, is still contradicted."""
    spec = SimulationSpec(lidar="os1-64", n_frames=1, seed=1)
    scan = simulate_frame(spec, 0).scan
    m = measure_beams(Scan(scan.points, scan.intensity, None))
    a = spec.lidar_model.vertical_angles_deg
    spacing = float(np.median(np.diff(a)))
    off_beam = np.abs(m.model.vertical_angles_deg[:, None] - a).min(axis=1) >= spacing / 3
    assert m.method == "elevation clusters" and off_beam.any()  # a merged pair, as on the frames
    assert table_difference(m, spec.lidar_model) is None
    used, warning = choose_model(m, spec.lidar_model, "pcd/0001.pcd")
    assert warning is None and used.n_beams == 64
    merged = np.concatenate([a[:10], [0.5 * (a[10] + a[11])], a[12:40]])
    assert _clusters_on_beams(merged, a, spacing)
    assert not _clusters_on_beams(0.5 * (a[1:] + a[:-1]), a, spacing)  # all between beams
    assert not _clusters_on_beams(a[:40] + 0.4 * spacing, a, spacing)  # a table shifted off the named


def test_an_ouster_scan_without_its_ring_field_calibrates(simulated, tmp_path: Path, capsys) -> None:
    """``ilcc-graph calibrate`` of an OS1-128 set exported without the ring field (as PCL or MATLAB
    write it): the named table is kept and every board found (before: the first scan's merged
    clusters replaced it, no board passed the tests, exit 3)."""
    from ilcc_graph.app import main
    from ilcc_graph.io.results import read_calibration

    data = simulated("pinhole", "--lidar", "os1-128-gen2", "--no-ring-field", frames=4, seed=7)
    out = tmp_path / "out"
    assert main(["calibrate", str(data), "--out", str(out), "--no-report", "--jobs", "1"]) == 0
    captured = capsys.readouterr()
    assert "beams span" not in captured.err  # no table replaced
    cal = read_calibration(out / "calibration.yaml")
    assert sum(f.used for f in cal.frames) == 4


def test_organised_pcd_round_trip(tmp_path: Path) -> None:
    h, w = 4, 50
    az = np.repeat(np.linspace(-0.5, 0.5, w)[None], h, axis=0).ravel()
    el = np.repeat(np.deg2rad([3.0, 1.0, -1.0, -3.0])[:, None], w, axis=1).ravel()
    p = 5.0 * np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    p[7] = 0.0  # a lost return
    inten = np.arange(h * w, dtype=float)
    path = write_pcd(tmp_path / "o.pcd", Scan(p, inten), organised=(h, w))
    s = read_scan(path)
    assert s.columns == w and len(s) == h * w - 1 and s.ring is not None
    assert np.array_equal(s.ring, np.delete(np.repeat(np.arange(h), w), 7))  # ring = row
    m = measure_beams(s)
    assert np.allclose(m.model.vertical_angles_deg, [-3, -1, 1, 3], atol=1e-4)
    with pytest.raises(ValueError, match="organised"):
        write_pcd(tmp_path / "bad.pcd", Scan(p, inten), organised=(3, w))


ALT = [21.2 - k * 42.4 / 63 for k in range(64)]


@pytest.mark.parametrize("nested", [False, True])
def test_ouster_metadata_json(tmp_path: Path, nested: bool) -> None:
    intr = {"beam_altitude_angles": ALT, "beam_azimuth_angles": [4.2, 1.4, -1.4, -4.2] * 16}
    d = (
        {"beam_intrinsics": intr, "config_params": {"lidar_mode": "2048x10"}}
        if nested
        else {**intr, "lidar_mode": "2048x10", "lidar_origin_to_beam_origin_mm": 15.806}
    )
    f = tmp_path / "meta.json"
    f.write_text(json.dumps(d))
    m = read_calibration_file(f)
    assert m.n_beams == 64 and m.horizontal_resolution_deg == pytest.approx(360 / 2048)
    assert m.vertical_angles_deg[0] == pytest.approx(-21.2) and m.vertical_angles_deg[-1] == pytest.approx(
        21.2
    )


def test_velodyne_xml_yaml_and_hesai_csv(tmp_path: Path) -> None:
    ids = LASER_ID_ELEVATIONS_DEG["vlp16"]
    items = "".join(
        f"<item><px><id_>{i}</id_><rotCorrection_>0.0</rotCorrection_><vertCorrection_>{v}</vertCorrection_>"
        "<distCorrection_>0</distCorrection_></px></item>"
        for i, v in enumerate(ids)
    )
    xml = tmp_path / "db.xml"
    xml.write_text(
        '<?xml version="1.0"?><boost_serialization><DB><lasers_><count>16</count>'
        f"{items}</lasers_></DB></boost_serialization>"
    )
    yml = tmp_path / "VLP16db.yaml"
    yml.write_text(
        "lasers:\n"
        + "".join(
            f"- {{laser_id: {i}, rot_correction: 0.0, vert_correction: {float(np.deg2rad(v))!r}, "
            "dist_correction: 0.0}\n"
            for i, v in enumerate(ids)
        )
        + "num_lasers: 16\n"
    )
    csv = tmp_path / "correction.csv"
    csv.write_text("Laser id,Elevation,Azimuth\n" + "".join(f"{i + 1},{v},0.5\n" for i, v in enumerate(ids)))
    for f in (xml, yml, csv):
        m = read_calibration_file(f)
        assert np.allclose(m.vertical_angles_deg, np.arange(-15, 16, 2)), f.name
    bad = tmp_path / "bad.json"
    bad.write_text('{"lidar_mode": "1024x10"}')
    with pytest.raises(InputError, match="bad.json.*beam_altitude_angles"):
        read_calibration_file(bad)
    with pytest.raises(InputError, match="not found"):
        read_calibration_file(tmp_path / "missing.json")


def test_config_model_optional_and_calibration_file(tmp_path: Path) -> None:
    base = (
        "board: {squares: [6, 8], square_size: 0.1}\n"
        "camera: {model: equirectangular, width: 800, height: 400}\n"
    )
    (tmp_path / "config.yaml").write_text(base)
    assert load_config(tmp_path / "config.yaml").lidar is None
    (tmp_path / "cal").mkdir()
    (tmp_path / "cal" / "meta.json").write_text(
        json.dumps({"beam_altitude_angles": ALT, "lidar_mode": "1024x10"})
    )
    (tmp_path / "config.yaml").write_text(base + "lidar: {model: os1-64, calibration_file: cal/meta.json}\n")
    m = load_config(tmp_path / "config.yaml").lidar
    assert m.name == "os1-64" and m.vertical_angles_deg[-1] == pytest.approx(21.2)
    assert m.horizontal_resolution_deg == pytest.approx(360 / 1024) and "meta.json" in m.source
    (tmp_path / "config.yaml").write_text(base + "lidar: {calibration_file: cal/nothing.json}\n")
    with pytest.raises(InputError, match="nothing.json"):
        load_config(tmp_path / "config.yaml")


def test_clusters_find_a_beam_origin_above_the_points_origin() -> None:
    # Ouster clouds are given in a frame ~36 mm below the beams' origin: seen from the points'
    # origin a beam's elevation then changes with range (1 deg at 1.5 m for the top beam)
    spec, scan = _sim("os1-64-rev6", "ouster")
    valid = (scan.points != 0).any(axis=1)
    p = scan.points[valid] + [0.0, 0.0, 0.036]
    truth = 63 - scan.ring[valid]
    m = measure_beams(Scan(p, scan.intensity[valid], None))
    assert m.method == "elevation clusters" and m.model.n_beams == 64
    assert m.model.beam_origin_z_m == pytest.approx(0.035, abs=0.006)
    assert np.allclose(m.model.vertical_angles_deg, spec.lidar_model.vertical_angles_deg, atol=0.05)
    assert np.mean(beam_index(Scan(p, scan.intensity[valid], None), m.model) == truth) > 0.999
    m0 = measure_beams(Scan(p, scan.intensity[valid], scan.ring[valid]))  # with the ring field too
    assert m0.model.beam_origin_z_m == pytest.approx(0.035, abs=0.006)
    assert table_difference(m0, spec.lidar_model) is None
