"""UPnP: exact recovery, noise, global minimum among the candidates, planar twin, non-central rig."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ilcc_graph.init.upnp import (
    UpnpSolution,
    object_space_cost,
    quat_to_rotation,
    quaternion_starts,
    refine_angular,
    upnp,
)


def _problem(rng: np.random.Generator, n: int, kind: str, noise: float = 0.0):
    """Points in the LiDAR frame, bearings in the camera frame, true R, t (p_cam = R p + t)."""
    R = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
    t = rng.uniform(-0.5, 0.5, 3)
    if kind == "sphere":
        d = rng.normal(size=(n, 3))
    elif kind == "narrow":  # a 10-degree cone about +z, like a long-focal pinhole
        d = np.c_[rng.uniform(-0.09, 0.09, (n, 2)), np.ones(n)]
    elif kind == "behind":  # a panoramic camera's view: everything behind a pinhole's image plane
        d = np.c_[rng.uniform(-0.5, 0.5, (n, 2)), -np.ones(n)]
    else:
        raise ValueError(kind)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    X = d * rng.uniform(1.5, 8.0, (n, 1))
    F = X + rng.normal(size=X.shape) * noise * np.linalg.norm(X, axis=1, keepdims=True)
    F /= np.linalg.norm(F, axis=1, keepdims=True)
    return (X - t) @ R, F, R, t


def _rot_err_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))))


def test_quaternion_starts_cover_the_half_sphere() -> None:
    S = quaternion_starts()
    assert S.shape == (60, 4)
    np.testing.assert_allclose(np.linalg.norm(S, axis=1), 1.0)
    # no two starts are the same rotation (q ~ -q)
    G = np.abs(S @ S.T) - np.eye(60)
    assert G.max() < 0.81
    # every rotation is within 45 degrees (quaternion angle 22.5) of a start: test on random ones
    q = np.random.default_rng(0).normal(size=(5000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    worst = np.degrees(np.arccos(np.max(np.abs(q @ S.T), axis=1))).max()
    assert worst < 23.0


def test_quat_to_rotation_matches_scipy() -> None:
    q = np.random.default_rng(1).normal(size=(10, 4))
    ref = Rotation.from_quat(np.c_[q[:, 1:], q[:, :1]]).as_matrix()
    np.testing.assert_allclose(quat_to_rotation(q), ref, atol=1e-14)


@pytest.mark.parametrize(
    ("n", "kind", "seed"),
    [(4, "sphere", 0), (4, "sphere", 1), (4, "narrow", 2), (5, "narrow", 3), (35, "sphere", 4),
     (60, "narrow", 5), (700, "sphere", 6), (700, "narrow", 7), (12, "behind", 8)],
)  # fmt: skip
def test_exact_data_recovers_the_pose(n: int, kind: str, seed: int) -> None:
    P, F, R, t = _problem(np.random.default_rng(seed), n, kind)
    sols = upnp(P, F)
    assert sols and all(isinstance(s, UpnpSolution) for s in sols)
    best = sols[0]
    np.testing.assert_allclose(best.T_cam_points[:3, :3], R, atol=1e-8)
    np.testing.assert_allclose(best.T_cam_points[:3, 3], t, atol=1e-8)
    np.testing.assert_array_equal(best.T_cam_points[3], [0, 0, 0, 1])
    assert best.cost < 1e-14 * n
    assert best.front_fraction == 1.0
    costs = [s.cost for s in sols]
    assert costs == sorted(costs)
    for s in sols:  # the cost reported is the cost from the definition
        assert s.cost == pytest.approx(object_space_cost(s.T_cam_points, P, F), rel=1e-9, abs=1e-18)


@pytest.mark.parametrize(
    ("n", "kind", "max_deg", "max_mm"),
    [(35, "sphere", 0.05, 3.0), (700, "sphere", 0.015, 0.8), (100, "narrow", 0.25, 25.0)],
)
def test_noisy_data_stays_near(n: int, kind: str, max_deg: float, max_mm: float) -> None:
    rng = np.random.default_rng(10 + n)
    for _ in range(5):
        P, F, R, t = _problem(rng, n, kind, noise=0.5e-3)
        T = upnp(P, F)[0].T_cam_points
        assert _rot_err_deg(T[:3, :3], R) < max_deg
        assert 1e3 * np.linalg.norm(T[:3, 3] - t) < max_mm
        Tr = refine_angular(T, P, F)
        assert _rot_err_deg(Tr[:3, :3], R) < max_deg
        assert 1e3 * np.linalg.norm(Tr[:3, 3] - t) < max_mm


def _scipy_local_minima(P: np.ndarray, F: np.ndarray, rng: np.random.Generator, starts: int):
    V = np.eye(3)[None] - F[:, :, None] * F[:, None, :]
    Pc = P - P.mean(axis=0)
    out = []
    for _ in range(starts):
        R0 = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()

        def res(x, R0=R0):
            X = Pc @ (Rotation.from_rotvec(x[:3]).as_matrix() @ R0).T + x[3:]
            return np.einsum("nab,nb->na", V, X).ravel()

        sol = least_squares(res, np.zeros(6), method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14)
        R = Rotation.from_rotvec(sol.x[:3]).as_matrix() @ R0
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, sol.x[3:] - R @ P.mean(axis=0)
        out.append((object_space_cost(T, P, F), R))
    return out


@pytest.mark.parametrize(("n", "kind", "seed"), [(4, "narrow", 20), (6, "narrow", 21), (4, "sphere", 22),
                                                 (8, "narrow", 23)])  # fmt: skip
def test_candidates_hold_the_global_and_the_local_minima(n: int, kind: str, seed: int) -> None:
    """Noisy small problems have several minima: the best candidate is the best scipy finds,
    and every distinct local minimum scipy reaches from random starts is in the list."""
    rng = np.random.default_rng(seed)
    P, F, _, _ = _problem(rng, n, kind, noise=2e-3)
    sols = upnp(P, F)
    ref = _scipy_local_minima(P, F, rng, 25)
    best_ref = min(c for c, _ in ref)
    assert sols[0].cost <= best_ref * (1 + 1e-7) + 1e-15
    for c, R in ref:
        if c > best_ref * 1e3 + 1e-9:
            continue  # scipy stopped on a plateau, not at a minimum
        assert any(_rot_err_deg(R, s.T_cam_points[:3, :3]) < 0.05 for s in sols), c


def test_planar_board_has_a_twin_behind_and_prefer_front_picks_the_right_one() -> None:
    rng = np.random.default_rng(30)
    i, j = np.meshgrid(np.arange(5), np.arange(7), indexing="ij")
    board = np.c_[(j.ravel() + 1) * 0.075, (i.ravel() + 1) * 0.075, np.zeros(35)]
    R = Rotation.random(random_state=3).as_matrix()
    t = np.array([0.1, -0.2, 0.05])
    Rb = Rotation.from_rotvec([0.3, -0.2, 0.1]).as_matrix()
    X = board @ Rb.T + np.array([0.2, -0.1, 3.0])  # camera frame, in front of +z
    F = X / np.linalg.norm(X, axis=1, keepdims=True)
    P = (X - t) @ R
    sols = upnp(P, F)
    fronts = [s for s in sols if s.front_fraction == 1.0]
    behinds = [s for s in sols if s.front_fraction == 0.0]
    assert fronts and behinds
    assert behinds[0].cost == pytest.approx(fronts[0].cost, abs=1e-12)  # exact twin: both ~0
    for tie in (1e-3, np.inf):
        first = upnp(P, F, prefer_front=True, tie_rtol=tie)[0]
        assert first.front_fraction == 1.0
    np.testing.assert_allclose(first.T_cam_points[:3, :3], R, atol=1e-7)
    np.testing.assert_allclose(first.T_cam_points[:3, 3], t, atol=1e-7)
    # with noise off the plane the twin's cost is no longer equal; tie_rtol=inf still puts the front first
    Fn = F + rng.normal(size=F.shape) * 1e-3
    Fn /= np.linalg.norm(Fn, axis=1, keepdims=True)
    first = upnp(P, Fn, prefer_front=True, tie_rtol=np.inf)[0]
    assert first.front_fraction == 1.0
    assert _rot_err_deg(first.T_cam_points[:3, :3], R) < 2.0


def test_non_central_rig_recovers_the_pose() -> None:
    rng = np.random.default_rng(40)
    R = Rotation.random(random_state=5).as_matrix()
    t = np.array([0.3, -0.1, 0.2])
    centres = np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.0, 0.3, 0.1]])  # three cameras, body frame
    X = rng.normal(size=(30, 3)) * 3.0  # points in the body frame
    cam = np.arange(30) % 3
    F = X - centres[cam]
    F /= np.linalg.norm(F, axis=1, keepdims=True)
    P = (X - t) @ R
    best = upnp(P, F, origins=centres[cam])[0]
    np.testing.assert_allclose(best.T_cam_points[:3, :3], R, atol=1e-8)
    np.testing.assert_allclose(best.T_cam_points[:3, 3], t, atol=1e-8)
    # the central model on the same data is wrong: the offsets matter
    central = upnp(P, F)[0]
    assert central.cost > 1e-6


def test_weights_and_invariance_to_shifting_the_points() -> None:
    rng = np.random.default_rng(50)
    P, F, R, t = _problem(rng, 40, "sphere", noise=1e-3)
    a = upnp(P, F)[0]
    shift = np.array([10.0, -5.0, 3.0])
    b = upnp(P + shift, F)[0]
    np.testing.assert_allclose(b.T_cam_points[:3, :3], a.T_cam_points[:3, :3], atol=1e-9)
    np.testing.assert_allclose(b.T_cam_points[:3, 3], a.T_cam_points[:3, 3] - a.T_cam_points[:3, :3] @ shift,
                               atol=1e-8)  # fmt: skip
    # zero weight on the first half = solving on the second half alone
    w = np.r_[np.zeros(20), np.ones(20)]
    c = upnp(P, F, weights=w)[0]
    d = upnp(P[20:], F[20:])[0]
    np.testing.assert_allclose(c.T_cam_points, d.T_cam_points, atol=1e-9)


@pytest.mark.parametrize(
    ("points", "bearings", "match"),
    [(np.zeros((5, 2)), np.zeros((5, 2)), "must both be"), (np.zeros((2, 3)), np.ones((2, 3)), "at least 3"),
     (np.ones((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1)), "parallel"),
     (np.ones((4, 3)), np.full((4, 3), np.nan), "non-finite")],
)  # fmt: skip
def test_bad_input_raises(points: np.ndarray, bearings: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        upnp(points, bearings)
