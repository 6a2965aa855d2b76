"""``ilcc-graph demo`` says what it stores, where and how big, and stores the images as JPEG (a sixth
of the PNG's bytes, the same corners: docs/bench_demo.md); its data set is an output folder of ours.
"""

from __future__ import annotations

import re

import gtsam
import numpy as np
import pytest
import yaml
from accuracy import NEES_BOUND, pose_nees

from ilcc_graph.app import main
from ilcc_graph.io.output_folders import MARKER


def test_the_demo_says_what_it_stores(tmp_path, capsys):
    cache, out = tmp_path / "cache", tmp_path / "out"
    argv = ["demo", "--width", "1200", "--cache", str(cache), "--out", str(out), "--no-report", "--jobs", "1"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    data = cache / "demo-hdl32-equirect1200-seed0"
    stored = [ln for ln in printed.splitlines() if ln.startswith("kept in ")]
    assert len(stored) == 1 and str(data) in stored[0] and "deletable" in stored[0], printed
    size = sum(p.stat().st_size for p in data.rglob("*") if p.is_file()) / 1e6
    assert re.search(r"\((\d+) MB", stored[0]).group(1) == f"{size:.0f}"
    images = sorted(p.name for p in (data / "img").iterdir())
    assert len(images) == 20 and all(n.endswith(".jpg") for n in images)
    assert yaml.safe_load((data / MARKER).read_text())["kind"] == "data set"
    # the result beside the simulated truth: the errors printed are those of calibration.yaml against
    # the data set's truth, and the NEES is under chi-square's 99.9 % bound
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    truth = yaml.safe_load((data / "ground_truth.yaml").read_text())["T_cam_lidar"]
    said = re.search(r"against the truth: rotation off by ([\d.]+) deg, translation by ([\d.]+) mm", printed)
    nees_said = re.search(r"NEES ([\d.]+) \(chi-square, 6 dof", printed)
    assert said and nees_said, printed
    T, T_true = np.array(cal["T_cam_lidar"]), np.array(truth)
    xi = gtsam.Pose3(T).localCoordinates(gtsam.Pose3(T_true))
    assert float(said.group(1)) == pytest.approx(np.degrees(np.linalg.norm(xi[:3])), abs=6e-5)
    assert float(said.group(2)) == pytest.approx(1e3 * np.linalg.norm(T[:3, 3] - T_true[:3, 3]), abs=6e-3)
    nees = pose_nees(T, cal["covariance"], T_true)
    assert float(nees_said.group(1)) == pytest.approx(nees, abs=6e-3) and nees < NEES_BOUND
