"""Every mode through the one estimation core and the one output writer, on one simulated data set.

The same observations through batch, sessions (one session), sessions with the range offset held at
zero, and incremental (all frames) give the same estimate and sigmas; every mode writes
calibration.yaml, config.resolved.yaml and the report, and exports the same way.
"""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.app.write import write_run
from ilcc_graph.datasets import FolderSource
from ilcc_graph.estimation.sessions import JointOptions
from ilcc_graph.run.observe import observe
from ilcc_graph.run.pipeline import run, solve_observations
from ilcc_graph.run.result import RunOptions
from ilcc_graph.simulate import simulate_dataset, standard_spec


@pytest.fixture(scope="module")
def pinhole_set(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("modes") / "data"
    return simulate_dataset(out, standard_spec(lidar="hdl32", camera="pinhole", width=800, frames=6, seed=5))


@pytest.fixture(scope="module")
def observed(pinhole_set):
    return observe(FolderSource(pinhole_set))


def _same(a, b, rel: float = 1e-6) -> None:
    s = np.sqrt(np.diag(a.covariance))
    xi = gtsam.Pose3(a.T_cam_lidar).localCoordinates(gtsam.Pose3(b.T_cam_lidar))
    assert np.all(np.abs(xi) < rel * s), xi / s
    assert np.all(np.abs(np.sqrt(np.diag(b.covariance)) / s - 1.0) < rel)


def test_batch_sessions_range_offset_at_zero_and_incremental_agree(pinhole_set, observed) -> None:
    # one session is the batch: the sensor model chosen as calibrate chooses it (issue 34)
    auto = solve_observations([observed]).calibration
    one = solve_observations([observed], RunOptions(mode="sessions"))
    assert one.calibration.sensors["model"]["chosen"] == auto.sensors["model"]["chosen"]
    # two solves of one graph, each stopped by the solver's tolerance: 7e-10 m apart, 1.0002e-6 of
    # the batch's sigma since a chosen model no longer carries the models it contains (0.9973e-6
    # before, the same 7e-10 m): the bound is the solver's stopping precision, with a factor 2 of room
    _same(auto, one.calibration, rel=2e-6)
    # the range offset forced and held at zero: the batch with no sensor terms
    batch = solve_observations([observed], RunOptions(sensor_model="none")).calibration
    assert sum(f.used for f in batch.frames) >= 5
    held = RunOptions(joint=JointOptions(range_offset=True, range_offset_prior_sigma_m=1e-10))
    offset = solve_observations([observed], held)
    assert abs(offset.documents["joint.yaml"]["range_offsets"]["hdl32"]["value_mm"]) < 1e-6
    _same(batch, offset.calibration)
    # incremental mode ends with the batch strategy's answer, the model chosen as calibrate chooses it
    inc = run([FolderSource(pinhole_set)], RunOptions(mode="incremental"))
    _same(auto, inc.calibration)
    assert [f.used for f in inc.calibration.frames] == [f.used for f in auto.frames]


def test_every_mode_writes_the_same_outputs_and_exports_alike(pinhole_set, observed, tmp_path) -> None:
    results = {
        "graph": solve_observations([observed]),
        "graph-none": solve_observations([observed], RunOptions(sensor_model="none")),
        "paper": solve_observations([observed], RunOptions(mode="paper")),
        "incremental": run([FolderSource(pinhole_set)], RunOptions(mode="incremental")),
        "sessions": solve_observations([observed], RunOptions(mode="sessions")),
        "two-sessions": solve_observations([observed, observed], names=["a", "b"]),
    }
    exports = {}
    for mode, res in results.items():
        out = write_run(tmp_path / mode, res, report=mode in ("sessions", "two-sessions"))
        for name in ("calibration.yaml", "config.resolved.yaml"):
            assert (out / name).is_file(), (mode, name)
        cal = yaml.safe_load((out / "calibration.yaml").read_text())
        assert cal["camera"]["model"] == "pinhole", mode
        resolved = yaml.safe_load((out / "config.resolved.yaml").read_text())
        assert resolved["options"]["mode"] == res.options.mode and "lidar" in resolved["options"]["stages"]
        k = tmp_path / f"{mode}.kitti"
        assert main(["export", str(out / "calibration.yaml"), "--format", "kitti", "--out", str(k)]) == 0
        exports[mode] = dict(line.split(":", 1) for line in k.read_text().splitlines() if ":" in line)
    assert (tmp_path / "sessions" / "report" / "index.html").is_file()
    assert (tmp_path / "two-sessions" / "report" / "a" / "index.html").is_file()
    assert (tmp_path / "two-sessions" / "joint.yaml").is_file()
    assert (tmp_path / "two-sessions" / "sessions" / "b" / "calibration.yaml").is_file()
    assert (tmp_path / "incremental" / "incremental.yaml").is_file()
    # incremental ends with the default's answer; sessions (one, or the same twice) choose the sensor
    # model as the default does and give its answer
    for mode, same in (("sessions", "graph"), ("two-sessions", "graph"), ("incremental", "graph")):
        for key in ("R", "T"):
            ref = np.array(exports[same][key].split(), float)
            assert np.allclose(np.array(exports[mode][key].split(), float), ref, atol=1e-6), (mode, key)


def test_incremental_command_writes_its_outputs(pinhole_set, tmp_path) -> None:
    out = tmp_path / "b"
    args = ["calibrate", str(pinhole_set), "--target-sigma", "0.5,10", "--out", str(out), "--no-report"]
    assert main([*args, "--jobs", "1"]) == 0
    assert (out / "calibration.yaml").is_file() and (out / "config.resolved.yaml").is_file()
    updates = yaml.safe_load((out / "incremental.yaml").read_text())["updates"]
    assert updates[-1]["frame"] == "(final)" and "sigma" in updates[-1]


def test_refined_board_poses_are_kept(observed) -> None:
    cal = solve_observations([observed]).calibration
    for f in cal.frames:
        if f.used:
            d = np.linalg.inv(f.board.T_lidar_board) @ f.T_lidar_board_refined
            assert np.linalg.norm(d[:3, 3]) < 0.05 and f.T_lidar_board_refined is not None
    moved = [
        f for f in cal.frames if f.used and not np.allclose(f.T_lidar_board_refined, f.board.T_lidar_board)
    ]
    assert moved  # the graph refines the boards, and the output keeps that


def test_second_pass_finds_a_missed_board_where_the_image_puts_it(observed) -> None:
    import dataclasses

    lost = observed.frames[2]
    assert lost.board is not None
    missed = dataclasses.replace(lost, board=None, used=False, reason="LiDAR: no segment passed the tests")
    frames = [missed if f.name == lost.name else f for f in observed.frames]
    obs = dataclasses.replace(observed, frames=frames)
    without = solve_observations([obs], RunOptions(second_pass=False)).calibration
    assert not next(f for f in without.frames if f.name == lost.name).used
    res = solve_observations([obs])
    again = next(f for f in res.calibration.frames if f.name == lost.name)
    assert again.used and again.board.diagnostics["found_near_prediction"] == 1.0
    d = np.linalg.inv(lost.board.T_lidar_board) @ again.board.T_lidar_board
    assert np.linalg.norm(d[:3, 3]) < 0.01  # the same board pose as the first search found


def test_frames_without_their_source_are_not_read_again(observed) -> None:
    """An observation without its source (``Observation(None, ...)``, as ``pipeline.solve_observed``
    makes): it solves as it is; the second look, the boards on corrected ranges and the set-up
    mistakes' checks, which read a pair's frames again, leave it be (``Observation.pair_source``)."""
    import dataclasses

    from ilcc_graph.run.range_refit import refit_pass
    from ilcc_graph.run.second_look import second_pass
    from ilcc_graph.run.setup_mistakes import diagnose_failure, diagnose_result

    lost = observed.frames[2]
    missed = dataclasses.replace(lost, board=None, used=False, reason="LiDAR: no segment passed the tests")
    frames = [missed if f.name == lost.name else f for f in observed.frames]
    obs = dataclasses.replace(observed, source=None, frames=frames)
    assert obs.pair_source is None and obs.rig_source is None and obs.location == ""
    res = solve_observations([obs])  # named session1: no source, no label
    assert res.sessions[0].name == "session1"
    assert not next(f for f in res.calibration.frames if f.name == lost.name).used
    stages = RunOptions().stages
    assert second_pass(obs, res.calibration, stages) is None
    assert refit_pass(obs, res.calibration, stages) is None
    assert diagnose_failure([obs], stages) == [] and diagnose_result(obs, res.calibration) == []


def test_a_new_strategy_is_one_registration(observed, tmp_path, monkeypatch) -> None:
    """A strategy registered under a new mode runs through solve_observations and the one writer:
    its further poses and documents (plain data) are written, the mode is recorded, and the paper's
    refinement gives no covariance (None) while its file keeps the NaN convention."""
    import dataclasses

    from ilcc_graph.run import strategies
    from ilcc_graph.run.result import Result
    from ilcc_graph.run.strategies import Strategy, choose, solve_graph

    def two_sensors(observations, options, report=None) -> Result:  # e.g. a rig: the graph's pair, one more
        res = solve_graph.solve(observations, dataclasses.replace(options, mode="graph"), report)
        pose = res.calibration.extrinsic
        doc = {"sensors": {"camera": {"T_ref_sensor": pose.T}, "camera2": {"T_ref_sensor": np.eye(4)}}}
        return dataclasses.replace(
            res, mode="two", options=options, documents={"rig.yaml": doc}, poses={"camera": pose}
        )

    monkeypatch.setitem(strategies._REGISTRY, "two", Strategy("two", two_sensors))
    assert "two" in strategies.modes() and choose(RunOptions(mode="two"), 1).mode == "two"
    with pytest.raises(ValueError, match="calibrates one data set"):
        choose(RunOptions(mode="two"), 2)  # no joint strategy named for it
    res = solve_observations([observed], RunOptions(mode="two", second_pass=False))
    assert res.mode == "two" and res.covariance is not None and "camera" in res.poses
    out = write_run(tmp_path / "two", res, report=False)
    rig = yaml.safe_load((out / "rig.yaml").read_text())
    assert np.allclose(rig["sensors"]["camera"]["T_ref_sensor"], res.calibration.T_cam_lidar)
    assert yaml.safe_load((out / "config.resolved.yaml").read_text())["options"]["mode"] == "two"
    paper = solve_observations([observed], RunOptions(mode="paper"))
    assert paper.covariance is None and np.all(np.isnan(paper.calibration.covariance))
    with pytest.raises(ValueError, match="must be one of"):
        RunOptions(mode="nope")


def test_the_writer_and_the_report_read_only_the_result() -> None:
    """app/write.py and report/ import no strategy's own types (BatchSolution, JointSolution,
    FrameUpdate) and no strategy module: they read ``run.result.Result``."""
    import ast

    root = Path(__file__).resolve().parents[1] / "ilcc_graph"
    banned = ("batch", "sessions", "incremental")
    wrong = []
    for path in [root / "app" / "write.py", *sorted((root / "report").glob("*.py"))]:
        package = ["ilcc_graph", path.parent.name]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                base = package[: len(package) - node.level + 1] if node.level else []
                name = ".".join([*base, *([node.module] if node.module else [])])
                if name in [f"ilcc_graph.estimation.{b}" for b in banned] or name.startswith(
                    "ilcc_graph.run.strat"
                ):
                    wrong.append(f"{path.name}: {name}")
    assert not wrong, wrong
