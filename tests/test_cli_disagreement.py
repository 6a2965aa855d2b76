"""No answer the data do not support (issue 38): two frames that agree and two that disagree with
them beyond their noise give no calibration.yaml but exit 3, naming which frames agree, which
disagree and the likely cause, through the command line.

The data: a simulated set of four distinct board poses (HDL-32E + 640-px pinhole); in a copy, the
images of frames 0003 and 0004 are those of another capture of the same rig (seed 2: the board
elsewhere), as when the board moved between the scan and the photo. The set as simulated calibrates
(exit 0, every frame used), so the exit 3 is the corrupted frames' doing.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from pair_as_rig import rig_of_two
from test_diagnose import BOARD, CAMERA, T_CL, frame

from ilcc_graph.app import main
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.run.finish import require_covered, require_within_noise

FRAMES = 4
MOVED = ("0003", "0004")


def _with_moved_boards(good: Path, other: Path, out: Path) -> Path:
    """A copy of ``good`` whose frames ``MOVED`` show ``other``'s images (the board elsewhere)."""
    shutil.copytree(good, out)
    for name in MOVED:
        (image,) = sorted((other / "img").glob(f"{name}.*"))
        (out / "img" / image.name).unlink()
        shutil.copy(image, out / "img" / image.name)
    return out


def _as_rig(data: Path, where: Path) -> Path:
    """``data``'s pair as a rig of two whose camera is ``front``."""
    cfg = yaml.safe_load((data / "config.yaml").read_text())
    return rig_of_two(where, cfg, data / "pcd", data / "img", camera="front")


def test_the_set_as_simulated_calibrates_with_every_frame(simulated, calibrated):
    out = calibrated(simulated("pinhole", frames=FRAMES, seed=1))
    doc = yaml.safe_load((out / "calibration.yaml").read_text())
    assert [f["used"] for f in doc["frames"]] == [True] * FRAMES, doc["frames"]


def test_two_agreeing_frames_and_two_disagreeing_exit_3_naming_them(simulated, tmp_path, capsys):
    good = simulated("pinhole", frames=FRAMES, seed=1)
    data = _with_moved_boards(good, simulated("pinhole", frames=FRAMES, seed=2), tmp_path / "data")
    out = tmp_path / "out"
    assert main(["calibrate", str(data), "--out", str(out), "--jobs", "1", "--no-report"]) == 3
    err = capsys.readouterr().err
    assert not (out / "calibration.yaml").exists()
    failure = yaml.safe_load((out / "failure.yaml").read_text())
    message = failure["error"]
    # which frames agree and which disagree, in the message and per frame
    assert "only 2 distinct board poses agree (0001, 0002)" in message, message
    assert "2 disagree with them beyond their noise (0003, 0004)" in message, message
    assert "only 2 distinct board poses agree" in err, err
    rows = {f["frame"]: f for f in failure["frames"]}
    assert set(rows) >= {"0001", "0002", *MOVED}, failure
    for name in MOVED:
        reason = rows[name]["reason"]
        assert reason.startswith("chi-square gate") or reason.startswith("corner order"), reason
        assert "moved between the scan and the photo" in reason, reason  # the frame's likely cause
    for name in ("0001", "0002"):
        assert rows[name]["reason"].startswith("agrees with"), rows[name]
    # the likely cause over all frames: the images fit flat boards, the scans put them elsewhere
    assert "synchronisation" in (failure.get("advice") or "") and "0003, 0004" in failure["advice"], failure


def test_a_rig_of_two_with_two_agreeing_moments_and_two_disagreeing_exits_3_alike(simulated, tmp_path):
    """The same data as a rig of two: its start drops the two moved moments for the camera as the
    pair's corner order does, and the rig refuses as the pair does (it wrote a POOR answer from the
    two moments left), naming the camera, the moments and the same likely cause."""
    good = simulated("pinhole", frames=FRAMES, seed=1)
    data = _with_moved_boards(good, simulated("pinhole", frames=FRAMES, seed=2), tmp_path / "data")
    out = tmp_path / "out"
    assert main(["calibrate", str(_as_rig(data, tmp_path / "rig")), "--out", str(out), "--jobs", "1",
                 "--no-report"]) == 3  # fmt: skip
    assert not (out / "calibration.yaml").exists()
    failure = yaml.safe_load((out / "failure.yaml").read_text())
    assert failure["error"].startswith("camera 'front': only 2 distinct board poses agree (0001, 0002)")
    assert "2 disagree with them beyond their noise (0003, 0004)" in failure["error"], failure["error"]
    rows = {f["frame"]: f["reason"] for f in failure["frames"]}
    assert rows["0001"] == "agrees with 0002" and rows["0002"] == "agrees with 0001", rows
    assert "synchronisation" in (failure.get("advice") or "") and "0003, 0004" in failure["advice"], failure


