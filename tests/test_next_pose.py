"""Next-best board pose: the information a board adds, the LiDAR noise model, the proposal."""

from __future__ import annotations

import itertools

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, X

from ilcc_graph import next_pose as nxp
from ilcc_graph.estimation.graphs import frame_bearing_factor
from ilcc_graph.lidars import lidar_model
from ilcc_graph.simulate import default_camera, default_T_cam_lidar, paper_board
from ilcc_graph.types import GraphFrame

BOARD = paper_board()
LIDAR = lidar_model("hdl32")


def _rig(kind: str = "equirectangular", width: int = 2000) -> nxp.Rig:
    cam = default_camera(kind, width)
    return nxp.Rig(cam, default_T_cam_lidar(cam), LIDAR, BOARD)


def _pose(rig: nxp.Rig, az_deg: float, d: float, yaw: float = 0.0, pitch: float = 0.0) -> np.ndarray:
    a = np.radians(az_deg)
    return nxp.board_pose(
        np.array([d * np.cos(a), d * np.sin(a), -0.2]), BOARD, 0.5 * rig.camera_centre, yaw, pitch
    )


def _frames(rig: nxp.Rig, model: nxp.BoardNoiseModel, poses, cov_px: np.ndarray) -> list[GraphFrame]:
    out = []
    for i, T in enumerate(poses):
        Tc = rig.T_cam_lidar @ T
        p = BOARD.corners_board() @ Tc[:3, :3].T + Tc[:3, 3]
        b = p / np.linalg.norm(p, axis=1, keepdims=True)
        cov = model.covariance(T, BOARD, LIDAR)
        out.append(GraphFrame(f"{i:02d}", T, cov, BOARD.corners_board(), b, np.tile(cov_px, (len(b), 1, 1))))
    return out


def test_beam_hits_lie_on_the_board_and_follow_the_beam_table() -> None:
    rig = _rig()
    T = _pose(rig, 0.0, 2.0)
    b, ring, u = nxp.beam_hits(T, BOARD, LIDAR)
    x0, x1, y0, y1 = BOARD.extent()
    assert len(b) > 200 and np.all(np.abs(b[:, 2]) < 1e-9)
    assert b[:, 0].min() >= x0 and b[:, 0].max() <= x1 and b[:, 1].min() >= y0 and b[:, 1].max() <= y1
    # the diamond spans about 0.71 m vertically at 2 m: 20 deg / 1.33 deg spacing, about 15 beams
    assert 12 <= len(np.unique(ring)) <= 17
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1.0)
    far = nxp.beam_hits(_pose(rig, 0.0, 3.5), BOARD, LIDAR)[0]
    assert len(far) < 0.5 * len(b)  # fewer returns farther away


def test_the_noise_model_is_recovered_from_covariances_it_made() -> None:
    rig = _rig()
    truth = nxp.BoardNoiseModel((2.0e-4, 5.0e-6), (0.03, 0.5))
    placed = ((0, 1.5, 0, 0), (70, 2.2, 30, 0), (150, 1.8, -20, 15), (-80, 2.8, 0, -20), (-150, 1.3, 35, 10))
    poses = [_pose(rig, az, d, yaw, pitch) for az, d, yaw, pitch in placed]
    frames = _frames(rig, truth, poses, np.eye(2) * 0.0025)
    fitted = nxp.fit_noise_model(frames, BOARD, LIDAR)
    np.testing.assert_allclose(fitted.plane, truth.plane, rtol=1e-6)
    np.testing.assert_allclose(fitted.inplane, truth.inplane, rtol=1e-6)


def test_frame_information_is_what_the_graph_gives_the_extrinsic() -> None:
    """Three boards: the extrinsic's information from GTSAM's marginals of the real graph (board
    priors + grouped bearing factors) equals the sum of the three boards' predicted information."""
    rig = _rig()
    model = nxp.BoardNoiseModel.default(LIDAR)
    cov_px = np.diag([0.04, 0.09])
    poses = [_pose(rig, 0, 1.6, 20, 0), _pose(rig, 110, 2.3, 0, 20), _pose(rig, -120, 1.9, -30, -10)]
    frames = _frames(rig, model, poses, cov_px)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(X(0), gtsam.Pose3(rig.T_cam_lidar))
    total = np.zeros((6, 6))
    for i, f in enumerate(frames):
        fac, _ = frame_bearing_factor(X(0), B(i), f.points_board, f.bearings, f.cov_px, rig.camera)
        graph.add(fac.factor())
        graph.add(
            gtsam.PriorFactorPose3(
                B(i), gtsam.Pose3(f.T_lidar_board), gtsam.noiseModel.Gaussian.Covariance(f.board_cov)
            )
        )
        values.insert(B(i), gtsam.Pose3(f.T_lidar_board))
        total += nxp.frame_information(rig, f.T_lidar_board, f.board_cov, cov_px)
    info = np.linalg.inv(gtsam.Marginals(graph, values).marginalCovariance(X(0)))
    np.testing.assert_allclose(total, info, rtol=1e-5, atol=1e-6 * np.abs(info).max())


