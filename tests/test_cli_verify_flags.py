"""``verify``'s own flags through the command line, each with its effect: ``--tolerance`` (the change
the capture must be able to detect for ``pass``), ``--power`` (the detection probability at which the
detectable change is stated) and ``--alpha`` (the false-alarm rate of ``fail``), on one single-pair
capture (fisheye, 640 px, 5 boards) against its true extrinsic stored with a covariance of 0.02 deg
and 1 mm per axis. The thresholds come from the default run's own numbers, not from constants."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.io import read_ground_truth, write_calibration
from ilcc_graph.types import Calibration

COVARIANCE = np.diag([np.radians(0.02)] * 3 + [1e-3] * 3) ** 2


@pytest.fixture(scope="module")
def stored(simulated, tmp_path_factory) -> tuple[Path, Path, dict]:
    """(the capture, its true extrinsic as a stored calibration, verify.yaml of the default run)."""
    data = simulated("fisheye", seed=3)
    d = tmp_path_factory.mktemp("verify")
    cal = d / "truth.yaml"
    write_calibration(cal, Calibration(read_ground_truth(data).T_cam_lidar, COVARIANCE, ()))
    code, doc = _verify(cal, data, d / "default")
    assert code == 0 and doc["verdict"] == "pass"
    assert (doc["tolerance_deg"], doc["tolerance_mm"], doc["alpha"], doc["power"]) == (0.25, 10.0, 0.05, 0.95)
    return data, cal, doc


def _verify(cal: Path, data: Path, out: Path, *flags: str) -> tuple[int, dict]:
    code = main(["verify", str(cal), str(data), "--out", str(out), "--jobs", "1", *flags])
    doc = yaml.safe_load((out / "verify.yaml").read_text())
    assert code == doc["exit_status"] and (out / "verdict.txt").read_text().strip() == doc["verdict"]
    return code, doc


def test_tolerance_below_what_the_capture_detects_warns(stored, tmp_path):
    data, cal, default = stored
    cam = default["sensors"]["camera"]
    deg, mm = 0.85 * cam["detectable_deg"], 0.85 * cam["detectable_mm"]
    code, doc = _verify(cal, data, tmp_path / "v", "--tolerance", f"{deg},{mm}")
    assert (doc["tolerance_deg"], doc["tolerance_mm"]) == pytest.approx((deg, mm))
    # the same capture, the same (absent) change: only the tolerance moved below its detectable change
    assert code == 4 and doc["sensors"]["camera"]["verdict"] == "warn"
    assert doc["sensors"]["camera"]["p_value"] == pytest.approx(cam["p_value"])


def test_higher_power_makes_the_detectable_change_larger(stored, tmp_path):
    """At a tolerance 15 % above the default run's detectable change that run would pass; with
    ``--power 0.9999`` the detectable change grows past it (as the normal quantiles say, ~1.4 x on
    one axis) and the verdict is warn."""
    data, cal, default = stored
    cam = default["sensors"]["camera"]
    deg, mm = 1.15 * cam["detectable_deg"], 1.15 * cam["detectable_mm"]
    code, doc = _verify(cal, data, tmp_path / "v", "--tolerance", f"{deg},{mm}", "--power", "0.9999")
    got = doc["sensors"]["camera"]
    assert doc["power"] == 0.9999 and code == 4 and got["verdict"] == "warn", got["reason"]
    assert got["detectable_deg"] > deg and got["detectable_mm"] > mm
    for axis, a in got["axes"].items():  # every axis: same sigma, a larger detectable change
        before = cam["axes"][axis]
        assert a["sigma"] == pytest.approx(before["sigma"]) and a["detectable"] > 1.2 * before["detectable"]


def _turned(cal: Path, deg: float, out: Path) -> Path:
    """``cal`` with the camera turned ``deg`` about its own y axis."""
    doc = yaml.safe_load(cal.read_text())
    T = np.array(doc["T_cam_lidar"], dtype=float)
    T[:3] = gtsam.Rot3.Ry(np.radians(deg)).matrix() @ T[:3]
    doc["T_cam_lidar"] = T.tolist()
    out.write_text(yaml.safe_dump(doc))
    return out


def test_alpha_decides_whether_a_small_change_fails(stored, tmp_path):
    """The stored extrinsic turned by 4.5 sigma of its ry change (the default run's sigma): the same
    chi-square p-value (~1e-3) fails at ``--alpha 0.05`` and does not at ``--alpha 1e-6``."""
    data, cal, default = stored
    sigma = default["sensors"]["camera"]["axes"]["ry_deg"]["sigma"]
    moved = _turned(cal, 4.5 * sigma, tmp_path / "moved.yaml")
    code5, strict = _verify(moved, data, tmp_path / "a5", "--alpha", "0.05")
    code6, lax = _verify(moved, data, tmp_path / "a6", "--alpha", "1e-6")
    p = strict["sensors"]["camera"]["p_value"]
    assert lax["sensors"]["camera"]["p_value"] == pytest.approx(p) and 1e-6 < p < 0.05, p
    assert code5 == 5 and strict["sensors"]["camera"]["verdict"] == "fail"
    assert code6 != 5 and lax["sensors"]["camera"]["verdict"] != "fail" and lax["alpha"] == 1e-6
    assert abs(abs(strict["sensors"]["camera"]["axes"]["ry_deg"]["change"]) - 4.5 * sigma) < 2 * sigma
