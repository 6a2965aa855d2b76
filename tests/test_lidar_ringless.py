"""Scanline-free LiDARs (Livox-like rosettes): the named models, the simulator's pattern, telling a
scan without scanlines from a spinning one, the ringless board search on a cluttered scan, the one
pseudo-beam of the estimation core, and end-to-end calibrations of a simulated Livox set."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml

from ilcc_graph.config import load_config
from ilcc_graph.datasets import FolderSource
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions, layout_for
from ilcc_graph.io import read_scan, write_pcd
from ilcc_graph.lidar import estimate_board
from ilcc_graph.lidar.ringless import find_ringless_candidates, pseudo_rings
from ilcc_graph.lidars import choose_model, lidar_model, measure_beams, scanline_free
from ilcc_graph.run.pipeline import run
from ilcc_graph.run.result import RunOptions
from ilcc_graph.simulate import (
    SceneOptions,
    SimulationSpec,
    Systematics,
    default_camera,
    frame_scene,
    simulate_dataset,
    simulate_scan,
)
from ilcc_graph.simulate.placements import _pose, board_placements
from ilcc_graph.simulate.rosette import ROSETTES, rosette_directions
from ilcc_graph.types import BoardReturns, Scan

MID70 = lidar_model("livox-mid70")
CHI2_6_9997 = 25.0  # chi2(6) at 99.97 %: the other simulated sensors' end-to-end bound


def _spec(lidar: str = "livox-mid70", frames: int = 6, seed: int = 2, **kw) -> SimulationSpec:
    return SimulationSpec(
        lidar=lidar, camera=default_camera("pinhole", 640), n_frames=frames, seed=seed, **kw
    )


def _scan(spec: SimulationSpec, i: int = 0) -> Scan:
    """Frame i's scan alone (no image rendered)."""
    return simulate_scan(spec, frame_scene(spec, board_placements(spec)[i], i), i)


def _nees(cal, data: Path) -> float:
    truth = np.array(yaml.safe_load((data / "ground_truth.yaml").read_text())["T_cam_lidar"])
    xi = gtsam.Pose3.Logmap(gtsam.Pose3(cal.T_cam_lidar).between(gtsam.Pose3(truth)))
    return float(xi @ np.linalg.solve(cal.covariance, xi))


def test_livox_models_are_scanline_free_cones(tmp_path: Path) -> None:
    for name, half in (("livox-mid40", 19.2), ("livox-mid70", 35.2)):
        m = lidar_model(name)
        assert m.ringless and m.n_beams == 1 and m.range_sigma_m == 0.02
        assert np.allclose(m.vertical_angles_deg, [-half, half])
        assert m.to_dict() == {"model": name}
        p = np.random.default_rng(0).normal(size=(50, 3))
        assert np.array_equal(m.ring_from_points(p), np.zeros(50, np.int32))
    assert not lidar_model("hdl32").ringless
    (tmp_path / "config.yaml").write_text(
        "board: {squares: [6, 8], square_size: 0.075}\nlidar: {model: livox-mid40}\n"
        "camera: {model: pinhole, width: 640, height: 400,\n"
        "         K: [[320, 0, 319.5], [0, 320, 199.5], [0, 0, 1]]}\n"
    )
    assert load_config(tmp_path / "config.yaml").lidar.ringless


def test_the_rosette_is_dense_at_its_centre_and_does_not_repeat() -> None:
    r = ROSETTES["livox-mid70"]
    d = rosette_directions(r, 0.0, 0.5)
    assert d.shape == (50_000, 3) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
    off = np.degrees(np.arccos(d[:, 0]))
    assert off.max() <= 35.2 + 1e-9 and off.max() > 35.0
    # per solid angle, the inner 5 deg hold several times the density of the 15-20 deg ring
    solid = lambda a, b: 2 * np.pi * (np.cos(np.deg2rad(a)) - np.cos(np.deg2rad(b)))  # noqa: E731
    inner = (off < 5).sum() / solid(0, 5)
    mid = ((off > 15) & (off < 20)).sum() / solid(15, 20)
    assert inner > 3 * mid
    # the next 0.1 s does not retrace the last: its returns fall between the earlier petals
    a, b = rosette_directions(r, 0.0, 0.1), rosette_directions(r, 0.1, 0.1)
    from scipy.spatial import cKDTree

    gap = cKDTree(a).query(b)[0]
    assert np.median(gap) > 5 * np.median(cKDTree(a).query(a, 2)[0][:, 1])


