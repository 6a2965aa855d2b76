"""The command line flag by flag: each command and option run through ``ilcc-graph`` (``app.main``)
on small simulated sets, and what it wrote checked.

Accuracy is judged against the run's own covariance: the error against the simulated truth, as the
Mahalanobis distance squared (NEES), stays under the chi-square bound of 6 dof at 99.9 %, 22.5; a
covariance 10 x too small gives NEES ~ 100 x larger, one 10 x too large passes any fixed bound but
fails the width checks of the other tests (test_graph.py's Monte Carlo checks the mean NEES;
test_cli_honesty.py the mean NEES over seeds of each camera model and LiDAR kind, both ways).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from accuracy import NEES_BOUND, pose_nees
from pair_as_rig import rig_of_two
from scipy.stats import chi2

from ilcc_graph.app import main
from ilcc_graph.cameras import make_camera

#: NEES bound: chi-square, 6 dof, 99.9 %


def _yaml(path: Path) -> dict:
    return yaml.safe_load(path.read_text())


def _runpose_nees(out: Path, data: Path) -> float:
    cal = _yaml(out / "calibration.yaml")
    return pose_nees(cal["T_cam_lidar"], cal["covariance"], _yaml(data / "ground_truth.yaml")["T_cam_lidar"])


@pytest.fixture(scope="module")
def pano(simulated) -> Path:
    return simulated("equirectangular")


def test_refine_paper(pano, calibrated, capsys, tmp_path):
    out = tmp_path / "paper"
    assert (
        main(["calibrate", str(pano), "--out", str(out), "--jobs", "1", "--no-report", "--refine", "paper"])
        == 0
    )
    assert capsys.readouterr().out.startswith("NO UNCERTAINTY: ")
    cal = _yaml(out / "calibration.yaml")
    assert cal["method"] == "paper" and np.all(np.isnan(np.array(cal["covariance"], float)))
    assert _yaml(out / "config.resolved.yaml")["options"]["mode"] == "paper"
    # no covariance of its own: judged under the graph's on the same frames, 1.5 x wider (the paper's
    # refinement holds the boards fixed: ~1.5 x the graph's error, docs/bench_graph.md section 4)
    graph = _yaml(calibrated(pano) / "calibration.yaml")
    truth = _yaml(pano / "ground_truth.yaml")["T_cam_lidar"]
    assert pose_nees(cal["T_cam_lidar"], 1.5**2 * np.array(graph["covariance"]), truth) < NEES_BOUND


def test_robust(pano, calibrated):
    out = calibrated(pano, "--robust", "huber")
    assert _yaml(out / "config.resolved.yaml")["options"]["noise"]["robust"] == "huber"
    assert _runpose_nees(out, pano) < NEES_BOUND


def test_refine_intrinsics(simulated, calibrated, tmp_path):
    """Stated intrinsics off by a typical error: refined, they come back to the truth within their
    sigmas, and the extrinsic stays within its own; Kalibr gets the refined ones. The same data as
    a rig of two give the same answer and intrinsics, and its camchain carries them."""
    data = simulated("pinhole", "--intrinsics-error", "1")
    # the LiDAR read as 6-dof poses. k3 (0 in truth) refines to ~1e-5, moving pixels by ~0.02 px:
    # below cameras.pinhole.KALIBR_PX, so the camchain leaves it out with a comment
    out = calibrated(data, "--refine-intrinsics", "--sensor-model", "none")
    got = _yaml(out / "calibration.yaml")["sensor_errors"]["camera_intrinsics"]
    error = _yaml(data / "ground_truth.yaml")["camera_intrinsics_error"]  # stated minus true
    z_refined, z_stated = [], []
    for name, v in got.items():
        true = v["stated"] - error[name]
        z_refined.append((v["refined"] - true) / v["sigma"])
        z_stated.append((v["stated"] - true) / v["sigma"])
    assert max(abs(z) for z in z_refined) < 4.0, z_refined
    assert max(abs(z) for z in z_stated) > 2.0  # the stated values were off: the test can fail
    assert _yaml(out / "config.resolved.yaml")["options"]["intrinsics"]["refine"] is True
    assert _runpose_nees(out, data) < NEES_BOUND
    assert (
        main(["export", str(out / "calibration.yaml"), "--format", "kalibr", "--out", str(tmp_path / "k")])
        == 0
    )
    cam0 = _yaml(tmp_path / "k")["cam0"]
    assert cam0["intrinsics"] == pytest.approx(
        [got[n]["refined"] for n in ("fx", "fy", "cx", "cy")], rel=1e-15
    )
    # the same data as a rig of two, the same flags: the rig's one solve refines them as the pair's
    rig = rig_of_two(tmp_path / "rig", _yaml(data / "config.yaml"), data / "pcd", data / "img")
    flags = ["--jobs", "1", "--no-report", "--refine-intrinsics", "--sensor-model", "none"]
    assert main(["calibrate", str(rig), "--out", str(tmp_path / "r"), *flags]) == 0
    doc = _yaml(tmp_path / "r" / "calibration.yaml")
    seen = doc["pairs"]["camera/lidar"]
    np.testing.assert_allclose(seen["T_a_b"], _yaml(out / "calibration.yaml")["T_cam_lidar"], atol=1e-9)
    in_rig = doc["camera_intrinsics"]["camera"]
    assert list(in_rig) == list(got)
    for name, v in in_rig.items():
        assert v["stated"] == got[name]["stated"]
        assert v["refined"] == pytest.approx(got[name]["refined"], rel=1e-9, abs=1e-12)
        assert v["sigma"] == pytest.approx(got[name]["sigma"], rel=1e-6)
    # and the rig's Kalibr camchain carries them
    assert main(["export", str(tmp_path / "r" / "calibration.yaml"), "--format", "kalibr",
                 "--out", str(tmp_path / "rk")]) == 0  # fmt: skip
    assert _yaml(tmp_path / "rk")["cam0"]["intrinsics"] == pytest.approx(
        [in_rig[n]["refined"] for n in ("fx", "fy", "cx", "cy")], rel=1e-15
    )


def test_range_offset(pano, calibrated):
    out = calibrated(pano, "--range-offset")
    offsets = _yaml(out / "joint.yaml")["range_offsets"]
    assert list(offsets) == ["hdl32"]
    value, sigma = offsets["hdl32"]["value_mm"], offsets["hdl32"]["sigma_mm"]
    # the simulated HDL-32 has no global offset; its per-beam biases and 4 mm on black print average out
    assert 0 < sigma < 5 and abs(value) < 4 * sigma
    assert _yaml(out / "config.resolved.yaml")["options"]["joint"]["range_offset"] is True
    assert _runpose_nees(out, pano) < NEES_BOUND


@pytest.fixture(scope="module")
def sessions(simulated) -> list[Path]:
    """Two sessions of one rig (same extrinsic, other board poses)."""
    return [simulated("pinhole", seed=1), simulated("pinhole", seed=2)]


def test_mode_rigid_with_several_data(sessions, calibrated):
    out = calibrated(sessions, "--mode", "rigid")
    joint = _yaml(out / "joint.yaml")
    assert joint["mode"] == "rigid" and joint["consistency"]["moved"] is None
    assert joint["consistency"]["global"]["p_value"] > 0.01
    for d in sessions:
        assert (out / "sessions" / d.name / "calibration.yaml").is_file()
    assert len(_yaml(out / "calibration.yaml")["frames"]) == 10
    assert _runpose_nees(out, sessions[0]) < NEES_BOUND


def test_mode_drift_with_its_options(sessions, calibrated):
    flags = ("--mode", "drift", "--drift-sigma", "0.1,2", "--alpha", "0.05", "--repeatability", "0.01,0.5")
    out = calibrated(sessions, *flags)
    joint = _yaml(out / "joint.yaml")
    assert joint["mode"] == "drift" and set(joint["sessions"]) == {d.name for d in sessions}
    options = _yaml(out / "config.resolved.yaml")["options"]["joint"]
    assert (options["drift_sigma_deg"], options["drift_sigma_mm"], options["alpha"]) == (0.1, 2.0, 0.05)
    assert (options["repeatability_deg"], options["repeatability_mm"]) == (0.01, 0.5)
    truth = _yaml(sessions[0] / "ground_truth.yaml")["T_cam_lidar"]
    for e in joint["sessions"].values():  # each session's own extrinsic, within its own covariance
        assert pose_nees(e["T_cam_lidar"], e["covariance"], truth) < NEES_BOUND


def test_target_sigma_and_stop_at_target(pano, calibrated):
    out = calibrated(pano, "--target-sigma", "1,50", "--stop-at-target")
    updates = _yaml(out / "incremental.yaml")["updates"]
    read = [u for u in updates if u["frame"] not in ("(final)", "(again)", "(batch)")]
    assert read[-1]["reached_target"] and len(read) < 5  # the last two frames were never read
    assert [u for u in updates if u["frame"] == "(batch)"][-1]["reached_target"]  # calibrate's answer too
    assert _runpose_nees(out, pano) < NEES_BOUND


def test_demo_on_a_given_small_set_verbose(pano, tmp_path, capsys, caplog):
    """``demo --data`` with a set that has a ground truth: calibrated and compared with the truth;
    with ``-v`` the estimation core's notes are logged (without it they are not, test_summary.py)."""
    out = tmp_path / "demo"
    argv = [
        "demo",
        "--data",
        str(pano),
        "--out",
        str(out),
        "--jobs",
        "1",
        "--no-report",
        "--no-studies",
        "-v",
    ]
    with caplog.at_level("INFO", logger="ilcc_graph"):
        assert main(argv) == 0
    text = capsys.readouterr().out
    assert "against the truth: rotation off by" in text and "NEES" in text
    assert "simulating" not in text  # the set was there
    assert _runpose_nees(out, pano) < NEES_BOUND
    assert any(r.name.startswith("ilcc_graph.estimation") and r.levelname == "INFO" for r in caplog.records)


