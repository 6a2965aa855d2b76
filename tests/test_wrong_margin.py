"""A board whose white margin is wider than config.yaml says (issue 38, item 4: a print taped to a
larger panel; users seldom know their margin to the centimetre): the LiDAR's board search allows a
board up to ``LidarOptions.margin_tolerance_m`` larger per side, so the boards are found and placed
by their print. Before, a margin 100 mm narrower than the board's lost most boards to the count test
("count_ratio ... 1.32 > 1.15"), here 6 of 6 scans; through the command line as a user meets it. Where
the print shows, the stage measures the margin from the board's outline (lidar/margin.py): the run
reports the measured one once (a warning, calibration.yaml's ``lidar_margin_*``, the summary) and the
outline checks the print's fit as the board measured, so the result stays within its covariance."""

from __future__ import annotations

import logging
import re
from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml
from scipy.stats import chi2

from ilcc_graph.app import main
from ilcc_graph.board import Board
from ilcc_graph.cameras.pinhole import Pinhole
from ilcc_graph.errors import BoardNotFound
from ilcc_graph.io import read_calibration, read_scan
from ilcc_graph.lidar import LidarOptions, estimate_board
from ilcc_graph.lidar.detection import find_candidates
from ilcc_graph.lidars import beam_index
from ilcc_graph.simulate import SceneOptions, SimulationSpec, simulate_dataset, simulate_frames

REAL = Board(7, 9, 0.1, 0.17, 0.17)  # the panel: 170 mm of white around the print
SAID = 0.07  # what config.yaml says
TOL_MM = 15.0  # the measured margin's tolerance against the truth (mm)


@pytest.fixture(scope="module")
def wide(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SimulationSpec]:
    """A VLP-16 + pinhole set on the wide-margin board, config.yaml naming a 70 mm margin."""
    K = np.array([[480.0, 0.0, 319.5], [0.0, 480.0, 239.5], [0.0, 0.0, 1.0]])
    spec = SimulationSpec(
        lidar="vlp16", camera=Pinhole(640, 480, K, np.zeros(4)), board=REAL, n_frames=6, seed=4,
        scene=SceneOptions(board_distance_m=(2.0, 3.5)),
    )  # fmt: skip
    data = tmp_path_factory.mktemp("wide") / "set"
    simulate_dataset(data, spec)
    cfg = yaml.safe_load((data / "config.yaml").read_text(encoding="utf-8"))
    cfg["board"]["margin"] = SAID
    (data / "config.yaml").write_text(yaml.safe_dump(cfg), encoding="utf-8")
    return data, spec


def test_the_search_finds_boards_wider_than_configured_within_the_tolerance(wide) -> None:  # noqa: ANN001
    data, spec = wide
    said = Board(7, 9, 0.1, SAID, SAID)
    strict = LidarOptions(margin_tolerance_m=0.0)
    found = refused = 0
    truth = yaml.safe_load((data / "ground_truth.yaml").read_text(encoding="utf-8"))["T_lidar_board"]
    for p in sorted((data / "pcd").iterdir()):
        scan = read_scan(p)
        estimate_board(scan, said, spec.lidar_model)  # found with the default tolerance
        found += 1
        try:
            estimate_board(scan, said, spec.lidar_model, options=strict)
        except BoardNotFound as err:
            refused += 1
            if "count_ratio" in str(err) or "size_ratio" in str(err):
                # the board's own refusal comes first, not a room's it merged with (at its mean point's
                # range, under a metre)
                first = re.search(r"largest: \w+: .*? at (\d+\.\d+) m", str(err))
                assert first is not None and float(first.group(1)) > 1.5, err
                continue
            # another board-shaped object was the candidate, refused by its fit (a piece of the room
            # the search now splits): the board itself was not among the search's candidates
            T = np.asarray(truth[p.stem])
            centre = T[:3, :3] @ said.corners_board().mean(axis=0) + T[:3, 3]
            ring = beam_index(scan, spec.lidar_model)
            cands = find_candidates(scan.points, ring, scan.intensity, said, spec.lidar_model, options=strict)
            near = [np.linalg.norm(scan.points[c.indices].mean(axis=0) - centre) < 0.3 for c in cands]
            assert not any(near), err
    assert found == 6 and refused >= 4, (found, refused)


