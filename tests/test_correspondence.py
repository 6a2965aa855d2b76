"""Corner order across frames: random half turns resolved, outliers dropped, perm None, 1-2 frames."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ilcc_graph.init.correspondence import OrderResult, bearing_errors, resolve_half_turns

ROWS, COLS, SQUARE = 6, 8, 0.075  # 5 x 7 inner corners, symmetric under a half turn
INCONSISTENT = "corner order inconsistent with the other frames"


def _board() -> tuple[np.ndarray, np.ndarray]:
    i, j = np.meshgrid(np.arange(ROWS - 1), np.arange(COLS - 1), indexing="ij")
    corners = np.c_[(j.ravel() + 1) * SQUARE, (i.ravel() + 1) * SQUARE, np.zeros(i.size)]
    perm = np.arange(len(corners))[::-1].copy()  # k -> K-1-k, as Board.half_turn_permutation()
    return corners, perm


def _frames(seed: int, n: int, geometry: str, flip_prob: float = 0.5):
    """Simulated frames: LiDAR corners (3 mm noise), bearings (0.5 mrad), random image half turns."""
    rng = np.random.default_rng(seed)
    corners, perm = _board()
    centre = corners.mean(axis=0)
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T[:3, 3] = rng.uniform(-0.3, 0.3, 3)
    lidar, bearings, flips = [], [], []
    for _ in range(n):
        if geometry == "panoramic":  # boards all around (equirectangular camera frame)
            d = rng.normal(size=3) * np.array([1.0, 1.0, 0.3])
        else:  # a pinhole's field of view (OpenCV camera frame, z forward)
            d = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.35, 0.35), 1.0])
        d /= np.linalg.norm(d)
        z = Rotation.from_rotvec(rng.normal(size=3) * 0.4).as_matrix() @ -d  # facing the camera, tilted
        x = np.cross(rng.normal(size=3), z)
        x /= np.linalg.norm(x)
        X = d * rng.uniform(2.0, 6.0) + (corners - centre) @ np.c_[x, np.cross(z, x), z].T
        P = (X - T[:3, 3]) @ T[:3, :3] + rng.normal(size=X.shape) * 0.003
        F = X / np.linalg.norm(X, axis=1, keepdims=True) + rng.normal(size=X.shape) * 0.5e-3
        F /= np.linalg.norm(F, axis=1, keepdims=True)
        flip = bool(rng.random() < flip_prob)
        lidar.append(P)
        bearings.append(F[perm] if flip else F)  # the image stage listed it half turned
        flips.append(flip)
    names = [f"{k:04d}" for k in range(n)]
    return lidar, bearings, perm, flips, names, T


def _rot_err_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))))


@pytest.mark.parametrize(
    ("geometry", "seed"), [("panoramic", 1), ("panoramic", 2), ("pinhole", 4), ("pinhole", 7)]
)
def test_random_half_turns_are_resolved(geometry: str, seed: int) -> None:
    lidar, bearings, perm, flips, names, T = _frames(seed, 8, geometry)
    assert 0 < sum(flips) < 8
    r = resolve_half_turns(lidar, bearings, perm, names)
    assert isinstance(r, OrderResult)
    assert r.dropped == []
    assert r.ambiguous is None
    assert r.flip == dict(zip(names, flips, strict=True))
    assert r.T_cam_lidar is not None
    assert _rot_err_deg(r.T_cam_lidar[:3, :3], T[:3, :3]) < 0.1
    assert np.linalg.norm(r.T_cam_lidar[:3, 3] - T[:3, 3]) < 0.01
    for k, name in enumerate(names):  # each frame's own pose: not the half-turned twin (180 deg off)
        assert _rot_err_deg(r.per_frame_T[name][:3, :3], T[:3, :3]) < 30.0
        chosen = bearings[k][perm] if r.flip[name] else bearings[k]
        assert 1e3 * np.sqrt(np.mean(bearing_errors(T, lidar[k], chosen) ** 2)) < 3.0
        e_as_listed, e_flipped = r.errors_mrad[name]
        assert (e_flipped < e_as_listed) == flips[k]


@pytest.mark.parametrize("geometry", ["panoramic", "pinhole"])
def test_an_inconsistent_frame_is_dropped(geometry: str) -> None:
    lidar, bearings, perm, flips, names, _ = _frames(11, 8, geometry)
    lidar[2] = lidar[2] + np.array([0.4, -0.3, 0.2])  # the LiDAR stage put this board elsewhere
    bearings[5] = bearings[5][np.random.default_rng(0).permutation(35)]  # scrambled image corners
    r = resolve_half_turns(lidar, bearings, perm, names)
    dropped = dict(r.dropped)
    assert set(dropped) == {names[2], names[5]}
    assert all(why.startswith(INCONSISTENT) for why in dropped.values())
    assert "mrad" in dropped[names[2]]
    assert r.flip == {n: f for n, f in zip(names, flips, strict=True) if n not in dropped}


def test_without_half_turn_symmetry_only_consistency_is_checked() -> None:
    lidar, bearings, _perm, _, names, T = _frames(21, 6, "panoramic", flip_prob=0.0)
    _, perm = _board()
    bearings[3] = bearings[3][perm]  # this frame's order is wrong and perm is not allowed
    r = resolve_half_turns(lidar, bearings, None, names)
    assert [n for n, _ in r.dropped] == [names[3]]
    assert r.dropped[0][1].startswith(INCONSISTENT)
    assert r.flip == {n: False for n in names if n != names[3]}
    assert all(np.isnan(e1) for _, e1 in r.errors_mrad.values())
    assert _rot_err_deg(r.T_cam_lidar[:3, :3], T[:3, :3]) < 0.1


def test_two_frames_are_enough_when_the_boards_differ() -> None:
    for seed, geometry in [(31, "panoramic"), (32, "pinhole"), (33, "panoramic")]:
        lidar, bearings, perm, flips, names, _ = _frames(seed, 2, geometry)
        r = resolve_half_turns(lidar, bearings, perm, names)
        assert r.ambiguous is None
        assert r.dropped == []
        assert r.flip == dict(zip(names, flips, strict=True))


def test_two_frames_of_the_same_board_pose_are_ambiguous() -> None:
    lidar, bearings, perm, _, names, _ = _frames(41, 1, "panoramic", flip_prob=0.0)
    rng = np.random.default_rng(5)
    lidar2 = lidar[0] + rng.normal(size=lidar[0].shape) * 0.003
    bearings2 = bearings[0] + rng.normal(size=bearings[0].shape) * 0.5e-3
    bearings2 /= np.linalg.norm(bearings2, axis=1, keepdims=True)
    r = resolve_half_turns([lidar[0], lidar2], [bearings[0], bearings2[perm]], perm, ["a", "b"])
    assert r.ambiguous is not None and "two extrinsics" in r.ambiguous


def test_one_frame_is_ambiguous_with_a_half_turn_and_fine_without() -> None:
    lidar, bearings, perm, _, names, _ = _frames(51, 1, "pinhole")
    r = resolve_half_turns(lidar, bearings, perm, names)
    assert r.ambiguous is not None and "only one" in r.ambiguous
    assert r.flip == {names[0]: False}
    r = resolve_half_turns(lidar, bearings, None, names)
    assert r.ambiguous is None and r.flip == {names[0]: False}


def test_frames_whose_order_is_known_are_never_flipped() -> None:
    lidar, bearings, perm, flips, names, _ = _frames(61, 6, "panoramic")
    k = flips.index(True)
    flippable = [i != k for i in range(6)]
    r = resolve_half_turns(lidar, bearings, perm, names, flippable=flippable)
    assert names[k] not in r.flip
    assert [n for n, _ in r.dropped] == [names[k]]
    assert r.flip == {n: f for i, (n, f) in enumerate(zip(names, flips, strict=True)) if i != k}


def test_two_disagreeing_frames_are_both_dropped() -> None:
    """One board's LiDAR pose is turned 60 degrees: with two frames nobody can tell which is wrong.
    (A shifted, or 30-degree turned, board is not enough with two frames: one joint extrinsic
    absorbs most of it, to errors of a few mrad that only the graph's chi-square gate can judge.)"""
    lidar, bearings, perm, _, names, _ = _frames(71, 2, "panoramic")
    c = lidar[1].mean(axis=0)
    lidar[1] = c + (lidar[1] - c) @ Rotation.from_rotvec([0.0, 0.0, np.radians(60.0)]).as_matrix().T
    r = resolve_half_turns(lidar, bearings, perm, names)
    assert r.flip == {}
    assert {n for n, _ in r.dropped} == set(names)
    assert r.ambiguous is not None and "cannot tell" in r.ambiguous


def test_bad_input_raises() -> None:
    lidar, bearings, perm, _, names, _ = _frames(81, 2, "panoramic")
    with pytest.raises(ValueError, match="one entry per name"):
        resolve_half_turns(lidar, bearings[:1], perm, names)
    with pytest.raises(ValueError, match="perm"):
        resolve_half_turns(lidar, bearings, perm[:-1], names)
    with pytest.raises(ValueError, match="unique"):
        resolve_half_turns(lidar, bearings, perm, ["a", "a"])