@pytest.mark.parametrize("kind", ["equirectangular", "pinhole"])
def test_the_proposal_is_in_view_new_and_shrinks_the_worst_sigma(kind: str) -> None:
    rig = _rig(kind, 2000 if kind == "equirectangular" else 960)
    model = nxp.BoardNoiseModel.default(LIDAR)
    cov_px = np.eye(2) * 0.01
    az = (0, 120, -120) if kind == "equirectangular" else (0, 15, -15)
    poses = [_pose(rig, a, 2.0, 0, 0) for a in az]  # all facing the rig: one normal direction each
    frames = _frames(rig, model, poses, cov_px)
    info = sum(nxp.frame_information(rig, f.T_lidar_board, f.board_cov, cov_px) for f in frames)
    cov = np.linalg.inv(info)
    adv = nxp.Advisor(rig, frames, noise=model)
    p = adv.propose(cov, (0.01, 0.2))
    assert p is not None and p.candidates > 20
    assert (
        nxp.in_view(rig, p.T_lidar_board) is not None
    )  # every corner in the image, board in the LiDAR's field
    c = p.T_lidar_board[:3, :3] @ BOARD.pattern_centre + p.T_lidar_board[:3, 3]
    for f in frames:  # not one of the boards so far
        c0 = f.T_lidar_board[:3, :3] @ BOARD.pattern_centre + f.T_lidar_board[:3, 3]
        assert np.linalg.norm(c - c0) > 0.1 or p.T_lidar_board[:3, 2] @ f.T_lidar_board[:3, 2] < 0.98
    scale = np.array([0.01] * 3 + [0.2] * 3)
    assert np.max(p.sigmas_after / scale) < np.max(p.sigmas_now / scale)
    np.testing.assert_allclose(p.azimuth_deg, np.degrees(np.arctan2(c[1], c[0])))
    # no valid candidate of the whole coarse grid does better (every centre, every turn: the search
    # turns only the centres whose facing board is among the best or no candidate)
    for centre, (yaw, pitch) in itertools.product(adv._grid, [(0.0, 0.0), *nxp.TURNS]):
        got = adv.candidate(centre, yaw, pitch)
        if got is not None:
            after = np.sqrt(np.diag(np.linalg.inv(np.linalg.inv(cov) + got[1])))
            worst = np.max(np.concatenate([np.degrees(after[:3]), 1e3 * after[3:]]) / scale)
            assert worst >= np.max(p.sigmas_after / scale) - 1e-9
    text = p.describe()
    assert ("left" in text.split(",")[0]) == (p.azimuth_deg > 0) or "straight" in text


def test_a_board_out_of_the_cameras_view_adds_nothing() -> None:
    rig = _rig("pinhole", 960)
    behind = _pose(rig, 180.0, 2.0)
    assert nxp.frame_information(rig, behind, np.eye(6) * 1e-6, np.eye(2) * 0.01) is None


def test_after_a_run_the_advice_predicts_with_the_noise_the_run_found(tmp_path) -> None:
    """from_calibration scales the boards' covariances by the run's variance components: with board
    priors found 40 x noisier than stated, one more board promises much less."""
    import dataclasses

    from ilcc_graph.datasets import open_source
    from ilcc_graph.next_pose import from_calibration
    from ilcc_graph.run.observe import observe
    from ilcc_graph.run.pipeline import solve_observed
    from ilcc_graph.run.stages import StageOptions
    from ilcc_graph.simulate import simulate_dataset, standard_spec

    spec = standard_spec(lidar="hdl32", camera="pinhole", width=800, frames=6, seed=5)
    obs = observe(open_source(simulate_dataset(tmp_path / "sim", spec)), StageOptions(jobs=1))
    cal = solve_observed(obs.frames, obs.config)
    stated = from_calibration(cal, obs.config)
    noisy = dataclasses.replace(cal, diagnostics={**cal.diagnostics, "variance_component_board": 40.0})
    found = from_calibration(noisy, obs.config)
    assert stated is not None and found is not None
    gain_stated = stated.sigmas_now / stated.sigmas_after
    gain_found = found.sigmas_now / found.sigmas_after
    assert np.all(gain_found >= 1.0 - 1e-9) and np.max(gain_found) < np.max(gain_stated)
