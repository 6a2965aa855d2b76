"""The rig as a strategy of the run (issues 23 and 24): ``run([rig source], RunOptions(mode="rig"))``
gives what ``calibrate_rig`` gives, through the one ``Result`` and the one writer; its headline is the
pair of the first camera and the first LiDAR, so a rig of one camera and one LiDAR reads like today's
single-pair run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from ilcc_graph.app.write import write_run
from ilcc_graph.datasets import open_source
from ilcc_graph.io.rig_results import read_rig_calibration, write_rig_calibration
from ilcc_graph.run.pipeline import run
from ilcc_graph.run.result import RunOptions
from ilcc_graph.run.rig_calibrate import calibrate_rig, to_calibration
from ilcc_graph.run.stages import StageOptions
from ilcc_graph.run.strategies import modes, strategy
from ilcc_graph.simulate import simulate_dataset, standard_spec
from ilcc_graph.simulate.rig_export import write_rig_set
from ilcc_graph.simulate.rig_spec import backpack_rig

ONE = StageOptions(jobs=1)


@pytest.fixture(scope="module")
def backpack(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("rig") / "backpack"
    write_rig_set(d, backpack_rig(width=800, n_moments=6, seed=3))
    return d


def test_the_rig_is_a_registered_strategy() -> None:
    s = strategy("rig")
    assert "rig" in modes() and s.observe is not None and s.second_pass and s.joint is None


def test_the_rig_through_the_run_is_calibrate_rig(backpack: Path, tmp_path: Path) -> None:
    result = run([open_source(backpack, rig=True)], RunOptions(mode="rig", stages=ONE))
    direct = calibrate_rig(backpack)
    assert result.mode == "rig" and set(result.poses) == set(direct.sensors)
    for s in direct.sensors:
        np.testing.assert_array_equal(result.poses[s].T, direct.T_ref_sensor[s])
        np.testing.assert_array_equal(result.poses[s].covariance, direct.pose(s).covariance)
    # the headline: the first camera against the first LiDAR, with its covariance from the joint one
    cam, lidar = direct.rig.cameras[0], direct.rig.lidars[0]
    e = direct.relative(cam, lidar)
    cal = result.calibration
    np.testing.assert_array_equal(cal.T_cam_lidar, e.T)
    np.testing.assert_array_equal(cal.covariance, e.covariance)
    assert cal.method == f"rig {cam}/{lidar}" and cal.camera is not None
    assert [f.name for f in cal.frames] == [m.name for m in direct.observation.moments]  # type: ignore[union-attr]
    assert sum(f.used for f in cal.frames) == len(set(direct.used(cam)) & set(direct.used(lidar)))
    # the one writer writes the rig's calibration.yaml (read back as the rig's) and its config
    assert result.rig is not None and result.rig.sensors == direct.sensors  # typed, not a document
    assert not result.documents
    out = write_run(tmp_path / "out", result, report=False)
    write_rig_calibration(tmp_path / "direct.yaml", to_calibration(direct))
    assert (out / "calibration.yaml").read_bytes() == (tmp_path / "direct.yaml").read_bytes()
    back = read_rig_calibration(out / "calibration.yaml")
    assert back.sensors == direct.sensors and back.reference == direct.reference
    np.testing.assert_array_equal(back.covariance, direct.covariance)
    resolved = yaml.safe_load((out / "config.resolved.yaml").read_text())
    assert set(resolved["sensors"]) == set(direct.rig.names) and resolved["options"]["mode"] == "rig"


def test_a_rigs_observation_is_not_read_as_a_pairs(backpack: Path) -> None:
    """A rig's observation holds its ``RigSource``, which no check that reads a pair's frames again
    is handed (``Observation.pair_source``): the set-up mistakes' checks judge it on its frames'
    reasons alone."""
    from ilcc_graph.run.setup_mistakes import diagnose_failure

    rig_pass = strategy("rig").observe
    assert rig_pass is not None
    obs = rig_pass(open_source(backpack, rig=True), ONE, None)
    assert obs.pair_source is None and obs.rig_source is obs.source and obs.location == str(backpack)
    assert diagnose_failure([obs], ONE) == []


def test_a_pair_as_a_rig_through_the_run_is_todays_result(tmp_path: Path) -> None:
    """A single-pair data set opened as a rig of two, in rig mode: the headline is the batch solve's
    extrinsic, the LiDAR's sensor model chosen among the same candidates (the default ``auto``)."""
    spec = standard_spec(lidar="hdl32", camera="pinhole", width=800, frames=6, seed=5)
    data = simulate_dataset(tmp_path / "pair", spec)
    base = run([open_source(data)], RunOptions(second_pass=False, stages=ONE))
    rig = run([open_source(data, rig=True)], RunOptions(mode="rig", stages=ONE))
    assert [(f.name, f.used) for f in rig.calibration.frames] == [
        (f.name, f.used) for f in base.calibration.frames
    ]
    np.testing.assert_allclose(rig.calibration.T_cam_lidar, base.calibration.T_cam_lidar, atol=1e-9)
    np.testing.assert_allclose(rig.calibration.covariance, base.calibration.covariance, rtol=1e-6, atol=1e-14)
    assert rig.rig is not None and not rig.documents  # the rig's calibration typed, no document
    chosen = rig.rig.extra["sensor_model"]
    assert chosen["chosen"] == base.calibration.sensors["model"]["chosen"] and not chosen["forced"]


def test_calibrate_a_rig_prints_its_verdict_and_writes_its_report(
    backpack: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Through the command line: the rig's verdict (a line per sensor, then the rig's level) within 80
    columns, and report/index.html with a picture per (moment, camera, LiDAR) that saw the board."""
    from ilcc_graph.app import main
    from ilcc_graph.report.rig_verdict import rig_verdict

    out = tmp_path / "out"
    assert main(["calibrate", str(backpack), "--out", str(out), "--jobs", "1"]) == 0
    printed = capsys.readouterr().out
    lines = [line for line in printed.splitlines() if not line.startswith(("wrote ", "report: "))]
    assert all(len(line) <= 80 for line in lines), printed
    level, _ = rig_verdict(read_rig_calibration(out / "calibration.yaml"))
    assert f"\n{level}: " in printed and "sensor  verdict" in printed
    page = (out / "report" / "index.html").read_text()
    pictures = sorted((out / "report" / "figures").iterdir())
    assert pictures and all(p.name in page for p in pictures)
    assert all(s in page for s in ("vlp16", "os1", "pano")) and level in page