def test_frames_the_gate_could_not_drop_give_no_result():
    """Used frames still failing the chi-square gate when it may drop no more (``Answer.failing``):
    no majority agrees, so no covariance covers the frames used: exit 3 naming them, each with its
    likely cause (here two boards moved 50 mm between scan and photo), and the cause over all frames."""
    rng = np.random.default_rng(4)
    frames = [dataclasses.replace(frame(rng), name=f"c{i}", used=True) for i in range(3)]
    frames += [dataclasses.replace(frame(rng, moved_m=0.05), name=f"m{i}", used=True) for i in range(2)]
    gone = dataclasses.replace(frame(rng, moved_m=0.08), name="g0", used=False, reason="chi-square gate: x")
    frames.append(gone)
    config = SimpleNamespace(board=BOARD, camera=CAMERA)
    failing = [("m0", "chi-square gate: residual 90 > 24"), ("m1", "chi-square gate: residual 80 > 24")]
    require_covered(frames, [], config, T_CL.matrix())  # nothing failing: no error
    with pytest.raises(CalibrationImpossible) as got:
        require_covered(frames, failing, config, T_CL.matrix())
    err = got.value
    assert str(err).startswith("2 of the 5 frames left (m0, m1) still disagree beyond their noise"), err
    rows = {f: why for f, _, why in err.frames}
    assert set(rows) == {"m0", "m1", "g0"}, rows
    assert all("moved between the scan and the photo" in rows[n] for n in ("m0", "m1")), rows
    assert err.advice.startswith("likely: synchronisation: the images of m0, m1, g0"), err.advice


def test_a_rigs_moments_the_gate_could_not_drop_give_no_result(simulated, tmp_path):
    """A rig's joint solve whose gate leaves used moments failing (``Solution.failing``, put into the
    real solve of a rig of two here: no simulated capture makes the gate run out of drops) is refused
    for the camera that used them, as the pair's ``finish`` refuses its frames."""
    from ilcc_graph.run.rig_calibrate import calibrate_rig
    from ilcc_graph.run.stages import StageOptions
    from ilcc_graph.run.strategies.solve_rig import RigRunOptions, require_cameras

    rig = _as_rig(simulated("pinhole", frames=FRAMES, seed=1), tmp_path / "rig")
    res = calibrate_rig(rig, RigRunOptions(stages=StageOptions(jobs=1)))
    require_cameras(res)  # as solved: every moment within its noise
    joint = res.solution.solution
    failing = [(n, "chi-square gate: residual 90 > 24") for n in MOVED]
    broken = dataclasses.replace(joint, failing=failing)
    res = dataclasses.replace(res, solution=dataclasses.replace(res.solution, solution=broken))
    with pytest.raises(CalibrationImpossible) as got:
        require_cameras(res)
    message = f"camera 'front': 2 of the {FRAMES} frames left (0003, 0004) still disagree beyond their noise"
    assert str(got.value).startswith(message), got.value
    assert {f for f, _, why in got.value.frames if "chi-square gate" in why} == set(MOVED), got.value.frames