def test_simulated_livox_scan_has_no_rings_and_is_recognised(tmp_path: Path) -> None:
    scan = _scan(_spec(frames=1, integration_time_s=0.2))
    assert scan.ring is None and 19_000 <= len(scan) <= 20_000  # 100,000 returns/s, a closed room
    off = np.degrees(np.arccos(scan.points[:, 0] / np.linalg.norm(scan.points, axis=1)))
    assert off.max() < 35.6 and scan.intensity.min() >= 0 and scan.intensity.max() <= 255
    path = write_pcd(tmp_path / "a.pcd", scan)
    assert b"ring" not in path.read_bytes()[:300]
    back = read_scan(path)
    assert back.ring is None and np.allclose(back.points, scan.points, atol=1e-5)
    m = measure_beams(back)
    assert m.method == "no scanlines" and m.model.ringless and scanline_free(back.points)
    # named models of the other kind are contradicted, the right kind is kept as it is
    used, warning = choose_model(m, lidar_model("hdl32"), "pcd/0001.pcd")
    assert used.ringless and "no scanlines" in warning and "hdl32" in warning
    assert choose_model(m, MID70) == (MID70, None)
    spin = _scan(_spec("vlp16", frames=1, seed=1))
    used, warning = choose_model(measure_beams(spin), MID70)
    assert not used.ringless and used.n_beams == 16 and "livox-mid70 is a scanline-free model" in warning
    with pytest.raises(ValueError, match="plain"):
        _spec(sensor_format="ouster")


@pytest.mark.parametrize("name", ["hdl32", "vlp16", "os1-64-rev6", "pandar64"])
def test_spinning_scans_without_ring_field_keep_their_scanlines(name: str) -> None:
    scan = _scan(SimulationSpec(lidar=name, n_frames=1, seed=1))
    assert not scanline_free(scan.points)
    assert measure_beams(Scan(scan.points, scan.intensity, None)).method == "elevation clusters"


def test_board_beside_a_wall_above_the_floor_is_found_without_rings() -> None:
    """The board 0.4 m in front of the back wall, 0.5 m above the floor, on its pole, a person beside it."""
    base = _spec(frames=1, seed=3, integration_time_s=0.5, systematics=Systematics.off(),
                 scene=SceneOptions(room=(-2.0, 3.0, -2.5, 2.5), person_probability=1.0))  # fmt: skip
    T = _pose(base, np.array([2.6, 0.5, -0.7]), np.deg2rad(40), np.deg2rad(-10), np.deg2rad(15))
    spec = base.with_(placements=(T,))
    scene = frame_scene(spec, T, 0)
    assert len(scene.boxes) == 2  # pole and person
    scan = simulate_scan(spec, scene, 0)
    Ti = np.linalg.inv(T)
    b = scan.points @ Ti[:3, :3].T + Ti[:3, 3]
    x0, x1, y0, y1 = spec.board.extent()
    on = (np.abs(b[:, 2]) < 0.05) & (b[:, 0] > x0) & (b[:, 0] < x1) & (b[:, 1] > y0) & (b[:, 1] < y1)
    assert (scan.points[:, 0] > 2.95).sum() > 20 * on.sum()  # the wall behind holds far more returns
    cands = find_ringless_candidates(scan.points, None, scan.intensity, spec.board, MID70)
    assert len(cands) == 1
    assert on[cands[0].indices].mean() > 0.97  # the board, not the wall, floor, pole or person
    fit = estimate_board(scan, spec.board, MID70)
    bf = fit.points_lidar @ Ti[:3, :3].T + Ti[:3, 3]
    on_fit = (np.abs(bf[:, 2]) < 0.05) & (bf[:, 0] > x0) & (bf[:, 0] < x1) & (bf[:, 1] > y0) & (bf[:, 1] < y1)
    assert on_fit.mean() > 0.98 and on_fit.sum() > 0.95 * on.sum()  # the fit gathers every board return
    truth = spec.board.corners_board() @ T[:3, :3].T + T[:3, 3]
    err = min(np.sqrt(((fit.corners_lidar[p] - truth) ** 2).sum(axis=1).mean())
              for p in (np.arange(len(truth)), spec.board.half_turn_permutation()))  # fmt: skip
    assert err < 0.004
    assert np.all(fit.returns.ring == 0)  # one pseudo-beam for the estimation core
    bands = pseudo_rings(fit.points_lidar)
    assert bands.min() == 0 and 20 < bands.max() < 200  # what the fit's own covariance grouped by


