"""The boards fitted again on ranges corrected by the LiDAR's estimated errors (``run.range_refit``):
the correction itself, the stage on corrected ranges, when it is worth it, and the command line."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml
from scipy.spatial import cKDTree

from ilcc_graph.app import main
from ilcc_graph.estimation.selection import AUTO, MODELS, candidates
from ilcc_graph.lidar import estimate_board
from ilcc_graph.lidar.stretch import REFIT_RATIO, correction_of, largest_stretch, significant
from ilcc_graph.simulate import Systematics, board_placements, frame_scene, simulate_scan, standard_spec
from ilcc_graph.types import FrameResult, RangeCorrection


def test_a_correction_moves_each_return_along_its_ray_and_back() -> None:
    rng = np.random.default_rng(0)
    P = rng.normal(size=(50, 3)) * 3.0
    ring = rng.integers(0, 4, 50)
    c = RangeCorrection(0.02, ((1, -0.005), (3, 0.010)), 1e-3)
    rho = np.linalg.norm(P, axis=1)
    expected = 0.02 + np.select([ring == 1, ring == 3], [-0.005, 0.010], 0.0) + 1e-3 * rho
    np.testing.assert_allclose(c.along_ray(ring, rho), expected)
    Q = c.corrected(P, ring)
    np.testing.assert_allclose(np.linalg.norm(Q, axis=1), rho - expected, atol=1e-12)
    np.testing.assert_allclose(np.cross(P, Q), 0.0, atol=1e-12)  # along the ray
    # undone exactly by the offsets; the scale term reads the range it is given: to first order
    c0 = replace(c, scale=0.0)
    np.testing.assert_allclose(c0.corrected(c0.corrected(P, ring), ring, sign=-1.0), P, atol=1e-12)
    np.testing.assert_allclose(c.corrected(Q, ring, sign=-1.0), P, atol=1e-4)


def test_the_correction_is_read_from_the_calibrations_sensor_terms() -> None:
    le = {"names": ["offset[2]", "offset[5]", "dark", "scale"], "values": [0.01, -0.02, 0.004, 1e-4]}
    c = correction_of({"lidar_errors": le})
    assert c == RangeCorrection(0.0, ((2, 0.01), (5, -0.02)), 1e-4)  # the dark print's left out
    assert correction_of({"lidar_errors": {"names": ["offset", "dark"], "values": [0.02, 0.004]}}) == (
        RangeCorrection(0.02)
    )
    assert correction_of({"lidar_errors": {"names": ["dark"], "values": [0.004]}}) is None
    assert correction_of({}) is None


@pytest.fixture(scope="module")
def scans():  # noqa: ANN201 - (spec, the same returns without and with a 20 mm range offset)
    spec = standard_spec("hdl32", "pinhole", width=800, frames=3, seed=4, systematics=Systematics.off())
    T = board_placements(spec)[0]
    scene = frame_scene(spec, T, 0)
    clean = simulate_scan(spec, scene, 0)
    long = simulate_scan(spec.with_(systematics=replace(Systematics.off(), range_offset_m=0.02)), scene, 0)
    return spec, clean, long


def test_the_stage_on_corrected_ranges_is_the_stage_on_the_true_ranges(scans) -> None:
    """Returns 20 mm long, corrected by 20 mm: the same board pose as the scan without the offset,
    while the fit's returns stay the measured (long) ones."""
    spec, clean, long = scans
    lengthened = np.linalg.norm(long.points, axis=1) - np.linalg.norm(clean.points, axis=1)
    np.testing.assert_allclose(lengthened, 0.02, atol=1e-6)
    truth = estimate_board(clean, spec.board, spec.lidar_model)
    first = estimate_board(long, spec.board, spec.lidar_model)
    again = estimate_board(long, spec.board, spec.lidar_model, correction=RangeCorrection(0.02))
    # the same up to the float32 points' rounding, which the fit's search carries on (0.02 mm)
    assert _sigmas_apart(again, truth) < 0.2
    assert _sigmas_apart(first, truth) > 5.0  # its plane 20 mm too far
    sigmas = (np.sqrt(np.diag(fit.covariance)) for fit in (again, truth))
    np.testing.assert_allclose(*sigmas, rtol=0.05)
    for pts in (again.points_lidar, again.returns.points):  # the measured returns, not the corrected
        gap = cKDTree(long.points).query(pts)[0]
        assert gap.max() < 1e-6 and len(pts) > 100
    assert again.diagnostics["range_correction_mm"] == pytest.approx(20.0)