def test_a_rig_whose_boards_sit_far_above_their_noise_gives_no_result(simulated, tmp_path):
    """A LiDAR reading 20 mm long, its rig of two solved without range terms (``RigOptions.models``:
    the pair's ``--sensor-model none``): the boards' residuals are far above their stated noise and
    used moments put the board far from where the scan saw it, so the camera is refused as the pair's
    run refuses (tests/test_selection.py), its name in the message."""
    from ilcc_graph.estimation.rig_solve import RigOptions
    from ilcc_graph.run.rig_calibrate import calibrate_rig
    from ilcc_graph.run.stages import StageOptions
    from ilcc_graph.run.strategies.solve_rig import RigRunOptions, require_cameras

    data = simulated("pinhole", "--lidar", "hdl32", "--range-offset-mm", "20", frames=7, seed=5, width=800)
    rig = _as_rig(data, tmp_path / "rig")
    options = RigRunOptions(stages=StageOptions(jobs=1), solve=RigOptions(models=("none",)))
    with pytest.raises(CalibrationImpossible) as got:
        require_cameras(calibrate_rig(rig, options))
    message = "camera 'front': the residuals are far above the detectors' stated noise (LiDAR board poses"
    assert str(got.value).startswith(message), got.value
    assert any("from where the scan saw it" in why for _, _, why in got.value.frames), got.value.frames
    assert got.value.advice.startswith("likely: the LiDAR's ranges"), got.value.advice


def test_a_used_frame_hidden_by_residuals_far_above_the_noise_gives_no_result():
    """Residuals far above the stated noise (LiDAR board poses' component 32, 5.7 x their sigma, as a
    simulated set of 8 frames with 4 boards moved before the photo gave) and a used frame whose image
    puts the board 50 mm from where its scan saw it: exit 3 naming it; none when no used frame is off."""
    rng = np.random.default_rng(5)
    clean = [dataclasses.replace(frame(rng), name=f"c{i}", used=True) for i in range(4)]
    moved = dataclasses.replace(frame(rng, moved_m=0.05), name="m0", used=True)
    config = SimpleNamespace(board=BOARD, camera=CAMERA)
    require_within_noise(clean, {"board": 32.0}, config, T_CL.matrix())  # nothing off: no error
    with pytest.raises(CalibrationImpossible) as got:
        require_within_noise([*clean, moved], {"board": 32.0}, config, T_CL.matrix())
    err = got.value
    assert "(LiDAR board poses 5.7 x their stated sigma)" in str(err), err
    assert "the result uses frames whose image puts the board far from where the scan saw it (m0)" in str(err)
    (row,) = err.frames
    assert row[0] == "m0" and row[2].startswith("used, but its image puts the board"), row
    assert err.advice.startswith("likely: synchronisation: the images of m0"), err.advice


def _misconfigured(simulated, tmp_path: Path, focal: float = 1.0, square: float = 1.0) -> tuple[int, Path]:
    """A small VLP-16 + 800-px pinhole set whose config.yaml states ``focal`` x the lens's focal
    length and ``square`` x the print's square size, calibrated: (exit code, output folder)."""
    data = tmp_path / "data"
    shutil.copytree(simulated("pinhole", "--lidar", "vlp16", frames=6, seed=3, width=800), data)
    cfg = yaml.safe_load((data / "config.yaml").read_text())
    K = np.array(cfg["camera"]["K"], dtype=float)
    K[0, 0], K[1, 1] = focal * K[0, 0], focal * K[1, 1]
    cfg["camera"]["K"] = K.tolist()
    cfg["board"]["square_size"] = round(cfg["board"]["square_size"] * square, 6)
    (data / "config.yaml").write_text(yaml.safe_dump(cfg))
    out = tmp_path / "out"
    return main(["calibrate", str(data), "--out", str(out), "--jobs", "1", "--no-report"]), out


def test_a_camera_whose_focal_length_is_not_the_lenss_exits_3_naming_it(simulated, tmp_path, capsys):
    """config.yaml states twice the lens's focal length (a slip of units or of another camera's K):
    the images alone fit a flat board at some 25 x their stated corner noise. The solve's noise grows
    to cover the frames, but not an extrinsic through the wrong camera (it was written 1.5 m from the
    truth, exit 0, POOR): exit 3 naming the camera, no calibration.yaml."""
    code, out = _misconfigured(simulated, tmp_path, focal=2.0)
    assert code == 3
    assert not (out / "calibration.yaml").exists()
    failure = yaml.safe_load((out / "failure.yaml").read_text())
    assert "the images do not fit the camera as stated" in failure["error"], failure["error"]
    assert "camera.K" in failure["error"] and "the images do not fit" in capsys.readouterr().err