def test_one_pseudo_beam_has_an_offset_and_no_elevation_term() -> None:
    rng = np.random.default_rng(0)

    def returns(ring: np.ndarray) -> BoardReturns:
        n = ring.size
        return BoardReturns(rng.normal(size=(n, 3)), ring, (rng.random(n) < 0.5).astype(float), 0.01,
                            np.eye(3) * 1e-6, np.zeros((3, 3)))  # fmt: skip

    opts = LidarErrorOptions(beam_elevations=True)
    one = layout_for([returns(np.zeros(300, np.int64)) for _ in range(3)], opts)
    assert one.names == ["offset[0]", "dark"] and ("elevation[0]" in dict(one.excluded))
    many = layout_for([returns(np.repeat(np.arange(4), 75)) for _ in range(3)], opts)
    assert [n for n in many.names if n.startswith("elevation")] == [f"elevation[{b}]" for b in range(4)]


def test_simulated_livox_set_calibrates_with_the_shipped_config(tmp_path: Path) -> None:
    data = simulate_dataset(tmp_path / "mid70", _spec(systematics=Systematics.off(), integration_time_s=0.5))
    assert "livox-mid70" in (data / "config.yaml").read_text()
    cal = run([FolderSource(data)]).calibration
    assert sum(f.used for f in cal.frames) == 6
    assert _nees(cal, data) < CHI2_6_9997


def test_a_livox_set_whose_config_names_no_lidar_calibrates_with_its_range_offset(tmp_path: Path) -> None:
    """A user's config without a lidar section: the scans say they have no scanlines. With the
    simulator's default systematics the one laser's range bias is common to every return; the
    LiDAR's own error terms (``--lidar-errors``) estimate it."""
    data = simulate_dataset(
        tmp_path / "mid40", _spec("livox-mid40", frames=5, seed=4, integration_time_s=0.3)
    )
    cfg = yaml.safe_load((data / "config.yaml").read_text())
    del cfg["lidar"]
    (data / "config.yaml").write_text(yaml.safe_dump(cfg))
    result = run([FolderSource(data)], RunOptions(lidar_errors=LidarErrorOptions()))
    assert result.sessions[0].observation.config.lidar.ringless
    cal = result.calibration
    assert sum(f.used for f in cal.frames) == 5
    assert _nees(cal, data) < CHI2_6_9997


def test_a_livox_recording_as_a_ros2_bag_reads_without_rings(tmp_path: Path) -> None:
    from ilcc_graph.datasets import open_source
    from ilcc_graph.simulate import RenderOptions, simulate_frames, write_bag

    spec = _spec(frames=2, integration_time_s=0.3, image=RenderOptions(supersample=1))
    frames = list(simulate_frames(spec))
    src = open_source(write_bag(tmp_path / "livox", spec, frames=frames, storage="mcap"))
    refs = src.frames()
    assert len(refs) == 2
    config = src.config()
    assert config.lidar.ringless
    scan = src.read_scan(refs[0], config)
    assert scan.ring is None and np.allclose(scan.points, frames[0].scan.points, atol=1e-5)
    fit = estimate_board(scan, config.board, config.lidar)
    T = frames[0].T_lidar_board
    truth = spec.board.corners_board() @ T[:3, :3].T + T[:3, 3]
    err = min(np.sqrt(((fit.corners_lidar[p] - truth) ** 2).sum(axis=1).mean())
              for p in (np.arange(len(truth)), spec.board.half_turn_permutation()))  # fmt: skip
    assert err < 0.004