def _sigmas_apart(fit, ref) -> float:  # noqa: ANN001 - BoardFit
    """Mahalanobis distance of ``fit``'s pose from ``ref``'s under ``ref``'s covariance."""
    xi = np.asarray(gtsam.Pose3(ref.T_lidar_board).localCoordinates(gtsam.Pose3(fit.T_lidar_board)))
    return float(np.sqrt(xi @ np.linalg.solve(ref.covariance, xi)))


def test_a_large_offset_is_worth_a_refit_and_a_small_one_is_not(scans) -> None:
    spec, clean, _ = scans
    fit = estimate_board(clean, spec.board, spec.lidar_model)
    frames = [FrameResult("0001", True, board=fit)]
    big = largest_stretch(frames, RangeCorrection(0.02), spec.board)
    small = largest_stretch(frames, RangeCorrection(0.0005), spec.board)
    assert big == pytest.approx(40.0 * small, rel=1e-9)  # proportional to the offset
    assert significant(frames, RangeCorrection(0.02), spec.board) and big > REFIT_RATIO
    assert not significant(frames, RangeCorrection(0.0005), spec.board)
    assert not significant([replace(frames[0], used=False)], RangeCorrection(0.02), spec.board)
    assert not significant(frames, None, spec.board)


def test_boards_on_corrected_ranges_leave_the_model_without_range_terms_out() -> None:
    """Their poses rest on the estimated correction: ``none`` would take them as measured."""
    auto = [MODELS[n] for n in AUTO]
    assert [m.name for m in candidates(auto, True)] == ["range", "beams"]
    assert [m.name for m in candidates(auto, False)] == list(AUTO)
    assert [m.name for m in candidates([MODELS["none"]], True)] == ["none"]  # forced: as asked
    assert [m.name for m in candidates([MODELS["none"], MODELS["offset"]], True)] == ["offset"]


@pytest.fixture(scope="module")
def long_set(tmp_path_factory) -> Path:
    """Seven small pinhole frames of a HDL-32E reading 20 mm long (besides its per-beam offsets)."""
    out = tmp_path_factory.mktemp("refit") / "data"
    args = ["simulate", str(out), "--lidar", "hdl32", "--camera", "pinhole", "--width", "800",
            "--frames", "7", "--seed", "5", "--range-offset-mm", "20"]  # fmt: skip
    assert main(args) == 0
    return out


def test_calibrate_fits_the_boards_again_and_says_so(long_set: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    assert main(["calibrate", str(long_set), "--out", str(out), "--no-report", "--jobs", "1"]) == 0
    text = capsys.readouterr().out
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    used = sum(f["used"] for f in cal["frames"])
    d = cal["diagnostics"]
    assert d["lidar_boards_on_corrected_ranges"] == used >= 5
    assert 15.0 < d["lidar_range_correction_mm"] < 25.0
    assert f"{used} boards fitted again on their ranges corrected" in " ".join(text.split())
    model = cal["sensor_errors"]["model"]
    assert model["chosen"] in ("range", "beams") and "none" not in {c["name"] for c in model["candidates"]}
    # within its stated covariance of the simulator's truth
    truth = yaml.safe_load((long_set / "ground_truth.yaml").read_text())
    T_true = np.asarray(truth["T_cam_lidar"], dtype=np.float64)
    xi = np.asarray(gtsam.Pose3(np.asarray(cal["T_cam_lidar"])).localCoordinates(gtsam.Pose3(T_true)))
    assert float(xi @ np.linalg.solve(np.asarray(cal["covariance"]), xi)) < 22.46  # chi-square 6, 99.9 %