def test_calibrate_measures_the_margin_and_reports_it_once(
    wide, tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture  # noqa: ANN001
) -> None:
    """Through the command line: every frame used, the margin the LiDAR measured (truth 170 mm) reported
    once as a warning, in calibration.yaml and in the summary, and the result within its covariance."""
    data, spec = wide
    out = tmp_path / "out"
    with caplog.at_level(logging.WARNING, logger="ilcc_graph"):
        assert main(["calibrate", str(data), "--out", str(out), "--no-report", "--jobs", "1"]) == 0
    warned = [r.getMessage() for r in caplog.records if "margin the LiDAR measured" in r.getMessage()]
    assert len(warned) == 1, warned
    cal = read_calibration(out / "calibration.yaml")
    assert sum(f.used for f in cal.frames) == 6, [f.reason for f in cal.frames]
    for axis in ("long", "short"):  # within 15 mm of the board's 170 mm; config.yaml said 70
        got = cal.diagnostics[f"lidar_margin_{axis}_mm"]
        assert abs(got - 1e3 * REAL.margin_long) < TOL_MM, cal.diagnostics
        assert f"{got:.0f} mm" in warned[0]
    assert "margin the LiDAR measured" in " ".join(capsys.readouterr().out.split())
    T = np.asarray(spec.T_cam_lidar)
    xi = np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(cal.T_cam_lidar).between(gtsam.Pose3(T))))
    nees = float(xi @ np.linalg.solve(cal.covariance, xi))
    assert nees < chi2.ppf(0.999, 6), nees
    assert np.linalg.norm(cal.T_cam_lidar[:3, 3] - T[:3, 3]) < 0.01


def test_a_right_margin_is_not_reported(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The LiDAR stage's margin on a board whose config.yaml margin is right: measured, not contradicted."""
    K = np.array([[480.0, 0.0, 319.5], [0.0, 480.0, 239.5], [0.0, 0.0, 1.0]])
    spec = SimulationSpec(
        lidar="vlp16", camera=Pinhole(640, 480, K, np.zeros(4)), board=REAL, n_frames=3, seed=4,
        scene=SceneOptions(board_distance_m=(2.0, 3.5)),
    )  # fmt: skip
    measured = []
    for f in simulate_frames(spec):
        d = estimate_board(f.scan, REAL, spec.lidar_model).diagnostics
        assert d["margin_contradicted"] == 0.0, d
        measured += [d[k] for k in ("margin_long_mm", "margin_short_mm") if k in d]
    assert measured and all(abs(m - 170.0) < TOL_MM for m in measured), measured


def test_check_and_a_rig_of_two_report_the_measured_margin_as_calibrate_does(
    wide, tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture  # noqa: ANN001
) -> None:
    """The same recording through two more doors (issue 34: a fix reaches every door): ``check`` says
    the measured margin in its closing lines; the pair given as a rig.yaml of its two sensors warns
    once naming the LiDAR, says it in its summary and keeps it in its calibration.yaml."""
    data, _ = wide
    assert main(["check", str(data), "--out", str(tmp_path / "check")]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert "margin the LiDAR measured is 17" in said and "in config.yaml" in said, said[-1500:]
    cfg = yaml.safe_load((data / "config.yaml").read_text(encoding="utf-8"))
    rig_dir = tmp_path / "rig"
    rig_dir.mkdir()
    (rig_dir / "lidar").symlink_to((data / "pcd").resolve())
    (rig_dir / "camera").symlink_to((data / "img").resolve())
    rig = {"reference": "lidar", "board": cfg["board"],
           "sensors": {"lidar": {"lidar": cfg["lidar"]}, "camera": {"camera": cfg["camera"]}}}  # fmt: skip
    (rig_dir / "rig.yaml").write_text(yaml.safe_dump(rig), encoding="utf-8")
    out = tmp_path / "rig_out"
    with caplog.at_level(logging.WARNING, logger="ilcc_graph"):
        assert main(["calibrate", str(rig_dir), "--out", str(out), "--no-report", "--jobs", "1"]) == 0
    warned = [r.getMessage() for r in caplog.records if "margin the LiDAR measured" in r.getMessage()]
    assert len(warned) == 1 and "(lidar)" in warned[0] and "in rig.yaml" in warned[0], warned
    assert "lidar: the board's white margin the LiDAR measured" in " ".join(capsys.readouterr().out.split())
    margins = yaml.safe_load((out / "calibration.yaml").read_text(encoding="utf-8"))["lidar_margin"]["lidar"]
    for axis in ("long", "short"):
        assert abs(margins[f"lidar_margin_{axis}_mm"] - 1e3 * REAL.margin_long) < TOL_MM, margins


def test_the_margin_warning_in_an_80_column_terminal(wide, tmp_path: Path) -> None:  # noqa: ANN001
    """In a real terminal (tmux, 80 columns) the run's warnings wrap as the rest of its output does:
    no line wider than the window (a log line was one line of 350 characters, broken mid-word)."""
    import shlex
    import shutil
    import sys

    from test_summary import _tmux

    if shutil.which("tmux") is None:
        pytest.skip("tmux is not installed (apt-get install tmux): the terminal is not checked")
    data, _ = wide
    argv = [sys.executable, "-m", "ilcc_graph.app", "calibrate", str(data), "--out", "out", "--no-report"]
    lines = _tmux(tmp_path, " ".join(shlex.quote(a) for a in argv))
    assert all(len(line) <= 80 for line in lines), max(lines, key=len)
    text = " ".join(" ".join(lines).split())
    assert "WARNING: " in text and "the board's white margin the LiDAR measured is 17" in text, text[:2000]
