"""Calibrations whose LiDAR shows no print (issue 20): a print the LiDAR cannot see, an intensity field
of zeros or of ring numbers, no ring field, and boards partly above the top beam, each simulated and
calibrated the way a user runs it (the command line for one), checked against the truth with the
run's own covariance."""

from __future__ import annotations

import logging
from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.board import Board
from ilcc_graph.datasets import open_source
from ilcc_graph.io import read_ground_truth
from ilcc_graph.lidar._synthetic import SynthScene, board_pose
from ilcc_graph.report.text import lidar_view_lines
from ilcc_graph.run.pipeline import run
from ilcc_graph.simulate import RenderOptions, board_placements, simulate_dataset, standard_spec
from ilcc_graph.types import Calibration

CHI2_6_999 = 22.46
BOARD = Board(6, 8, 0.075, 0.045, 0.02)


def _spec(frames: int = 8, seed: int = 5, board: Board = BOARD, **kw):  # noqa: ANN003, ANN202
    return standard_spec(
        "vlp16", "pinhole", width=640, frames=frames, seed=seed, board=board,
        image=RenderOptions(supersample=1), **kw,
    )  # fmt: skip


def _extrinsic_error(T_est: np.ndarray, cov: np.ndarray, T_true: np.ndarray) -> tuple[float, float, float]:
    """(rotation deg, translation mm, NEES) of an estimate against the truth."""
    xi = np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(T_est).between(gtsam.Pose3(T_true))))
    return (
        float(np.degrees(np.linalg.norm(xi[:3]))),
        float(1e3 * np.linalg.norm(xi[3:])),
        float(xi @ np.linalg.solve(cov, xi)),
    )


def _boards_trustworthy(cal: Calibration, board: Board) -> None:
    """Every board a frame has: a finite, positive covariance that fixes it in its plane within a square."""
    for f in cal.frames:
        if f.board is None:
            continue
        C = f.board.covariance
        assert np.all(np.isfinite(C)) and np.linalg.eigvalsh(C).min() > 0, f.name
        assert 2.0 * np.sqrt(np.linalg.eigvalsh(C[3:5, 3:5]).max()) < board.square_size, f.name


@pytest.mark.parametrize("field", ["invisible", "none"], ids=["print-invisible", "no-intensity-field"])
def test_print_invisible_through_the_command_line(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, field: str
) -> None:
    """A print the LiDAR cannot see, and scans with no intensity field at all (x y z and ring, as
    Open3D's legacy clouds or MATLAB's ``pcwrite`` of a cloud without Intensity write them)."""
    data = simulate_dataset(tmp_path / "data", _spec(intensity_field=field))
    header = next((data / "pcd").iterdir()).read_bytes()[:400]
    assert (b"intensity" in header) == (field != "none"), header
    out = tmp_path / "out"
    with caplog.at_level(logging.WARNING, logger="ilcc_graph"):
        assert main(["calibrate", str(data), "--out", str(out), "--no-report", "--jobs", "1"]) == 0
    said = [
        r.getMessage() for r in caplog.records if "show no print in the LiDAR intensity" in r.getMessage()
    ]
    assert len(said) == 1, said  # once for the run, not per frame
    assert ("the scans have no intensity field" in said[0]) == (field == "none"), said
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    used = sum(f["used"] for f in cal["frames"])
    assert used >= 7
    assert cal["diagnostics"]["lidar_boards_no_print"] == used
    resolved = yaml.safe_load((out / "config.resolved.yaml").read_text())
    assert resolved["options"]["lidar_errors"] is not None  # the beams' offsets estimated without a print
    truth = read_ground_truth(data).T_cam_lidar
    rot, trans, nees = _extrinsic_error(np.array(cal["T_cam_lidar"]), np.array(cal["covariance"]), truth)
    assert rot < 0.3 and trans < 10.0 and nees < CHI2_6_999, (rot, trans, nees)


@pytest.mark.parametrize(
    "field, ring_field, board",
    [
        (
            "zero",
            True,
            Board(6, 7, 0.08, 0.04, 0.04),
        ),  # no half-turn symmetry: each frame's order from the image
        ("ring", True, BOARD),
        ("invisible", False, BOARD),
    ],
    ids=["zeros-odd-board", "ring-number", "no-ring-field"],
)
def test_intensity_fields_without_a_print(tmp_path: Path, field: str, ring_field: bool, board: Board) -> None:
    spec = _spec(board=board, intensity_field=field, ring_field=ring_field)
    data = simulate_dataset(tmp_path / "data", spec)
    cal = run([open_source(data)]).calibration
    used = [f for f in cal.frames if f.used]
    assert len(used) >= 7, [f.reason for f in cal.frames if not f.used]
    assert all(f.board.diagnostics["no_contrast"] == 1.0 for f in used)
    assert all(f.board.returns is not None and np.all(f.board.returns.dark == 0.0) for f in used)
    _boards_trustworthy(cal, board)
    rot, trans, nees = _extrinsic_error(cal.T_cam_lidar, cal.covariance, np.asarray(spec.T_cam_lidar))
    assert rot < 0.3 and trans < 10.0 and nees < CHI2_6_999, (rot, trans, nees)