def test_a_rig_whose_camera_is_not_the_lenss_exits_3_naming_that_camera(simulated, tmp_path, capsys):
    """The same misconfigured pair as a rig of two (rig.yaml: the LiDAR ``lidar``, the camera
    ``front`` with twice the lens's focal length): the rig's door refuses as the pair's does (it wrote
    a POOR answer with the LiDAR's range offset at +1.4 m), naming the camera's section of rig.yaml;
    no calibration.yaml."""
    code, _ = _misconfigured(simulated, tmp_path, focal=2.0)
    rig, out = _as_rig(tmp_path / "data", tmp_path / "rig"), tmp_path / "rig_out"
    capsys.readouterr()
    assert code == main(["calibrate", str(rig), "--out", str(out), "--jobs", "1", "--no-report"]) == 3
    assert not (out / "calibration.yaml").exists()
    failure = yaml.safe_load((out / "failure.yaml").read_text())
    error, advice = failure["error"], failure["advice"]
    assert "the images do not fit camera 'front' as stated" in error, error
    assert "sensors.front.camera.K" in error and "camera 'front'" in capsys.readouterr().err
    # the likely cause names the rig's section too, and no pair's flag (a rig's cameras are not refined)
    assert "check sensors.front.camera.K" in advice and "--refine-intrinsics" not in error + advice, failure


def test_a_rig_of_three_names_the_camera_to_leave_out(simulated, tmp_path):
    """A rig of three: the LiDAR, the camera ``front`` stated with twice the lens's focal length and
    ``twin`` (the same images, the lens as it is): the run exits 3 naming ``front`` and saying that
    leaving it out of rig.yaml calibrates the other sensors."""
    _misconfigured(simulated, tmp_path, focal=2.0)
    data, rig = tmp_path / "data", _as_rig(tmp_path / "data", tmp_path / "rig")
    spec = yaml.safe_load((rig / "rig.yaml").read_text())
    twin = dict(spec["sensors"]["front"]["camera"])
    twin["K"] = (np.array(twin["K"]) * [[0.5], [0.5], [1.0]]).tolist()
    spec["sensors"]["twin"] = {"camera": twin}
    (rig / "twin").symlink_to((data / "img").resolve())
    (rig / "rig.yaml").write_text(yaml.safe_dump(spec))
    out = tmp_path / "rig_out"
    assert main(["calibrate", str(rig), "--out", str(out), "--jobs", "1", "--no-report"]) == 3
    error = yaml.safe_load((out / "failure.yaml").read_text())["error"]
    assert "camera 'front'" in error.split(":")[0] and "twin" not in error, error  # its images or moments
    assert error.endswith("or leave camera 'front' out of rig.yaml to calibrate the other sensors"), error


def test_a_square_size_not_the_prints_is_named_when_no_corner_order_fits(simulated, tmp_path):
    """board.square_size 7 % larger than the print's (a square measured, not the whole pattern): no
    extrinsic fits more than two frames in any corner order, and the exit 3 named only the order,
    advising more poses. The frames' moves say the board's size is wrong: the advice says so."""
    code, out = _misconfigured(simulated, tmp_path, square=16 / 15)
    assert code == 3
    failure = yaml.safe_load((out / "failure.yaml").read_text())
    assert failure["advice"].startswith("likely: the board's size"), failure
    assert "1.067 x" in failure["advice"] and "board.square_size" in failure["advice"], failure["advice"]


def test_a_focal_length_15_percent_long_is_named_as_the_likely_cause(simulated, tmp_path):
    """A focal length 15 % long: the boards land 0.4-0.5 m from their scans (exit 3), and 3 of the 6
    images alone fit a flat board at 7-15 x their stated noise. The likely cause named was
    synchronisation (the intrinsics needed more than half the images); it is the camera's now."""
    code, out = _misconfigured(simulated, tmp_path, focal=1.15)
    assert code == 3
    failure = yaml.safe_load((out / "failure.yaml").read_text())
    assert failure["advice"].startswith("likely: the camera's intrinsics or lens model"), failure["advice"]
