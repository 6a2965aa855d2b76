"""The simulator's intrinsics error: images rendered by the true camera, config.yaml stating a
perturbed one (with its sigma), ground_truth.yaml recording the truth; off by default; its own
random stream."""

from __future__ import annotations

import numpy as np
import pytest

from ilcc_graph.cameras import make_camera
from ilcc_graph.config import load_config
from ilcc_graph.io import read_ground_truth, read_image
from ilcc_graph.simulate import (
    IntrinsicsError,
    ground_truth,
    simulate_dataset,
    simulate_frame,
    standard_spec,
    stated_camera,
)
from ilcc_graph.simulate.export import config_dict


def test_off_by_default_config_states_the_truth() -> None:
    spec = standard_spec(camera="fisheye", width=640, frames=2)
    assert spec.intrinsics_error.is_off
    assert config_dict(spec)["camera"] == spec.camera.to_dict()
    gt = ground_truth(spec)
    assert gt["camera_truth"] == spec.camera.to_dict()
    assert gt["camera_intrinsics_error"] == dict.fromkeys(spec.camera.intrinsic_names, 0.0)
    assert gt["simulation"]["intrinsics_error"]["focal_rel_sigma"] == 0.0


@pytest.mark.parametrize("kind", ["pinhole", "fisheye", "double_sphere", "unified"])
def test_the_stated_camera_is_drawn_from_its_stated_sigma(kind: str) -> None:
    spec = standard_spec(camera=kind, width=640, frames=2, intrinsics_error=IntrinsicsError.typical())
    truth = spec.camera
    sigma = spec.intrinsics_error.sigmas(truth)
    np.testing.assert_allclose(sigma[:4], [0.005 * truth.K[0, 0], 0.005 * truth.K[1, 1], 2.0, 2.0])
    stated = stated_camera(truth, spec.intrinsics_error, spec.seed)
    assert type(stated) is type(truth) and (stated.width, stated.height) == (truth.width, truth.height)
    np.testing.assert_array_equal(stated.intrinsics_sigma, sigma)
    z = (stated.intrinsics() - truth.intrinsics())[sigma > 0] / sigma[sigma > 0]
    assert np.all(z != 0) and np.abs(z).max() < 5
    assert stated == stated_camera(truth, spec.intrinsics_error, spec.seed)  # seeded
    assert stated != stated_camera(truth, spec.intrinsics_error, spec.seed + 1)
    assert config_dict(spec)["camera"] == stated.to_dict()
    gt = ground_truth(spec)
    assert gt["camera_truth"] == truth.to_dict()
    d = stated.intrinsics() - truth.intrinsics()
    assert gt["camera_intrinsics_error"] == dict(zip(truth.intrinsic_names, d.tolist(), strict=True))
    quiet = IntrinsicsError(0.005, 2.0, state_sigma=False)
    assert stated_camera(truth, quiet, 0).intrinsics_sigma is None


def test_many_draws_have_the_stated_spread() -> None:
    truth = standard_spec(camera="fisheye", width=640).camera
    err = IntrinsicsError.typical()
    sigma = err.sigmas(truth)
    z = np.array(
        [(stated_camera(truth, err, s).intrinsics() - truth.intrinsics()) / sigma for s in range(400)]
    )
    np.testing.assert_allclose(z.std(axis=0), 1.0, atol=0.12)
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=0.15)


def test_switching_it_changes_no_other_draw() -> None:
    base = standard_spec(camera="pinhole", width=320, frames=2, seed=3)
    on = base.with_(intrinsics_error=IntrinsicsError.typical(2.0))
    a, b = simulate_frame(base, 1), simulate_frame(on, 1)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.scan.points, b.scan.points)
    np.testing.assert_array_equal(a.T_lidar_board, b.T_lidar_board)
    ga, gb = ground_truth(base), ground_truth(on)
    for key in ("T_cam_lidar", "T_lidar_board", "lidar_beam_bias_m", "camera_truth"):
        assert ga[key] == gb[key]


def test_a_panorama_has_nothing_to_perturb() -> None:
    with pytest.raises(ValueError, match="camera model 'equirectangular' has nothing to perturb"):
        standard_spec(camera="equirectangular", width=800, intrinsics_error=IntrinsicsError.typical())
    with pytest.raises(ValueError, match="focal_rel_sigma must be finite and >= 0"):
        IntrinsicsError(-0.01)


def test_images_follow_the_truth_and_config_the_perturbed_camera(tmp_path) -> None:
    from ilcc_graph.image import detect_corners

    spec = standard_spec(
        camera="pinhole", width=640, frames=2, seed=2, intrinsics_error=IntrinsicsError.typical(2.0)
    )
    data = simulate_dataset(tmp_path / "sim", spec)
    config, gt = load_config(data / "config.yaml"), read_ground_truth(data)
    truth, stated = make_camera(gt.extra["camera_truth"]), config.camera
    assert truth == spec.camera and stated == stated_camera(spec.camera, spec.intrinsics_error, spec.seed)
    np.testing.assert_array_equal(stated.intrinsics_sigma, spec.intrinsics_error.sigmas(truth))
    board = config.board
    P = np.c_[board.corners_board(), np.ones(board.n_corners)].T
    for name, T_lb in gt.T_lidar_board.items():
        uv = detect_corners(read_image(data / "img" / f"{name}.png"), stated, board).uv
        p_cam = (gt.T_cam_lidar @ T_lb @ P)[:3].T
        errs = []
        for cam in (truth, stated):
            ref = cam.project(p_cam)
            e = min(
                (np.linalg.norm(uv - r, axis=1) for r in (ref, ref[board.half_turn_permutation()])),
                key=lambda x: float(np.median(x)),
            )
            errs.append(float(np.median(e)))
        assert errs[0] < 0.15 and errs[1] > 1.0, (name, errs)  # the pixels are the truth's


def test_cli_simulate_states_the_error(tmp_path) -> None:
    from ilcc_graph.app import main

    out = tmp_path / "sim"
    argv = ["simulate", str(out), "--camera", "pinhole", "--width", "320", "--frames", "1"]
    assert main([*argv, "--intrinsics-error", "1.5"]) == 0
    cam, gt = load_config(out / "config.yaml").camera, read_ground_truth(out)
    truth = make_camera(gt.extra["camera_truth"])
    assert cam != truth and cam.intrinsics_sigma is not None
    assert cam == stated_camera(truth, IntrinsicsError.typical(1.5), 0)
    assert main([*argv[:1], str(tmp_path / "pano"), "--width", "320", "--intrinsics-error", "1"]) == 2
