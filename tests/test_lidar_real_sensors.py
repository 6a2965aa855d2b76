"""The LiDAR stage on real-sensor-like input: any intensity unit, candidates chosen by the fit,
the expected-board hint, simulated Ouster / Velodyne-CSV data sets, recorded Ouster and VLP-16 sets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from ilcc_graph.board import Board
from ilcc_graph.config import load_config
from ilcc_graph.datasets import FolderSource
from ilcc_graph.errors import BoardNotFound
from ilcc_graph.io import read_scan
from ilcc_graph.lidar import ExpectedBoard, estimate_board
from ilcc_graph.lidar._synthetic import SynthScene, synth_scan
from ilcc_graph.lidar.detection import find_candidates
from ilcc_graph.lidars import lidar_model
from ilcc_graph.run.pipeline import run
from ilcc_graph.run.source import resolve_lidar
from ilcc_graph.simulate import SimulationSpec, Systematics, default_camera, simulate_dataset
from ilcc_graph.types import Scan


def find_board(points, ring, intensity, board, model):  # noqa: ANN001, ANN201
    """The most uniform of the candidates that pass the chessboard tests."""
    return max(find_candidates(points, ring, intensity, board, model), key=lambda c: c.uniformity)


BOARD = Board(6, 8, 0.075)
HDL32 = lidar_model("hdl32")


def _corner_error(fit, T: np.ndarray, board: Board) -> float:
    truth = board.corners_board() @ T[:3, :3].T + T[:3, 3]
    errs = [np.sqrt(((fit.corners_lidar[p] - truth) ** 2).sum(axis=1).mean()) for p in
            (np.arange(len(truth)), board.half_turn_permutation())]  # fmt: skip
    return float(min(errs))


def test_intensity_in_any_unit_gives_the_same_board() -> None:
    scan, T = synth_scan(
        BOARD, HDL32, SynthScene(distance=3.0, tilt_deg=(20.0, 5.0), stand=True), np.random.default_rng(4)
    )
    r = np.linalg.norm(scan.points, axis=1)
    raw = scan.intensity / 60.0 * 6000.0 * np.minimum(1.0, (2.0 / r) ** 2)  # Ouster-like raw signal
    raw = raw + (2 * np.sqrt(raw) + 5) * np.random.default_rng(1).standard_normal(len(r))
    units = {"x0.01": scan.intensity * 0.01, "x80+500": 80.0 * scan.intensity + 500.0, "ouster raw": raw}
    ref = estimate_board(scan, BOARD, HDL32)
    assert _corner_error(ref, T, BOARD) < 0.005
    for name, inten in units.items():
        fit = estimate_board(Scan(scan.points, inten, scan.ring), BOARD, HDL32)
        assert np.abs(fit.corners_lidar - ref.corners_lidar).max() < 0.003, name
        if name != "ouster raw":  # a gain and offset change nothing (the raw model has its own noise)
            assert fit.points_lidar.shape == ref.points_lidar.shape, name


def test_a_two_tone_board_sized_panel_does_not_beat_the_chessboard() -> None:
    sc = SynthScene(
        distance=3.0, tilt_deg=(25.0, 0.0), in_plane_deg=30, decoy_azimuth_deg=25.0, azimuth_window_deg=80
    )
    scan, T = synth_scan(BOARD, HDL32, sc, np.random.default_rng(3))
    # the panel passes the paper's tests (and the contrast test) as well as the board
    cands = []
    find_candidates(
        scan.points, scan.ring, scan.intensity, BOARD, HDL32, accept=lambda c: cands.extend(c) and False
    )
    az = [np.degrees(np.arctan2(*scan.points[c.indices].mean(axis=0)[[1, 0]])) for c in cands]
    assert any(a > 15 for a in az) and any(abs(a) < 5 for a in az)
    fit = estimate_board(scan, BOARD, HDL32)
    assert fit.diagnostics["candidates_passed"] >= 2
    assert _corner_error(fit, T, BOARD) < 0.005


def test_half_turn_symmetric_board_comes_back_with_its_y_axis_up() -> None:
    scan, T = synth_scan(BOARD, HDL32, SynthScene(distance=2.5, in_plane_deg=170.0), np.random.default_rng(2))
    fit = estimate_board(scan, BOARD, HDL32)
    assert fit.T_lidar_board[2, 1] >= 0 and _corner_error(fit, T, BOARD) < 0.005
    assert np.all(np.linalg.eigvalsh(fit.covariance) > 0)


def test_expected_board_restricts_the_search_and_is_checked() -> None:
    sc = SynthScene(
        distance=3.0, tilt_deg=(25.0, 0.0), in_plane_deg=30, decoy_azimuth_deg=25.0, azimuth_window_deg=80
    )
    scan, T = synth_scan(BOARD, HDL32, sc, np.random.default_rng(3))
    rough = T.copy()
    rough[:3, 3] += [0.1, -0.08, 0.05]  # a prediction some cm off
    fit = estimate_board(scan, BOARD, HDL32, expected=ExpectedBoard(rough, 0.3, 20.0))
    assert _corner_error(fit, T, BOARD) < 0.005
    # predicted where the panel is: only the panel is searched, and it is no chessboard
    Td = T.copy()
    Td[:3, 3] = scan.points[find_board(scan.points, scan.ring, scan.intensity, BOARD, HDL32).indices].mean(
        axis=0
    )
    with pytest.raises(BoardNotFound):
        estimate_board(scan, BOARD, HDL32, expected=ExpectedBoard(Td, 0.2, 30.0))


def _small_spec(lidar: str, fmt: str, frames: int, **kw) -> SimulationSpec:
    return SimulationSpec(
        lidar=lidar, camera=default_camera("pinhole", 640), n_frames=frames, seed=2, sensor_format=fmt, **kw
    )


OS1_2048 = lidar_model("os1-64-rev6", horizontal_resolution_deg=360 / 2048)


@pytest.mark.parametrize(
    ("lidar", "fmt", "frames"),
    [
        ("hdl32", "velodyne-csv", 20),
        ("vlp16", "velodyne-csv", 4),
        ("os1-64-rev6", "ouster", 4),
        (OS1_2048, "ouster", 2),
    ],
)
def test_simulated_real_sensor_sets_give_the_board_in_every_frame(
    tmp_path: Path, lidar: str, fmt: str, frames: int
) -> None:
    data = simulate_dataset(tmp_path / "d", _small_spec(lidar, fmt, frames))
    gt = yaml.safe_load((data / "ground_truth.yaml").read_text())
    config = load_config(data / "config.yaml")
    src = FolderSource(data)
    paths = src.frames()
    config = resolve_lidar(src, paths, config)
    for p in paths:
        scan = read_scan(p.scan)
        if fmt == "ouster":
            assert scan.columns == round(360 / config.lidar.horizontal_resolution_deg)
            assert scan.columns in (1024, 2048) and scan.intensity.max() > 300  # raw signal, not 0-255
        else:
            assert p.scan.suffix == ".csv" and scan.ring is not None
        fit = estimate_board(scan, config.board, config.lidar, config.roi)
        assert _corner_error(fit, np.array(gt["T_lidar_board"][p.name]), config.board) < 0.01, p.name


def test_calibrate_on_a_small_ouster_like_set_gives_the_truth(tmp_path: Path) -> None:
    import gtsam

    data = simulate_dataset(
        tmp_path / "os", _small_spec("os1-64-rev6", "ouster", 6, systematics=Systematics.off())
    )
    (data / "config.yaml").write_text(
        (data / "config.yaml").read_text().replace("os1-64-rev6", "os1-64")
    )  # wrong table
    cal = run([FolderSource(data)]).calibration
    truth = np.array(yaml.safe_load((data / "ground_truth.yaml").read_text())["T_cam_lidar"])
    xi = gtsam.Pose3.Logmap(gtsam.Pose3(cal.T_cam_lidar).between(gtsam.Pose3(truth)))
    assert sum(f.used for f in cal.frames) == 6
    assert float(xi @ np.linalg.solve(cal.covariance, xi)) < 25.0  # chi2(6) 99.97 %


def test_recorded_ouster_sets_board_in_every_frame(acfr_os1_fisheye: Path, acfr_os1_pinhole: Path) -> None:
    for data in (acfr_os1_fisheye, acfr_os1_pinhole):
        config = load_config(data / "config.yaml")
        src = FolderSource(data)
        paths = src.frames()
        config = resolve_lidar(src, paths, config)
        assert config.lidar.n_beams == 64 and config.lidar.horizontal_resolution_deg == pytest.approx(
            360 / 1024
        )
        for p in paths:
            fit = estimate_board(read_scan(p.scan), config.board, config.lidar, config.roi)
            ref = read_scan(data / "acfr_reference" / f"{p.name}_target.pcd").points.mean(axis=0)
            # ACFR's own segmentation of the board: same object (its outline differs by a few cm)
            assert np.linalg.norm(fit.corners_lidar.mean(axis=0) - ref) < 0.06, (data.name, p.name)


# pose37 of the VLP-16 set: the board at ~3.3 m, measured once with this stage and rounded to
# 1 cm / 0.001; the test moves it a further 3 cm so that it checks the hint, not a copy
POSE37_T = np.array([
    [0.016, -0.316, -0.949, 3.206],
    [-0.643, 0.723, -0.252, -0.19],
    [0.766, 0.614, -0.191, -0.624],
    [0.0, 0.0, 0.0, 1.0],
])  # fmt: skip


def test_vlp16_pose37_with_an_expected_board(acfr_data: Path) -> None:
    config = load_config(acfr_data / "config.yaml")
    scan = read_scan(acfr_data / "pcd" / "pose37.pcd")
    U, _, Vt = np.linalg.svd(POSE37_T[:3, :3])
    T = POSE37_T.copy()
    T[:3, :3] = U @ Vt
    T[:3, 3] += [0.02, -0.02, 0.01]
    fit = estimate_board(scan, config.board, config.lidar, config.roi, expected=ExpectedBoard(T, 0.3, 15.0))
    pred = config.board.corners_board() @ T[:3, :3].T + T[:3, 3]
    pred_turned = pred[config.board.half_turn_permutation()]
    err = min(np.linalg.norm(fit.corners_lidar - c, axis=1).max() for c in (pred, pred_turned))
    assert err < 0.06
    # every board point on the board (no pillar behind it, no stand below)
    Ti = np.linalg.inv(fit.T_lidar_board)
    b = fit.points_lidar @ Ti[:3, :3].T + Ti[:3, 3]
    x0, x1, y0, y1 = config.board.extent()
    assert np.abs(b[:, 2]).max() < 0.08
    assert (
        b[:, 0].min() > x0 - 0.03
        and b[:, 0].max() < x1 + 0.03
        and b[:, 1].min() > y0 - 0.03
        and b[:, 1].max() < y1 + 0.03
    )
    far = T.copy()
    far[:3, 3] += 1.2 * T[:3, 2]  # 1.2 m along the normal: towards the sensor, nothing there
    with pytest.raises(BoardNotFound):
        estimate_board(scan, config.board, config.lidar, config.roi, expected=ExpectedBoard(far, 0.3, 15.0))


def test_recorded_vlp16_set_board_in_every_frame(acfr_data: Path) -> None:
    config = load_config(acfr_data / "config.yaml")
    src = FolderSource(acfr_data)
    paths = src.frames()
    config = resolve_lidar(src, paths, config)
    found = 0
    for p in paths:
        try:
            fit = estimate_board(read_scan(p.scan), config.board, config.lidar, config.roi)
        except BoardNotFound:
            continue
        found += float(np.linalg.norm(fit.corners_lidar.mean(axis=0)) < 4.5)  # the board stands 1.5-4 m away
    assert found >= 19


def test_a_few_saturated_returns_do_not_move_the_board() -> None:
    scan, T = synth_scan(
        BOARD, HDL32, SynthScene(distance=2.0, tilt_deg=(15.0, 0.0)), np.random.default_rng(7)
    )
    ref = estimate_board(scan, BOARD, HDL32)
    Ti = np.linalg.inv(T)
    b = scan.points @ Ti[:3, :3].T + Ti[:3, 3]
    on = np.flatnonzero(
        (np.abs(b[:, 2]) < 0.05) & (b[:, 0] > 0) & (b[:, 0] < 0.6) & (b[:, 1] > 0) & (b[:, 1] < 0.45)
    )
    inten = scan.intensity.copy()
    inten[on[:: max(1, on.size // 8)]] = 40.0 * inten.max()  # ~1 % of the board: retro-reflective tape
    fit = estimate_board(Scan(scan.points, inten, scan.ring), BOARD, HDL32)
    assert np.abs(fit.corners_lidar - ref.corners_lidar).max() < 0.003
    assert _corner_error(fit, T, BOARD) < 0.005
