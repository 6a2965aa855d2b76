"""Flags of ``calibrate`` and ``simulate`` through the command line, each with its effect checked
against the simulated truth (not only that it was accepted): ``--sensor-model range|beams|offset``
on a LiDAR whose ranges all read 30 mm long, ``--robust cauchy``, ``simulate --noise-scale``,
``simulate --format velodyne-csv|ouster``. Every extrinsic is judged by its NEES against the truth
(chi-square, 6 dof, 99.9 %: ``accuracy.NEES_BOUND``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from accuracy import NEES_BOUND, pose_nees

from ilcc_graph.app import main

OFFSET_MM = 30.0  # every range of the LiDAR reads this much long (simulate --range-offset-mm)


def _yaml(path: Path) -> dict:
    return yaml.safe_load(path.read_text())


def _judged(out: Path, data: Path) -> tuple[dict, float]:
    """(calibration.yaml, its NEES against the truth); every frame used."""
    cal = _yaml(out / "calibration.yaml")
    assert all(f["used"] for f in cal["frames"]), [f.get("reason") for f in cal["frames"]]
    truth = _yaml(data / "ground_truth.yaml")["T_cam_lidar"]
    return cal, pose_nees(cal["T_cam_lidar"], cal["covariance"], truth)


@pytest.fixture(scope="module")
def long_ranges(simulated) -> Path:
    return simulated("pinhole", "--range-offset-mm", str(OFFSET_MM), seed=1)


def _forced(cal: dict, name: str) -> dict:
    model = cal["sensor_errors"]["model"]
    assert model["chosen"] == name and model["forced"] and [c["name"] for c in model["candidates"]] == [name]
    return cal["sensor_errors"].get("lidar", {}).get("terms", {})


def test_sensor_model_range_finds_the_range_offset(long_ranges, calibrated):
    """One range offset and the dark-print offset, each its true value within 3 of its sigmas
    (measured: 29.9 +- 0.9 mm, 4.0 +- 0.5 mm against 30 and 4)."""
    cal, nees = _judged(calibrated(long_ranges, "--sensor-model", "range"), long_ranges)
    assert nees < NEES_BOUND
    terms = _forced(cal, "range")
    assert set(terms) == {"offset", "dark"}, terms
    truth = _yaml(long_ranges / "ground_truth.yaml")["simulation"]["systematics"]
    for name, true_mm in (("offset", OFFSET_MM), ("dark", 1e3 * truth["dark_range_offset_m"])):
        t = terms[name]
        assert abs(t["value_mm"] - true_mm) < 3 * t["sigma_mm"], (name, t, true_mm)


def test_sensor_model_beams_finds_each_beams_bias(long_ranges, calibrated):
    """Per-beam offsets: the beams' biases as simulated, relative to their mean (the model has no
    global offset term of its own), within 3 of their sigmas for 90 % of the beams on the boards."""
    cal, nees = _judged(calibrated(long_ranges, "--sensor-model", "beams"), long_ranges)
    assert nees < NEES_BOUND
    terms = _forced(cal, "beams")
    beams = {int(n[7:-1]): t for n, t in terms.items() if n.startswith("offset[")}
    assert len(beams) >= 8 and "dark" in terms, terms
    bias = 1e3 * np.array(_yaml(long_ranges / "ground_truth.yaml")["lidar_beam_bias_m"])
    ids = sorted(beams)
    got = np.array([beams[i]["value_mm"] for i in ids])
    want = bias[ids]
    z = (got - got.mean() - (want - want.mean())) / np.array([beams[i]["sigma_mm"] for i in ids])
    assert np.mean(np.abs(z) < 3) >= 0.9, z


def test_sensor_model_offset_uses_the_stage_poses_and_one_offset(long_ranges, calibrated):
    cal, nees = _judged(calibrated(long_ranges, "--sensor-model", "offset"), long_ranges)
    assert nees < NEES_BOUND
    assert _forced(cal, "offset") == {}  # no per-return terms: the LiDAR stage's poses
    assert (
        _yaml(calibrated(long_ranges, "--sensor-model", "offset") / "config.resolved.yaml")["options"][
            "sensor_model"
        ]
        == "offset"
    )


@pytest.fixture(scope="module")
def plain(simulated, calibrated) -> tuple[Path, dict]:
    """The reference: pinhole, 640 px, 5 frames, seed 1, default flags; (data, calibration.yaml)."""
    data = simulated("pinhole", seed=1)
    cal, nees = _judged(calibrated(data), data)
    assert nees < NEES_BOUND
    return data, cal


def test_robust_cauchy(plain, calibrated):
    """The Cauchy kernel on the bearings: written to the resolved options, applied (the extrinsic
    is not least squares' to the last digit) and as honest as least squares."""
    data, ls = plain
    out = calibrated(data, "--robust", "cauchy")
    assert _yaml(out / "config.resolved.yaml")["options"]["noise"]["robust"] == "cauchy"
    cal, nees = _judged(out, data)
    assert nees < NEES_BOUND
    T, T_ls = np.array(cal["T_cam_lidar"]), np.array(ls["T_cam_lidar"])
    assert not np.allclose(T, T_ls, rtol=0, atol=1e-9)
    # the same data: the two answers within least squares' covariance of each other (measured: 2.9)
    assert pose_nees(T, np.array(ls["covariance"]), T_ls) < NEES_BOUND


def _board_spread_mm(data: Path, frame: str) -> float:
    """SD (mm) of frame's board returns off the true board plane (in the true board frame, inside
    the pattern)."""
    from ilcc_graph.io import read_scan

    truth = _yaml(data / "ground_truth.yaml")
    T = np.array(truth["T_lidar_board"][frame])
    rows, cols = truth["board"]["squares"]
    size = truth["board"]["square_size"]
    q = (read_scan(next((data / "pcd").glob(f"{frame}.*"))).points - T[:3, 3]) @ T[:3, :3]
    inside = (q[:, 0] > 0) & (q[:, 0] < cols * size) & (q[:, 1] > 0) & (q[:, 1] < rows * size)
    on = inside & (np.abs(q[:, 2]) < 0.1)
    assert on.sum() > 300, on.sum()
    return 1e3 * float(np.std(q[on, 2]))


def test_simulate_noise_scale_scales_the_board_returns_noise(simulated):
    """``simulate --noise-scale 1.5`` (same seed, same boards): the board's returns scatter about the
    true plane as the truth file states, its normal sigma (10 mm x the scale) with the beams' biases
    and the dark print's offset (a few mm) added in quadrature: measured 10.4-10.9 mm and
    15.2-15.8 mm, ratio 1.44 (1.5 diluted by the systematics)."""
    base, noisy = (
        simulated("pinhole", seed=1, frames=2),
        simulated("pinhole", "--noise-scale", "1.5", seed=1, frames=2),
    )
    for data, scale in ((base, 1.0), (noisy, 1.5)):
        sim = _yaml(data / "ground_truth.yaml")["simulation"]
        assert sim["noise_scale"] == scale
        normal = 1e3 * sim["board_noise_sigma_m"][2]
        assert normal == pytest.approx(10.0 * scale)  # stated: the baseline's 10 mm times the scale
        for frame in ("0001", "0002"):
            assert 0.95 * normal < _board_spread_mm(data, frame) < 1.15 * np.hypot(normal, 5.0), (
                scale,
                frame,
            )
    for frame in ("0001", "0002"):
        assert 1.3 < _board_spread_mm(noisy, frame) / _board_spread_mm(base, frame) < 1.55, frame


def test_simulate_velodyne_csv_calibrates_as_the_plain_pcds(plain, simulated, calibrated):
    """The same scans written as VeloView CSV (laser_id, micrometres): read back and calibrated,
    the same extrinsic as from the PCDs within a tenth of its sigma."""
    data, ref = plain
    csv = simulated("pinhole", "--format", "velodyne-csv", seed=1)
    scans = sorted((csv / "pcd").iterdir())
    assert [p.suffix for p in scans] == [".csv"] * 5
    assert scans[0].read_text().splitlines()[0] == "Points:0,Points:1,Points:2,intensity,laser_id"
    cal, nees = _judged(calibrated(csv), csv)
    assert nees < NEES_BOUND
    assert pose_nees(cal["T_cam_lidar"], np.array(ref["covariance"]), ref["T_cam_lidar"]) < 0.01


def test_simulate_ouster_format_gives_organised_scans_the_stage_reads(simulated, tmp_path, capsys):
    """``--format ouster`` (OS1-64 rev 6): organised PCDs, 64 rings of 1024 columns, raw signal; the
    LiDAR stage finds every board within its covariance of the truth."""
    from ilcc_graph.io import read_scan

    data = simulated("pinhole", "--lidar", "os1-64-rev6", "--format", "ouster", seed=1)
    header = (data / "pcd" / "0001.pcd").read_bytes()[:400].decode("ascii", "replace").splitlines()
    assert {"WIDTH 1024", "HEIGHT 64", "POINTS 65536", "FIELDS x y z intensity ring"} <= set(header)
    scan = read_scan(data / "pcd" / "0001.pcd")  # pixels without a return (0, 0, 0) left out
    assert scan.columns == 1024 and 0.9 * 65536 < len(scan) <= 65536 and scan.intensity.max() > 300
    assert set(np.unique(scan.ring)) == set(range(64))
    out = tmp_path / "lidar"
    assert main(["lidar-corners", str(data), "--out", str(out), "--jobs", "1"]) == 0
    truth = _yaml(data / "ground_truth.yaml")
    rows, cols = truth["board"]["squares"]  # the board turned half a turn about its pattern's centre
    H = np.diag([-1.0, -1.0, 1.0, 1.0])
    H[:2, 3] = np.array([cols, rows]) * truth["board"]["square_size"]
    assert sorted(truth["T_lidar_board"]) == [f"000{i}" for i in range(1, 6)]
    for name, T_true in truth["T_lidar_board"].items():
        doc = _yaml(out / f"{name}.yaml")
        candidates = [T_true, np.array(T_true) @ H] if doc["half_turn_ambiguous"] else [T_true]
        assert min(pose_nees(doc["T_lidar_board"], doc["covariance"], t) for t in candidates) < NEES_BOUND


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> dict[str, Path]:
    """The reference set (``plain``) again as ROS 2 bags by ``simulate --bag``: sqlite3 with PNG
    CompressedImages, mcap with JPEG ones whose config is moved away from the bag."""
    d = tmp_path_factory.mktemp("bags")
    base = ["--camera", "pinhole", "--width", "640", "--frames", "5", "--seed", "1", "--bag"]
    assert main(["simulate", str(d / "db3"), *base, "--storage", "sqlite3", "--bag-images", "png"]) == 0
    assert main(["simulate", str(d / "mc"), *base, "--storage", "mcap", "--bag-images", "jpeg"]) == 0
    (d / "elsewhere").mkdir()
    return {
        "sqlite3": d / "db3",
        "mcap": d / "mc",
        "mcap_config": (d / "mc.yaml").rename(d / "elsewhere" / "rig.yaml"),
    }


PNG, JPEG = b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff\xe0\x00\x10JFIF"  # the files' signatures


def _bag_file(bag: Path, storage: str, image: bytes) -> None:
    """The ROS 2 bag folder holds one file of ``storage`` whose 5 images are ``image`` files."""
    meta = _yaml(bag / "metadata.yaml")["rosbag2_bagfile_information"]
    assert meta["storage_identifier"] == storage
    types = {t["topic_metadata"]["type"] for t in meta["topics_with_message_count"]}
    assert "sensor_msgs/msg/CompressedImage" in types and "sensor_msgs/msg/Image" not in types
    (f,) = [bag / p for p in meta["relative_file_paths"]]
    blob = f.read_bytes()
    assert (blob.count(image), blob.count(PNG if image == JPEG else JPEG)) == (5, 0)


def test_a_ros2_sqlite3_bag_of_png_images_calibrates_to_the_folders_answer(plain, bags, tmp_path):
    """``calibrate`` on the sqlite3 bag: the very numbers of the folder's calibration (float32 points
    and lossless images in both), within its covariance of the truth."""
    data, ref = plain
    bag = bags["sqlite3"]
    _bag_file(bag, "sqlite3", PNG)
    out = tmp_path / "out"
    assert main(["calibrate", str(bag), "--out", str(out), "--jobs", "1", "--no-report"]) == 0
    cal = _yaml(out / "calibration.yaml")
    assert [f["name"] for f in cal["frames"]] == [f"t000000.{k}00" for k in range(5)]
    assert all(f["used"] for f in cal["frames"])
    np.testing.assert_allclose(cal["T_cam_lidar"], ref["T_cam_lidar"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(cal["covariance"], ref["covariance"], rtol=1e-9, atol=1e-15)
    truth = _yaml(bag.parent / "db3.ground_truth.yaml")["T_cam_lidar"]
    np.testing.assert_array_equal(truth, _yaml(data / "ground_truth.yaml")["T_cam_lidar"])
    assert pose_nees(cal["T_cam_lidar"], cal["covariance"], truth) < NEES_BOUND


def test_a_ros2_mcap_bag_of_jpeg_images_with_its_config_elsewhere(plain, bags, tmp_path, capsys):
    """The mcap bag, its config moved away: refused without ``--config`` (one line, exit 2), with it
    calibrated; JPEG moves the corners a little, so not the folder's numbers, but within a fraction
    of its sigmas of them and within its covariance of the truth."""
    data, ref = plain
    bag = bags["mcap"]
    _bag_file(bag, "mcap", JPEG)
    assert main(["calibrate", str(bag), "--out", str(tmp_path / "no"), "--jobs", "1", "--no-report"]) == 2
    assert "no config for this bag" in capsys.readouterr().err and not (tmp_path / "no").exists()
    out = tmp_path / "out"
    argv = ["calibrate", str(bag), "--config", str(bags["mcap_config"]), "--out", str(out), "--jobs", "1"]
    assert main([*argv, "--no-report"]) == 0
    cal = _yaml(out / "calibration.yaml")
    assert all(f["used"] for f in cal["frames"]) and len(cal["frames"]) == 5
    assert not np.allclose(cal["T_cam_lidar"], ref["T_cam_lidar"], rtol=0, atol=1e-9)
    assert pose_nees(cal["T_cam_lidar"], np.array(ref["covariance"]), ref["T_cam_lidar"]) < 0.5
    truth = _yaml(bag.parent / "mc.ground_truth.yaml")["T_cam_lidar"]
    assert pose_nees(cal["T_cam_lidar"], cal["covariance"], truth) < NEES_BOUND
