"""``calibrate --target-sigma DEG,MM --stop-at-target`` stops reading frames only where ``calibrate``'s
answer on the frames read reaches the target, through the command line on the recorded VLP-16 set.

iSAM2's running sigmas leave out the LiDAR's own errors (the sensor model ``calibrate`` chooses):
on this set they said 0.050 deg / 1.87 mm after 9 frames, the stream stopped there, and the answer
written (``calibrate``'s on those frames) was 0.071 deg / 2.8 mm, FAIR, the target missed with 10
frames left unread. Now each time the stream reaches the target, the frames read are solved as
``calibrate`` solves them (the update ``(batch)``), and the stream reads on until that answer
reaches it (16 frames, 0.034 deg / 1.3 mm in any direction, GOOD)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.slow

TARGET = (0.05, 2.0)  # deg, mm


def test_the_stream_stops_where_calibrates_answer_reaches_the_target(acfr_data: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    target = f"{TARGET[0]},{TARGET[1]}"
    done = subprocess.run(
        [sys.executable, "-m", "ilcc_graph.app", "calibrate", str(acfr_data), "--out", str(out),
         "--no-report", "--jobs", "2", "--target-sigma", target, "--stop-at-target"],
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    unread = [f for f in cal["frames"] if (f.get("reason") or "").startswith("not read")]
    assert unread, "the target is reachable on this set before its last frame"
    s = cal["sigma"]
    assert max(s[k] for k in ("rx_deg", "ry_deg", "rz_deg")) <= TARGET[0], s
    assert max(s[k] for k in ("tx_mm", "ty_mm", "tz_mm")) <= TARGET[1], s
    updates = yaml.safe_load((out / "incremental.yaml").read_text())["updates"]
    batches = [u for u in updates if u["frame"] == "(batch)"]
    assert batches and batches[-1]["reached_target"]  # the stop was confirmed
    assert not batches[0]["reached_target"]  # where the stream alone would have stopped
    assert f"{len(unread)} not read" in " ".join(done.stdout.split())  # the verdict counts them