def test_boards_partly_above_the_top_beam(tmp_path: Path) -> None:
    """Six boards 1.2-2.6 m away and two 0.9 m away whose top 1.5 squares lie above a VLP-16's top
    beam: every board used (none dropped for its corner order), the near ones said to leave the field
    of view, the result within its covariance."""
    board = Board(6, 7, 0.08, 0.03, 0.03)
    base = _spec(frames=6, seed=7, board=board)
    x0, x1, y0, y1 = board.extent()
    top = 0.9 * np.tan(np.deg2rad(15.0)) + 0.12
    el = float(np.degrees(np.arctan2(top - 0.5 * (y1 - y0), 0.9)))
    near = [board_pose(board, SynthScene(distance=0.9, elevation_deg=el, azimuth_deg=a, in_plane_deg=r))
            for a, r in ((8.0, 0.0), (-6.0, 180.0))]  # fmt: skip
    spec = base.with_(placements=(*board_placements(base), *near), intensity_field="invisible")
    data = simulate_dataset(tmp_path / "data", spec)
    cal = run([open_source(data)]).calibration
    assert [f.name for f in cal.frames if not f.used] == [], [f.reason for f in cal.frames]
    beyond = [f.name for f in cal.frames if f.board.diagnostics["outside_fov_share"] > 0.05]
    assert beyond == ["0007", "0008"]
    assert any(
        "beyond the LiDAR's field of view" in line and "0007" in line for line in lidar_view_lines(cal)
    )
    assert cal.diagnostics["lidar_boards_beyond_fov"] == 2
    _boards_trustworthy(cal, board)
    rot, trans, nees = _extrinsic_error(cal.T_cam_lidar, cal.covariance, np.asarray(spec.T_cam_lidar))
    assert rot < 0.3 and trans < 10.0 and nees < CHI2_6_999, (rot, trans, nees)


def test_simulate_writes_scans_without_intensity_or_ring(tmp_path: Path) -> None:
    """``ilcc-graph simulate --intensity-field none --no-ring-field`` writes x y z alone, as a folder
    and as a bag; the readers take them as scans without intensity or ring."""
    from ilcc_graph.io import read_scan

    common = ["--lidar", "vlp16", "--camera", "pinhole", "--width", "320", "--frames", "2"]
    flags = ["--intensity-field", "none", "--no-ring-field"]
    assert main(["simulate", str(tmp_path / "set"), *common, *flags]) == 0
    pcd = sorted((tmp_path / "set" / "pcd").iterdir())[0]
    assert b"FIELDS x y z\n" in pcd.read_bytes()[:300]
    scan = read_scan(pcd)
    assert not scan.has_intensity and scan.ring is None
    assert main(["simulate", str(tmp_path / "run.bag"), *common, *flags, "--bag"]) == 0
    src = open_source(tmp_path / "run.bag")
    scan = src.read_scan(src.frames()[0], src.config())
    assert not scan.has_intensity and scan.ring is None
    assert main(["simulate", str(tmp_path / "ring"), *common, "--intensity-field", "ring"]) == 0
    scan = read_scan(sorted((tmp_path / "ring" / "pcd").iterdir())[0])
    assert scan.has_intensity and np.array_equal(scan.intensity, scan.ring)


def test_the_warning_says_which_boards_show_a_print_that_cannot_be_read() -> None:
    """A board placed by its outline because its print could not be read (``print_unreadable``) is
    not said to show "no black/white contrast" in the run's one warning about such boards."""
    from ilcc_graph.run.stages import warn_no_print
    from ilcc_graph.types import BoardFit

    def fit(**diag: float) -> BoardFit:
        return BoardFit(np.eye(4), np.eye(6), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), True,
                        diagnostics=dict(diag))  # fmt: skip

    printed, plain, unread = fit(), fit(no_contrast=1.0), fit(no_contrast=1.0, print_unreadable=1.0)
    one = warn_no_print([printed, unread], "config.yaml")
    assert one is not None and "1 of 2 boards" in one and "no black/white contrast" not in one
    assert "too few returns lie clear of its squares' edges to read" in one, one
    both = warn_no_print([plain, unread], "config.yaml")
    assert both is not None and "no black/white contrast on the board; in 1 a print shows, but" in both, both
    assert warn_no_print([printed], "config.yaml") is None
