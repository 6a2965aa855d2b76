"""A rig preset other than the backpack (test_rig_commands.py) through the command line: the
ring of four pinhole cameras around an HDL-32E (``simulate-rig --rig ring-pinhole``, 400 px, 12
moments: three boards per camera), calibrated by ``calibrate`` and judged against the simulated
truth; then ``verify`` of that calibration on new captures: one whose left camera moved 40 mm along its
optical axis (``--translation-mm``, two boards per camera, written as a ROS 2 mcap rig bag:
``--as bag --storage mcap``), and an unchanged one of one board per camera."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from accuracy import NEES_BOUND, mean_band, pose_nees

from ilcc_graph.app import main
from ilcc_graph.io.rig_results import read_rig_calibration
from ilcc_graph.io.rig_truth import read_rig_ground_truth

RING = ["--rig", "ring-pinhole", "--width", "400"]
CAMERAS = ("front", "left", "back", "right")


@pytest.fixture(scope="module")
def ring(tmp_path_factory) -> tuple[Path, Path]:
    """(the simulated ring, its calibration.yaml by ``calibrate``)."""
    d = tmp_path_factory.mktemp("ring")
    assert main(["simulate-rig", str(d / "rig"), *RING, "--seed", "1"]) == 0
    assert main(["calibrate", str(d / "rig"), "--out", str(d / "cal"), "--jobs", "1", "--no-report"]) == 0
    return d / "rig", d / "cal" / "calibration.yaml"


def test_the_ring_calibrates_within_its_covariance_both_ways(ring):
    """Every camera's pose in the LiDAR frame against the truth: each NEES under the 99.9 % bound of
    one draw, their mean (4 cameras, each on its own boards) in chi2(24)/4's two-sided 99.9 % band,
    1.9 .. 13.4 (measured 10.6, 5.2, 6.5, 13.8: mean 9.0)."""
    data, stored = ring
    got, truth = read_rig_calibration(stored), read_rig_ground_truth(data)
    assert got.reference == "lidar" and got.sensors == ("lidar", *CAMERAS)
    nees = np.array([pose_nees(got.T_ref_sensor[s], got.block(s), truth.T_a_b("lidar", s)) for s in CAMERAS])
    assert np.all(nees < NEES_BOUND), nees
    lo, hi = mean_band(6, len(CAMERAS))
    assert lo < nees.mean() < hi, nees


def _verify(stored: Path, capture: Path, out: Path) -> tuple[int, dict]:
    code = main(["verify", str(stored), str(capture), "--out", str(out), "--jobs", "1"])
    doc = yaml.safe_load((out / "verify.yaml").read_text())
    assert code == doc["exit_status"]
    return code, doc


def test_verify_finds_the_one_camera_moved_40_mm(ring, tmp_path):
    """A capture of 8 moments (two boards per camera) whose left camera moved 40 mm along its own z,
    as a ROS 2 mcap rig bag: verify fails the left camera alone, its tz change the shift within 4 of
    its sigmas (measured 39.97 +- 2.5 mm); the unchanged cameras do not fail."""
    _, stored = ring
    moved = tmp_path / "moved"
    argv = ["simulate-rig", str(moved), *RING, "--seed", "9", "--moments", "8", "--moved", "left"]
    assert main([*argv, "--translation-mm", "0,0,40", "--as", "bag", "--storage", "mcap"]) == 0
    meta = yaml.safe_load((moved / "rig" / "metadata.yaml").read_text())
    assert meta["rosbag2_bagfile_information"]["storage_identifier"] == "mcap"
    assert (moved / "rig" / "rig.mcap").is_file()
    code, doc = _verify(stored, moved, tmp_path / "v")
    assert code == 5 and [s for s, c in doc["sensors"].items() if c["verdict"] == "fail"] == ["left"]
    tz = doc["sensors"]["left"]["axes"]["tz_mm"]
    assert abs(tz["change"] - 40.0) < 4 * tz["sigma"] and tz["change"] > 4 * tz["sigma"], tz
    assert doc["sensors"]["left"]["translation_mm"] > 20.0


def test_verify_does_not_fail_an_unchanged_ring_on_one_board_per_camera(ring, tmp_path):
    _, stored = ring
    # a new capture of the same rig: other boards and noise (--seed), the same LiDAR (--rig-seed)
    argv = [str(tmp_path / "same"), *RING, "--seed", "9", "--rig-seed", "1", "--moments", "4"]
    assert main(["simulate-rig", *argv]) == 0
    code, doc = _verify(stored, tmp_path / "same", tmp_path / "v")
    assert code != 5, {s: c["reason"] for s, c in doc["sensors"].items()}
    # the capture's LiDAR errors are modelled as the stored calibration chose (its model re-chosen on four
    # boards, one per camera, was the range model, whose offset moved every camera ~155 mm: exit 5)
    stored_doc = yaml.safe_load(stored.read_text())
    stored_model = stored_doc["sensor_model"]["chosen"]
    assert any(stored_model in n for n in doc["notes"]), doc["notes"]
    # every camera's change is tested net of the LiDAR's range terms both solves estimated, as a pair's
    # is (the calibration keeps each camera's pose with the terms); the LiDAR is the same, so its terms
    # are taken as shared
    assert [w["camera"] for w in stored_doc["extrinsic_with_lidar_terms"]] == list(CAMERAS)
    said = [n for n in doc["notes"] if "tested net of the LiDAR's own range terms" in n]
    assert len(said) == 1 and said[0].startswith(f"{', '.join(CAMERAS)}: the mount's change"), doc["notes"]


def test_a_ring_whose_one_camera_is_stated_wrong_says_why_it_has_no_pose(ring, tmp_path, capsys):
    """The ring with the left camera's focal length stated twice the lens's in rig.yaml: the start
    drops every moment of that camera (its corner order fits none), so the others are calibrated and
    the left camera has no pose; its reason names the likely cause (an internal error before: the
    held-out scores asked for the missing camera's pose)."""
    data, _ = ring
    copy = tmp_path / "rig"
    copy.mkdir()
    for entry in data.iterdir():
        if entry.name != "rig.yaml":
            (copy / entry.name).symlink_to(entry.resolve())
    spec = yaml.safe_load((data / "rig.yaml").read_text())
    K = np.array(spec["sensors"]["left"]["camera"]["K"], dtype=float)
    K[0, 0], K[1, 1] = 2.0 * K[0, 0], 2.0 * K[1, 1]
    spec["sensors"]["left"]["camera"]["K"] = K.tolist()
    (copy / "rig.yaml").write_text(yaml.safe_dump(spec))
    out = tmp_path / "out"
    capsys.readouterr()
    assert main(["calibrate", str(copy), "--out", str(out), "--jobs", "1", "--no-report"]) == 0
    said = capsys.readouterr().out
    got = read_rig_calibration(out / "calibration.yaml")
    assert "left" not in got.sensors and set(got.sensors) == {"lidar", "front", "back", "right"}
    reason = got.extra["unsolved"]["left"]
    assert "likely: the camera's intrinsics or lens model: 3 of 3 images" in reason, reason
    assert "check sensors.left.camera.K" in reason and "--refine-intrinsics" not in reason, reason
    assert "no pose for left" in said and "intrinsics" in said, said