def _half_turn(board: dict) -> np.ndarray:
    """The board frame turned half a turn about its normal through the pattern's centre."""
    rows, cols = board["squares"]
    c = np.array([cols, rows, 0.0]) * board["square_size"] / 2
    H = np.diag([-1.0, -1.0, 1.0, 1.0])
    H[:3, 3] = 2 * c
    return H


def test_lidar_corners(pano, tmp_path, capsys):
    """The LiDAR stage alone: every board found, its pose within its covariance of the truth (or of
    the truth turned half a turn, when the fit says the pattern cannot tell), the board's points."""
    out = tmp_path / "lidar"
    assert main(["lidar-corners", str(pano), "--out", str(out), "--jobs", "1"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if line[:4].isdigit()]
    assert [r[:2] for r in rows] == [[f"{i:04d}", "yes"] for i in range(1, 6)]
    truth = _yaml(pano / "ground_truth.yaml")
    H = _half_turn(truth["board"])
    for name, T_true in truth["T_lidar_board"].items():
        doc = _yaml(out / f"{name}.yaml")
        T, C = np.array(doc["T_lidar_board"]), np.array(doc["covariance"])
        candidates = [T_true, np.array(T_true) @ H] if doc["half_turn_ambiguous"] else [T_true]
        assert min(pose_nees(T, C, t) for t in candidates) < NEES_BOUND, name
        assert (out / f"{name}_board.pcd").stat().st_size > 1000 and doc["n_points"] > 100


def test_image_corners(pano, tmp_path, capsys):
    """The image stage alone: every board's corners where the truth projects them, within the
    stated pixel covariances (chi-square of 2K dof at 99.9 %; either order of a half-turn-symmetric board)."""
    out = tmp_path / "image"
    assert main(["image-corners", str(pano), "--out", str(out), "--jobs", "1"]) == 0
    assert sum(line[:4].isdigit() and " yes " in line for line in capsys.readouterr().out.splitlines()) == 5
    truth = _yaml(pano / "ground_truth.yaml")
    camera = make_camera(_yaml(pano / "config.yaml")["camera"])
    T = np.array(truth["T_cam_lidar"])
    for name, corners in truth["corners_lidar"].items():
        doc = _yaml(out / f"{name}.yaml")
        uv, cov = np.array(doc["image_corners"]), np.array(doc["cov_px"])
        expected = camera.project(np.array(corners) @ T[:3, :3].T + T[:3, 3])
        chi = [
            float(np.einsum("ki,kij,kj->", uv - e, np.linalg.inv(cov), uv - e))
            for e in (expected, expected[::-1])
        ]
        assert min(chi) < chi2.ppf(0.999, 2 * len(uv)), (name, chi)
        assert (out / f"{name}_corners.png").read_bytes()[:4] == b"\x89PNG"


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> dict:
    """A walk-and-pause ROS 1 bag: the board held still three times for 0.3 s, carried 0.2 s between
    (13 scans at 10 Hz); its config moved away from the bag (only ``--config`` finds it)."""
    from ilcc_graph.simulate import RenderOptions, standard_spec, write_bag
    from ilcc_graph.simulate.bag import WalkAndPause

    d = tmp_path_factory.mktemp("walk")
    spec = standard_spec(lidar="hdl32", camera="pinhole", width=320, frames=3, seed=2,
                         image=RenderOptions(supersample=1))  # fmt: skip
    bag = write_bag(d / "walk.bag", spec, timeline=WalkAndPause(pause_s=0.3, move_s=0.2), image_format="png")
    config = d / "elsewhere" / "rig.yaml"
    config.parent.mkdir()
    (d / "walk.yaml").rename(config)
    return {"bag": bag, "config": config, "truth": _yaml(d / "walk.ground_truth.yaml")}


def _frames_written(out: Path) -> list[str]:
    return sorted(p.stem for p in out.glob("t*.yaml"))


def test_bag_config_min_pause_and_select(walk, tmp_path, capsys):
    bag, config, truth = walk["bag"], walk["config"], walk["truth"]
    assert main(["image-corners", str(bag), "--out", str(tmp_path / "none")]) == 2
    assert "no config for this bag" in capsys.readouterr().err
    base = ["image-corners", str(bag), "--config", str(config), "--jobs", "1"]
    # a still pause of 0.3 s counts with --min-pause 0.2: one frame per pause, from within it
    assert main([*base, "--out", str(tmp_path / "pauses"), "--min-pause", "0.2"]) == 0
    got = _frames_written(tmp_path / "pauses")
    assert len(got) == len(truth["pauses"]) == 3
    for name, (first, last) in zip(got, truth["pauses"], strict=True):
        assert float(first[1:]) <= float(name[1:]) <= float(last[1:])
    # every scan with --select all
    assert main([*base, "--out", str(tmp_path / "all"), "--min-pause", "0.2", "--select", "all"]) == 0
    assert (
        _frames_written(tmp_path / "all") == sorted(truth["T_lidar_board"])
        and len(truth["T_lidar_board"]) == 13
    )


def test_check_until_watch_and_advise(pano, tmp_path):
    out = tmp_path / "check"
    assert main(["check", str(pano), "--until", "3", "--out", str(out)]) == 0
    doc = _yaml(out / "check.yaml")
    assert [f["frame"] for f in doc["frames"]] == ["0001", "0002", "0003"] and doc[
        "stopped"
    ] == "3 frames checked"
    assert doc["final"]["n_frames"] == 3 and (out / "next_pose.png").is_file()
    out = tmp_path / "watch"
    assert main(["check", str(pano), "--watch", "--until", "2", "--advise", "--out", str(out)]) == 0
    assert [f["frame"] for f in _yaml(out / "check.yaml")["frames"]] == ["0001", "0002"]


def test_config_of_the_data_set_is_resolved_and_exported(pano, calibrated, tmp_path):
    """config.resolved.yaml beside calibration.yaml lets export find the camera of a calibration.yaml
    that lost its ``camera:`` (an older file)."""
    out = calibrated(pano)
    copy = tmp_path / "run"
    shutil.copytree(out, copy)
    doc = _yaml(copy / "calibration.yaml")
    camera = doc.pop("camera")
    (copy / "calibration.yaml").write_text(yaml.safe_dump(doc))
    assert _yaml(copy / "config.resolved.yaml")["camera"] == camera
    assert (
        main(["export", str(copy / "calibration.yaml"), "--format", "json", "--out", str(tmp_path / "j")])
        == 0
    )
    assert _yaml(tmp_path / "j")["camera"] == camera


def test_rigid_sessions_of_one_capture_twice_are_its_calibration(simulated, calibrated, tmp_path, capsys):
    """``calibrate A A --mode rigid`` (one capture given twice) chooses the sensor model as the single
    run does, says so, and gives the single run's T_cam_lidar (issue 34: one path for every door)."""
    data = simulated("pinhole", "--range-offset-mm", "20", seed=3)  # a LiDAR reading 20 mm long
    single = _yaml(calibrated(data) / "calibration.yaml")
    chosen = single["sensor_errors"]["model"]["chosen"]
    assert chosen != "none"  # the offset is there to be modelled: a joint solve without it differs
    out = tmp_path / "twice"
    capsys.readouterr()
    argv = [
        "calibrate",
        str(data),
        str(data),
        "--mode",
        "rigid",
        "--out",
        str(out),
        "--jobs",
        "1",
        "--no-report",
    ]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert f"sensor model: {chosen} " in printed
    twice = _yaml(out / "calibration.yaml")
    assert twice["sensor_errors"]["model"]["chosen"] == chosen
    assert np.abs(np.array(twice["T_cam_lidar"]) - np.array(single["T_cam_lidar"])).max() < 1e-6
