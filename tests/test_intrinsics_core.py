"""Camera intrinsics in the estimation core: refined as variables, or their stated sigmas propagated.

One small simulated fisheye set whose config states intrinsics off the truth that rendered the
images (``simulate.IntrinsicsError``), with those sigmas in ``camera.intrinsics_sigma``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import gtsam
import numpy as np
import pytest

from ilcc_graph.datasets import FolderSource
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.io import read_ground_truth
from ilcc_graph.run.observe import observe
from ilcc_graph.run.pipeline import solve_observations
from ilcc_graph.run.result import RunOptions
from ilcc_graph.simulate import IntrinsicsError, simulate_dataset, standard_spec


@pytest.fixture(scope="module")
def fisheye_set(tmp_path_factory) -> Path:
    spec = standard_spec(lidar="hdl32", camera="fisheye", width=960, frames=10, seed=4)
    spec = dataclasses.replace(spec, intrinsics_error=IntrinsicsError.typical(2.0))
    return simulate_dataset(tmp_path_factory.mktemp("intr") / "data", spec)


@pytest.fixture(scope="module")
def observed(fisheye_set):
    return observe(FolderSource(fisheye_set))


def _nees(cal, T_true: np.ndarray) -> float:
    xi = gtsam.Pose3(cal.T_cam_lidar).localCoordinates(gtsam.Pose3(T_true))
    return float(xi @ np.linalg.solve(cal.covariance, xi))


def test_refined_intrinsics_come_closer_to_the_truth(fisheye_set, observed) -> None:
    from ilcc_graph.cameras import make_camera

    truth = read_ground_truth(fisheye_set)
    true_cam = make_camera(truth.extra["camera_truth"])
    stated = observed.config.camera
    res = solve_observations([observed], RunOptions(intrinsics=IntrinsicsOptions(refine=True)))
    intr = res.calibration.sensors["camera_intrinsics"]
    names, values, sigmas = intr["names"], intr["values"], intr["sigmas"]
    assert list(names) == list(stated.intrinsic_names)
    err_stated = np.abs(stated.intrinsics() - true_cam.intrinsics())[:4]
    err_refined = np.abs(values - true_cam.intrinsics())[:4]
    assert np.all(err_refined < err_stated), (err_stated, err_refined)
    assert np.all(err_refined < 4 * sigmas[:4])
    assert _nees(res.calibration, truth.T_cam_lidar) < 16.8


def test_stated_sigmas_widen_the_covariance_when_not_refined(observed) -> None:
    off = solve_observations(
        [observed], RunOptions(intrinsics=IntrinsicsOptions(propagate=False))
    ).calibration
    on = solve_observations([observed], RunOptions()).calibration
    assert np.allclose(off.T_cam_lidar, on.T_cam_lidar)  # the estimate does not move
    extra = on.covariance - off.covariance
    assert np.linalg.eigvalsh(0.5 * (extra + extra.T)).min() > -1e-12 * np.abs(off.covariance).max()
    assert np.trace(on.covariance[3:, 3:]) > 1.05 * np.trace(off.covariance[3:, 3:])


def test_effect_of_the_refined_intrinsics_is_the_difference_to_the_stated_camera(observed) -> None:
    """calibration.sensors says how far refining the intrinsics moved the extrinsic: the difference to
    a solve of the same frames with the stated camera."""
    from ilcc_graph.estimation import NoiseOptions

    res = solve_observations(  # the LiDAR model held at none: this is the camera's effect
        [observed],
        RunOptions(sensor_model="none", intrinsics=IntrinsicsOptions(refine=True), second_pass=False),
    ).calibration
    eff = res.sensors["effects"]["camera_intrinsics"]
    used = {f.name for f in res.frames if f.used}
    same = dataclasses.replace(observed, frames=[f for f in observed.frames if f.name in used])
    no_gate = NoiseOptions(chi2_gate_prob=None)
    stated = solve_observations(
        [same],
        RunOptions(
            sensor_model="none",
            noise=no_gate,
            intrinsics=IntrinsicsOptions(propagate=False),
            second_pass=False,
        ),
    ).calibration
    c_ref = -res.T_cam_lidar[:3, :3].T @ res.T_cam_lidar[:3, 3]
    c_st = -stated.T_cam_lidar[:3, :3].T @ stated.T_cam_lidar[:3, 3]
    assert eff["translation_mm"] == pytest.approx(1e3 * np.linalg.norm(c_ref - c_st), rel=1e-3, abs=1e-3)
    assert eff["mahalanobis"] > 0 and "lidar_errors" not in res.sensors["effects"]


def test_the_second_look_expects_each_board_through_the_refined_lens(observed) -> None:
    """The second look searches a board where the image and the answer put it: with the intrinsics
    refined, the image's corners go through the refined lens (``second_look.second_pass``), and the
    expected boards sit where the LiDAR saw them to 0.2-2.1 mm; through the stated lens 23-57 mm
    (measured)."""
    from ilcc_graph.config.rig_config import solved_camera
    from ilcc_graph.run.second_look import _predicted_board

    cal = solve_observations([observed], RunOptions(intrinsics=IntrinsicsOptions(refine=True))).calibration
    config = observed.pair_config
    camera = solved_camera(config.camera, cal.sensors)
    centre = config.board.corners_board().mean(axis=0)
    off = {"stated": [], "refined": []}
    for f in (f for f in observed.frames if f.board is not None and f.corners is not None):
        seen = f.board.T_lidar_board[:3, :3] @ centre + f.board.T_lidar_board[:3, 3]
        for what, cam in (("stated", None), ("refined", camera)):
            T = _predicted_board(f.corners, config, cal.T_cam_lidar, cam)
            off[what].append(np.linalg.norm(seen - (T[:3, :3] @ centre + T[:3, 3])))
    assert len(off["refined"]) >= 8
    assert np.median(off["refined"]) < 0.005 and np.median(off["stated"]) > 3 * np.median(off["refined"]), off
