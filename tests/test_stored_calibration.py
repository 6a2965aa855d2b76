"""Issue 36: one reader and one validation of a stored calibration (``io.stored.read_stored``) for
``verify``, ``export``, ``evaluate`` and the GTSAM hand-off, and ``verify`` refusing a capture that is
not comparable with the stored calibration (another board, camera model or sensors), all through the
command line: exit 2, one line naming the file and the problem."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.errors import InputError
from ilcc_graph.handoff import load_calibration
from ilcc_graph.handoff_rig import rig_prior
from ilcc_graph.io import read_ground_truth, write_calibration
from ilcc_graph.types import Calibration

RIG = ["--rig", "backpack", "--width", "1200"]
COV = np.diag([np.radians(0.02)] * 3 + [1e-3] * 3) ** 2
FISHEYE = {"model": "fisheye", "width": 640, "height": 400, "dist": [0.01, -0.002, 0.0003, -0.00004],
           "K": [[300, 0, 319.5], [0, 300, 199.5], [0, 0, 1]]}  # fmt: skip


@pytest.fixture(scope="module")
def pair(simulated) -> Path:  # noqa: ANN001 - conftest's factory
    """A small simulated pinhole pair (5 frames, 640 px), the session's ``simulated`` set."""
    return simulated("pinhole", frames=5, seed=3)


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A backpack rig calibrated through the command line; (a new capture of it, calibration.yaml)."""
    d = tmp_path_factory.mktemp("rig")
    assert main(["simulate-rig", str(d / "rig"), *RIG, "--moments", "6", "--seed", "1"]) == 0
    assert main(["calibrate", str(d / "rig"), "--out", str(d / "cal"), "--jobs", "1", "--no-report"]) == 0
    assert main(["simulate-rig", str(d / "new"), *RIG, "--moments", "5", "--seed", "9"]) == 0
    return d / "new", d / "cal" / "calibration.yaml"


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    code = main(argv)
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert code == 2, captured.out[-500:] + err[-500:]
    assert len(err.splitlines()) == 1 and "Warning" not in captured.err, err
    return err


def _broken(cov: np.ndarray, how: str) -> np.ndarray:
    """``cov`` made asymmetric or not positive definite (one eigenvalue negative)."""
    C = np.array(cov, dtype=np.float64)
    k = C.shape[0] - 6  # the last sensor's rotation about x
    if how == "asymmetric":
        C[k, k + 1] += 10 * C[k, k]
    else:
        C[k, k] = -C[k, k]
    return C


@pytest.mark.parametrize("how", ["asymmetric", "not positive definite"])
def test_a_pair_covariance_that_is_none_is_refused_by_every_reader(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], how: str
) -> None:
    """verify (before: exit 1 "math domain error", or a verdict with numpy's RuntimeWarning), export,
    evaluate and the hand-off refuse the same file with the same words."""
    T = read_ground_truth(pair).T_cam_lidar
    cal = write_calibration(tmp_path / "calibration.yaml", Calibration(T, _broken(COV, how), ()))
    words = "not symmetric" if how == "asymmetric" else "not positive definite"
    out = str(tmp_path / "v")
    errs = [
        _refused(["verify", str(cal), str(pair), "--out", out, "--jobs", "1"], capsys),
        _refused(["export", str(cal), "--format", "json"], capsys),
        _refused(["evaluate", str(pair), str(cal), "--jobs", "1"], capsys),
    ]
    with pytest.raises(InputError) as e:
        load_calibration(cal)
    for err in [*errs, f"error: {e.value}"]:
        assert f"{cal}: covariance is {words}" in err, err
    assert not Path(out).exists()


@pytest.mark.parametrize("how", ["asymmetric", "not positive definite"])
def test_a_rig_covariance_that_is_none_is_refused(
    rig: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str], how: str
) -> None:
    new, stored = rig
    doc = yaml.safe_load(stored.read_text())
    doc["covariance"] = _broken(np.array(doc["covariance"]), how).tolist()
    cal = tmp_path / "calibration.yaml"
    cal.write_text(yaml.safe_dump(doc))
    words = "not symmetric" if how == "asymmetric" else "not positive definite"
    err = _refused(["verify", str(cal), str(new), "--out", str(tmp_path / "v"), "--jobs", "1"], capsys)
    assert f"{cal}: covariance" in err and words in err
    assert words in _refused(["export", str(cal), "--format", "json"], capsys)
    with pytest.raises(InputError, match=words):
        rig_prior({"os1": 1}, cal)


def test_verify_refuses_a_capture_with_another_board(
    rig: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A capture whose rig.yaml names a 7x9 board against a calibration with a 6x8 one (before: ``warn:
    unchecked: not seen by the capture``, the board never named)."""
    new, stored = rig
    capture = tmp_path / "capture"  # the capture's files, its rig.yaml naming another board
    capture.mkdir()
    for sensor in ("vlp16", "os1", "pano"):
        (capture / sensor).symlink_to(new / sensor)
    (capture / "rig.yaml").write_text(
        (new / "rig.yaml").read_text().replace("squares: [6, 8]", "squares: [7, 9]")
    )
    err = _refused(["verify", str(stored), str(capture), "--out", str(tmp_path / "v"), "--jobs", "1"], capsys)
    assert "rig.yaml: the capture's board is [7, 9] squares" in err and "[6, 8]" in err


def test_verify_refuses_a_capture_with_another_camera_model(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A pinhole capture against a calibration of a fisheye camera (before: judged, ``FAIL - changed:
    23.8 deg``); and a capture whose board differs from the one in config.resolved.yaml beside the
    calibration."""
    T = read_ground_truth(pair).T_cam_lidar
    cal = write_calibration(
        tmp_path / "fisheye" / "calibration.yaml", Calibration(T, COV, (), camera=FISHEYE)
    )
    err = _refused(["verify", str(cal), str(pair), "--out", str(tmp_path / "v1"), "--jobs", "1"], capsys)
    assert "sensor camera is a pinhole camera in the capture but a fisheye camera" in err and str(cal) in err

    config = yaml.safe_load((pair / "config.yaml").read_text())
    cal = write_calibration(
        tmp_path / "run" / "calibration.yaml", Calibration(T, COV, (), camera=config["camera"])
    )
    config["board"]["square_size"] = 0.1
    (tmp_path / "run" / "config.resolved.yaml").write_text(yaml.safe_dump(config))
    err = _refused(["verify", str(cal), str(pair), "--out", str(tmp_path / "v2"), "--jobs", "1"], capsys)
    assert "the capture's board is [6, 8] squares of 0.075 m" in err and "[6, 8] of 0.1 m" in err
