"""Checks every camera model's tests share: round trips, Jacobians, and the two end-to-end runs
(the image stage on simulated images, a small simulated data set calibrated)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ilcc_graph.cameras import CameraModel


def unit(p: np.ndarray) -> np.ndarray:
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


def directions(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(N, 3) unit vectors at angle ``theta`` from +z and azimuth ``phi`` about it."""
    return np.c_[np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]


def numeric_jacobian(cam: CameraModel, p: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central differences of ``cam.project`` (steps relative to |p|; columns across a seam wrapped)."""
    J = np.empty((len(p), 2, 3))
    scale = np.linalg.norm(p, axis=1)
    for j in range(3):
        step = np.zeros((len(p), 3))
        step[:, j] = h * scale
        d = cam.project(p + step) - cam.project(p - step)
        d[:, 0] = cam.wrap_du(d[:, 0])
        J[:, :, j] = d / (2 * h * scale)[:, None]
    return J


def assert_jacobian(cam: CameraModel, p: np.ndarray, rel: float = 2e-6) -> None:
    """Analytic d uv / d p equals central differences; it annihilates p (scale invariance)."""
    uv, J = cam.project_with_jacobian(p)
    assert np.all(np.isfinite(J)), "points must be inside the valid region"
    np.testing.assert_array_equal(uv, cam.project(p))
    np.testing.assert_array_equal(J, cam.d_uv_d_point(p))
    scale = np.abs(J).max(axis=(1, 2), keepdims=True)
    err = np.abs(J - numeric_jacobian(cam, p)) / scale
    assert err.max() <= rel, err.max()
    radial = np.abs(np.einsum("nij,nj->ni", J, p)) / (scale[:, :, 0] * np.linalg.norm(p, axis=1)[:, None])
    assert radial.max() <= 1e-9


def numeric_intrinsics_jacobian(cam: CameraModel, p: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """(N, 2, n) central differences of ``cam.with_intrinsics(theta).project(p)`` w.r.t. theta
    (steps relative to each parameter, at least ``h``)."""
    theta = cam.intrinsics()
    J = np.empty((len(p), 2, theta.size))
    for j in range(theta.size):
        step = np.zeros(theta.size)
        step[j] = h * max(1.0, abs(theta[j]))
        d = cam.with_intrinsics(theta + step).project(p) - cam.with_intrinsics(theta - step).project(p)
        d[:, 0] = cam.wrap_du(d[:, 0])
        J[:, :, j] = d / (2 * step[j])
    return J


def intrinsics_jacobian_errors(cam: CameraModel, p: np.ndarray) -> np.ndarray:
    """(n,) largest |analytic - central differences| of d uv / d theta_j over the points (pixels
    per unit of theta_j), after checking that uv and d uv / d p are those of ``project`` and
    ``d_uv_d_point`` and that the points are imaged."""
    uv, J_p, J_t = cam.project_with_intrinsics_jacobian(p)
    assert J_t.shape == (len(p), 2, len(cam.intrinsic_names))
    assert np.all(np.isfinite(uv)) and np.all(np.isfinite(J_t)), "points must be inside the valid region"
    np.testing.assert_array_equal(uv, cam.project(p))
    np.testing.assert_array_equal(J_p, cam.d_uv_d_point(p))
    return np.abs(J_t - numeric_intrinsics_jacobian(cam, p)).max(axis=(0, 1), initial=0.0)


def assert_intrinsics_jacobian(cam: CameraModel, p: np.ndarray, rel: float = 1e-6) -> np.ndarray:
    """Analytic d uv / d intrinsics equals central differences to ``rel`` of each column's largest
    entry (plus 1e-7 px); the round trip ``with_intrinsics(intrinsics()) == cam`` holds. Returns
    the errors per parameter."""
    assert len(cam.intrinsics()) == len(cam.intrinsic_names) == len(set(cam.intrinsic_names))
    assert cam.with_intrinsics(cam.intrinsics()) == cam
    err = intrinsics_jacobian_errors(cam, p)
    scale = np.abs(cam.project_with_intrinsics_jacobian(p)[2]).max(axis=(0, 1), initial=0.0)
    assert np.all(err <= rel * scale + 1e-7), dict(zip(cam.intrinsic_names, err, strict=True))
    return err


def assert_pixel_round_trip(cam: CameraModel, uv: np.ndarray, atol: float = 1e-7) -> np.ndarray:
    """Pixels with a bearing project back onto themselves; returns the (N,) mask of those."""
    b = cam.bearing(uv)
    ok = np.isfinite(b[:, 0])
    np.testing.assert_allclose(np.linalg.norm(b[ok], axis=1), 1.0, atol=1e-13)
    back = cam.project(b[ok] * np.linspace(0.3, 40.0, ok.sum())[:, None])
    d = back - uv[ok]
    d[:, 0] = cam.wrap_du(d[:, 0])
    assert np.abs(d).max(initial=0.0) <= atol
    return ok


def truth_uv(spec, T_lidar_board: np.ndarray) -> np.ndarray:
    """(K, 2) true pixels of the board's inner corners in a simulated frame."""
    b = spec.board
    P = (spec.T_cam_lidar @ T_lidar_board @ np.c_[b.corners_board(), np.ones(b.n_corners)].T)[:3].T
    return spec.camera.project(P)


def assert_image_stage_finds_boards(kind: str, width: int, seed: int, frames: int = 2) -> list[float]:
    """``detect_corners`` on simulated images of ``kind``: every board found, corners within
    0.15 px (median) and 0.6 px (max) of the truth, up to the half turn of the symmetric 6 x 8
    board. Returns the per-frame median errors."""
    from ilcc_graph.image import detect_corners
    from ilcc_graph.simulate import simulate_frames, standard_spec

    spec = standard_spec(camera=kind, width=width, frames=frames, seed=seed)
    assert spec.camera.kind == kind
    medians = []
    for f in simulate_frames(spec):
        res = detect_corners(f.image, spec.camera, spec.board)
        ref = truth_uv(spec, f.T_lidar_board)
        e = min(
            (np.linalg.norm(res.uv - r, axis=1) for r in (ref, ref[spec.board.half_turn_permutation()])),
            key=lambda x: x.max(),
        )
        assert np.median(e) < 0.15 and e.max() < 0.6, (f.name, np.median(e), e.max())
        np.testing.assert_allclose(res.bearings, spec.camera.bearing(res.uv), atol=1e-12)
        medians.append(float(np.median(e)))
    return medians


def assert_simulated_set_calibrates(
    kind: str, out: Path, width: int = 640, frames: int = 6, seed: int = 1
) -> tuple[float, float]:
    """A small simulated data set of ``kind`` (HDL-32E, 6 x 8 board) calibrates from its files:
    the image stage finds every board, all frames but at most one are used (the pipeline may drop
    a LiDAR fit that disagrees with the others), rotation within 0.1 deg and translation within
    5 mm of the truth. Returns (rotation error deg, translation error mm)."""
    from ilcc_graph.datasets import FolderSource
    from ilcc_graph.io import read_ground_truth
    from ilcc_graph.run.pipeline import run
    from ilcc_graph.simulate import simulate_dataset, standard_spec

    data = simulate_dataset(out, standard_spec(camera=kind, width=width, frames=frames, seed=seed))
    result = run([FolderSource(data)])
    config, cal = result.sessions[0].observation.config, result.calibration
    assert config.camera.kind == kind
    reasons = [f.reason for f in cal.frames if not f.used]
    assert len(cal.frames) == frames and len(reasons) <= 1, reasons
    assert not any(r.startswith("image") for r in reasons), reasons
    E = np.linalg.inv(read_ground_truth(data).T_cam_lidar) @ cal.T_cam_lidar
    rot_deg = float(np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1.0, 1.0))))
    trans_mm = float(np.linalg.norm(E[:3, 3]) * 1000)
    assert rot_deg < 0.1 and trans_mm < 5.0, (rot_deg, trans_mm)
    return rot_deg, trans_mm
