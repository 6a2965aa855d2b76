"""The command line end to end: exit codes, messages, and the calibration file's schema."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from accuracy import NEES_BOUND, pose_nees

from ilcc_graph.app import main

SIGMA_KEYS = {"rx_deg", "ry_deg", "rz_deg", "tx_mm", "ty_mm", "tz_mm"}


def _config(path: Path, **camera) -> None:
    cam = camera or {"model": "equirectangular", "width": 2000, "height": 1000}
    path.write_text(
        yaml.safe_dump(
            {
                "board": {"squares": [6, 8], "square_size": 0.075, "margin": 0.0, "lower_left": "black"},
                "lidar": {"model": "hdl32"},
                "camera": cam,
            }
        )
    )


def test_help_lists_examples(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    assert "examples:" in capsys.readouterr().out


def test_bad_usage_is_exit_2():
    with pytest.raises(SystemExit) as exc:
        main(["calibrate"])
    assert exc.value.code == 2


def test_missing_data_dir_is_exit_2(tmp_path, capsys):
    assert main(["calibrate", str(tmp_path / "nope"), "--out", str(tmp_path / "out")]) == 2
    assert "nope" in capsys.readouterr().err


def test_truncated_pcd_is_exit_2_naming_the_file(tmp_path, capsys):
    data = tmp_path / "data"
    (data / "pcd").mkdir(parents=True)
    (data / "img").mkdir()
    _config(data / "config.yaml")
    header = (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        "WIDTH 100\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 100\nDATA binary\n"
    )
    (data / "pcd" / "0001.pcd").write_bytes(header.encode() + np.zeros(10 * 4, np.float32).tobytes())
    import cv2

    cv2.imwrite(str(data / "img" / "0001.png"), np.zeros((1000, 2000, 3), np.uint8))
    assert main(["calibrate", str(data), "--out", str(tmp_path / "out"), "--jobs", "1"]) == 2
    err = capsys.readouterr().err
    assert "0001.pcd" in err
    assert not (tmp_path / "out" / "calibration.yaml").exists()


def test_bad_config_is_exit_2_naming_the_key(tmp_path, capsys):
    data = tmp_path / "data"
    (data / "pcd").mkdir(parents=True)
    (data / "img").mkdir()
    (data / "config.yaml").write_text(
        "board:\n  squares: [6]\n  square_size: 0.075\nlidar: {model: hdl32}\n"
        "camera: {model: equirectangular, width: 2000, height: 1000}\n"
    )
    assert main(["calibrate", str(data), "--out", str(tmp_path / "out")]) == 2
    assert "board.squares" in capsys.readouterr().err


@pytest.fixture(scope="module")
def small_panoramic_set(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "data"
    assert (
        main(
            [
                "simulate",
                str(out),
                "--lidar",
                "hdl32",
                "--camera",
                "equirectangular",
                "--frames",
                "6",
                "--seed",
                "3",
                "--width",
                "3000",
            ]
        )
        == 0
    )
    return out


def test_calibrate_writes_interface_schema(small_panoramic_set, tmp_path):
    out = tmp_path / "out"
    args = [
        "calibrate",
        str(small_panoramic_set),
        "--out",
        str(out),
        "--jobs",
        "1",
        "--clouds",
        "--full-views",
    ]
    assert main(args) == 0
    assert (out / "report" / "index.html").is_file()
    assert len(list((out / "coloured").glob("*.ply"))) >= 1  # on request
    assert len(list((out / "report" / "figures" / "full").glob("*_full.jpg"))) >= 1
    assert (out / "next_pose.png").is_file()
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    T = np.array(cal["T_cam_lidar"], float)
    assert T.shape == (4, 4) and np.allclose(T[3], [0, 0, 0, 1])
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    cov = np.array(cal["covariance"], float)
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    assert set(cal["sigma"]) == SIGMA_KEYS
    assert np.isclose(cal["sigma"]["tx_mm"], 1e3 * np.sqrt(cov[3, 3]), rtol=1e-6)
    assert len(cal["frames"]) == 6
    for f in cal["frames"]:
        assert isinstance(f["name"], str) and isinstance(f["used"], bool)
        if f["used"]:
            assert np.array(f["lidar_corners"]).shape == (35, 3)
            assert np.array(f["image_corners"]).shape == (35, 2)
            assert f["rms_bearing_error_mrad"] >= 0
        else:
            assert f["reason"]
    truth = yaml.safe_load((small_panoramic_set / "ground_truth.yaml").read_text())
    T_true = np.array(truth["T_cam_lidar"], float)
    assert pose_nees(T, cov, T_true) < NEES_BOUND  # the error against the run's own covariance
    assert (out / "config.resolved.yaml").is_file()


def test_no_board_anywhere_is_exit_3(small_panoramic_set, tmp_path, capsys):
    data = tmp_path / "data"
    (data / "img").mkdir(parents=True)
    (data / "pcd").symlink_to(small_panoramic_set / "pcd")
    (data / "config.yaml").write_text((small_panoramic_set / "config.yaml").read_text())
    import cv2

    blank = np.full((1500, 3000, 3), 128, np.uint8)
    for pcd in sorted((small_panoramic_set / "pcd").iterdir()):
        cv2.imwrite(str(data / "img" / f"{pcd.stem}.png"), blank)
    assert main(["calibrate", str(data), "--out", str(tmp_path / "out"), "--jobs", "1"]) == 3
    err = capsys.readouterr().err
    assert "impossible" in err
    # a short table (frame, stage, reason), one line of advice, the details in the output folder
    lines = err.splitlines()
    assert lines[0].split() == ["frame", "stage", "reason"]
    n = len(list((small_panoramic_set / "pcd").iterdir()))
    rows = [line for line in lines if line[:1].isdigit() and line.split()[1] == "image"]
    assert len(rows) == n and all(len(line) < 120 for line in lines if not line.startswith("advice"))
    assert sum(line.startswith("advice: ") for line in lines) == 1
    # a blank image is said as such at once (not searched), and the advice is about the camera
    assert all("the image is blank (every pixel grey level 128)" in line for line in rows)
    assert any(line.startswith("advice: most images are blank") for line in lines)
    doc = yaml.safe_load((tmp_path / "out" / "failure.yaml").read_text())
    assert len(doc["frames"]) >= n and {f["stage"] for f in doc["frames"]} >= {"image"}
    assert len(lines[-1]) < 200  # the message itself stays short


def test_evaluate_and_export_a_calibration(small_panoramic_set, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["calibrate", str(small_panoramic_set), "--out", str(out), "--jobs", "1", "--no-report"]) == 0
    capsys.readouterr()
    assert (
        main(
            [
                "evaluate",
                str(small_panoramic_set),
                str(out / "calibration.yaml"),
                "--out",
                str(out),
                "--jobs",
                "1",
            ]
        )
        == 0
    )
    ev = yaml.safe_load((out / "evaluation.yaml").read_text())
    assert ev["frames"] and all(f["corner_rms_px"] < 1.0 for f in ev["frames"])
    assert (
        main(["export", str(out / "calibration.yaml"), "--format", "kitti", "--out", str(out / "k.txt")]) == 0
    )
    lines = dict(line.split(":", 1) for line in (out / "k.txt").read_text().splitlines() if ":" in line)
    R = np.array(lines["R"].split(), float).reshape(3, 3)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-6)
