"""No answer the data do not support (issue 38): two frames that agree and two that disagree with
them beyond their noise give no calibration.yaml but exit 3, naming which frames agree, which
disagree and the likely cause, through the command line.

The data: a simulated set of four distinct board poses (HDL-32E + 640-px pinhole); in a copy, the
images of frames 0003 and 0004 are those of another capture of the same rig (seed 2: the board
elsewhere), as when the board moved between the scan and the photo. The set as simulated calibrates
(exit 0, every frame used), so the exit 3 is the corrupted frames' doing.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml

from ilcc_graph.app import main

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
