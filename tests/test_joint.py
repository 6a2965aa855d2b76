"""Tests of the sessions strategy (rigid, drift, moved mount) of the estimation core (the rig's:
test_rig_solve.py)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from synthetic_graph import session_frames
from test_lidar_errors import CAMERA as LIDAR_CAMERA
from test_lidar_errors import lidar_frames

from ilcc_graph.board import Board
from ilcc_graph.cameras import Equirectangular
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation import NoiseOptions, solve, solve_problem
from ilcc_graph.estimation.lidar_errors import LidarLayout, merge_layouts
from ilcc_graph.estimation.problem import frames_problem
from ilcc_graph.estimation.selection import AUTO
from ilcc_graph.estimation.sessions import JointOptions, Session, compare_estimates, solve_sessions
from ilcc_graph.types import Estimate

PANO = Equirectangular(8000, 4000)
PANO_SMALL = Equirectangular(4000, 2000)
BOARD = Board(6, 8, 0.075)
BOARD_B = Board(5, 7, 0.1, margin_long=0.05, margin_short=0.03)
T_TRUE = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.03, -0.05, 0.07), np.array([0.05, -0.03, -0.25]))


def nees(est: Estimate, T: gtsam.Pose3) -> float:
    xi = est.pose.localCoordinates(T)
    return float(xi @ np.linalg.solve(est.covariance, xi))


def moved(T: gtsam.Pose3, deg: float, mm: float, rng: np.random.Generator) -> gtsam.Pose3:
    """``T`` turned by ``deg`` about a random axis and shifted ``mm`` in a random direction."""
    a, t = rng.normal(size=3), rng.normal(size=3)
    xi = np.concatenate([np.radians(deg) * a / np.linalg.norm(a), 1e-3 * mm * t / np.linalg.norm(t)])
    return T.compose(gtsam.Pose3.Expmap(xi))


def three_sessions(
    rng: np.random.Generator, T_by_session=(T_TRUE, T_TRUE, T_TRUE), n: int = 10
) -> list[Session]:
    """Three sessions with different boards and intrinsics (panoramas of two sizes)."""
    setups = [("A", PANO, BOARD), ("B", PANO_SMALL, BOARD_B), ("C", PANO, BOARD_B)]
    out = []
    for (name, cam, board), T in zip(setups, T_by_session):
        frames, _ = session_frames(
            rng, n, cam, T, board, prefix=f"{name}_", sigma_px=0.5 if cam is PANO else 0.3
        )
        out.append(Session(name, frames, cam, board=board))
    return out


def test_one_session_is_the_batch_strategy() -> None:
    rng = np.random.default_rng(1)
    s = three_sessions(rng)[0]
    T0 = T_TRUE.compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6))).matrix()
    joint = solve_sessions([Session(s.name, s.frames, s.camera, T0)])
    ref = solve(s.frames, s.camera, T0)
    d = np.sqrt(np.diag(ref.covariance))
    xi = gtsam.Pose3(ref.T_cam_lidar).localCoordinates(joint.joint.pose)
    assert np.all(np.abs(xi) < 1e-6 * d)
    assert np.all(np.abs(np.sqrt(np.diag(joint.joint.covariance)) / d - 1) < 1e-6)
    assert joint.components["A"] == ref.variance_components


def test_alone_is_the_session_under_the_joint_noise() -> None:
    rng = np.random.default_rng(1)
    sessions = three_sessions(rng)
    sol = solve_sessions(sessions)
    for s in sessions:
        # the joint graph names its boards "<session>/<frame>", the session's own graph "<frame>"
        comps = {
            (k, g.replace(f"{s.name}|{s.name}/", f"{s.name}|")): v
            for (k, g), v in sol.scales.items()
            if g == s.name or g.startswith(s.name + "|")
        }
        assert ("board", s.name) in comps and sum(k[0] == "bearing" for k in comps) == len(s.frames)
        uncertain = {
            (k, g.replace(f"{s.name}|{s.name}/", f"{s.name}|")): r
            for (k, g), r in sol.uncertain.items()
            if g == s.name or g.startswith(s.name + "|")
        }
        problem = frames_problem(s.frames, s.camera, sol.alone[s.name].T, group=s.name)
        kept = [f.name for f in s.frames if f.name not in dict(sol.dropped[s.name])]
        ref = solve_problem(
            problem, boards=kept, scales=comps, variance_factor=1.0, gate=False, uncertain=uncertain
        ).extrinsic(0)
        assert np.abs(ref.T - sol.alone[s.name].T).max() < 1e-9
        d = np.sqrt(np.diag(ref.covariance))
        assert np.abs(ref.covariance - sol.alone[s.name].covariance).max() < 1e-6 * d.max() ** 2


def test_rigid_sessions_with_different_boards_agree_and_shrink() -> None:
    rng = np.random.default_rng(2)
    sol = solve_sessions(three_sessions(rng))
    assert sol.mode == "rigid" and sol.moved is None
    assert not sol.global_test.moved and sol.global_test.dof == 12
    assert all(not t.moved for t in sol.session_tests + sol.pair_tests)
    assert nees(sol.joint, T_TRUE) < 16.8  # chi2(6) 99 %
    for name, alone in sol.alone.items():
        assert np.array_equal(sol.sessions[name].T, sol.joint.T)
        assert np.all(sol.joint.sigmas < alone.sigmas)
    # information adds: the joint information is about the sum of the three
    info_sum = sum(np.linalg.inv(a.covariance) for a in sol.alone.values())
    ratio = np.sqrt(np.diag(np.linalg.inv(info_sum))) / sol.joint.sigmas
    assert np.all(np.abs(ratio - 1) < 0.1)


def test_moved_mount_is_detected_and_located() -> None:
    rng = np.random.default_rng(3)
    T_moved = moved(T_TRUE, 0.5, 10.0, rng)
    sessions = three_sessions(rng, (T_TRUE, T_moved, T_moved))
    sol = solve_sessions(sessions)
    assert sol.global_test.moved and sol.global_test.p_value < 1e-6
    by_pair = {t.label: t for t in sol.pair_tests}
    assert by_pair["A -> B"].moved and not by_pair["B -> C"].moved
    jump = by_pair["A -> B"]
    assert jump.rotation_deg == pytest.approx(0.5, abs=0.1)
    assert jump.translation_mm == pytest.approx(10.0, abs=4.0)
    assert sol.moved == "A"  # the odd one out of A | B, C
    worst = max(sol.session_tests, key=lambda t: t.mahalanobis)
    assert worst.session == "A" and worst.p_value < 1e-6


def test_drift_mode_follows_each_session() -> None:
    rng = np.random.default_rng(4)
    T_b = moved(T_TRUE, 0.5, 10.0, rng)
    sessions = three_sessions(rng, (T_TRUE, T_b, T_TRUE), n=6)
    loose = solve_sessions(sessions, JointOptions(mode="drift", drift_sigma_deg=2.0, drift_sigma_mm=50.0))
    truth = {"A": T_TRUE, "B": T_b, "C": T_TRUE}
    for name, est in loose.sessions.items():
        assert nees(est, truth[name]) < 22.5  # chi2(6) 99.9 %
    assert loose.moved == "B"
    tight = solve_sessions(sessions, JointOptions(mode="drift", drift_sigma_deg=1e-4, drift_sigma_mm=1e-3))
    rigid = solve_sessions(sessions, JointOptions(mode="rigid"))
    xi = rigid.joint.pose.localCoordinates(tight.joint.pose)
    assert np.all(np.abs(xi) < 0.05 * rigid.joint.sigmas)
    chain = solve_sessions(sessions, JointOptions(mode="drift", drift_tie="chain", drift_sigma_deg=2.0))
    assert np.array_equal(chain.joint.T, chain.sessions["C"].T)


def test_shared_range_offset_across_sessions() -> None:
    rng = np.random.default_rng(5)
    sessions = []
    for name, cam, board in (("A", PANO, BOARD), ("B", PANO_SMALL, BOARD_B)):
        frames, _ = session_frames(rng, 10, cam, T_TRUE, board, range_offset_m=0.03, prefix=name)
        sessions.append(Session(name, frames, cam, board=board, lidar="vlp16"))
    sol = solve_sessions(sessions, JointOptions(range_offset=True))
    ro = sol.range_offsets["vlp16"]
    assert abs(ro.value_m - 0.03) < 3 * ro.sigma_m and ro.sigma_m < 2e-3
    assert nees(sol.joint, T_TRUE) < 16.8


def test_bad_input() -> None:
    rng = np.random.default_rng(6)
    s = three_sessions(rng, n=4)
    with pytest.raises(ValueError, match="mode"):
        solve_sessions(s, JointOptions(mode="loose"))
    with pytest.raises(ValueError, match="unique"):
        solve_sessions([s[0], s[0]])
    with pytest.raises(CalibrationImpossible):
        solve_sessions([Session("E", [], PANO)])
    single = solve_sessions(s[:1], JointOptions(noise=NoiseOptions(chi2_gate_prob=None)))
    assert single.global_test is None and single.session_tests == [] and single.pair_tests == []


def test_compare_estimates_is_consistent_for_independent_draws() -> None:
    """Mahalanobis distance of two independent draws around one pose: mean ~ 6 (chi2 with 6 dof)."""
    rng = np.random.default_rng(10)
    T = gtsam.Pose3.Expmap(rng.normal(0, 1, 6))
    Pa = np.diag([1e-4, 2e-4, 1e-4, 4e-4, 1e-4, 2e-4])
    Pb = np.diag([3e-4, 1e-4, 2e-4, 1e-4, 5e-4, 1e-4])
    m = []
    for _ in range(400):
        Ta = T.compose(gtsam.Pose3.Expmap(rng.multivariate_normal(np.zeros(6), Pa)))
        Tb = T.compose(gtsam.Pose3.Expmap(rng.multivariate_normal(np.zeros(6), Pb)))
        d, C = compare_estimates(Estimate(Ta.matrix(), Pa), Estimate(Tb.matrix(), Pb))
        m.append(d @ np.linalg.solve(C, d))
    assert 5.4 < np.mean(m) < 6.6


def test_summary_and_terminal_report_of_a_moved_mount() -> None:
    import yaml

    from ilcc_graph.report.text import format_joint
    from ilcc_graph.run.strategies.solve_sessions import joint_summary

    rng = np.random.default_rng(11)
    sessions = three_sessions(rng, (T_TRUE, T_TRUE, moved(T_TRUE, 0.5, 10.0, rng)), n=6)
    sol = solve_sessions(sessions, JointOptions(mode="drift"))
    summary = yaml.safe_load(yaml.safe_dump(yaml.safe_load(yaml.safe_dump(_plain(joint_summary(sol))))))
    assert summary["consistency"]["moved"] == "C" and summary["mode"] == "drift"
    assert np.allclose(summary["joint"]["T_cam_lidar"], sol.joint.T)
    assert set(summary["sessions"]) == {"A", "B", "C"}
    text = format_joint(joint_summary(sol))
    assert "MOVED" in text and "session C" in text and "rx ry rz" in text
    assert summary["consistency"]["global"]["kind"] == "global"
    assert [t.kind for t in sol.session_tests] == ["session"] * 3 and sol.pair_tests[0].kind == "pair"


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return x.tolist() if isinstance(x, np.ndarray) else x


def test_repeatability_widens_the_tests() -> None:
    rng = np.random.default_rng(14)
    sessions = three_sessions(rng, (T_TRUE, moved(T_TRUE, 0.05, 1.0, rng), T_TRUE), n=6)
    strict = solve_sessions(sessions)
    loose = solve_sessions(sessions, JointOptions(repeatability_deg=0.1, repeatability_mm=3.0))
    assert np.array_equal(strict.joint.T, loose.joint.T)
    for a, b in zip(strict.session_tests + strict.pair_tests, loose.session_tests + loose.pair_tests):
        assert b.mahalanobis < a.mahalanobis and np.allclose(a.delta, b.delta)
    assert loose.global_test.mahalanobis < strict.global_test.mahalanobis
    assert strict.global_test.moved and not loose.global_test.moved
    with pytest.raises(ValueError, match="repeatability"):
        solve_sessions(sessions, JointOptions(repeatability_mm=-1.0))


@pytest.mark.parametrize("seed, beam_sd, averaged", [(7, 0.001, True), (0, 0.004, False)])
def test_one_capture_twice_is_that_capture_under_the_model_it_chooses(
    seed: int, beam_sd: float, averaged: bool
) -> None:
    """Sessions choose the sensor model as the batch does; one capture given twice is the batch's
    answer: the LiDAR's terms shared, each session bringing their prior (issue 34)."""
    rng = np.random.default_rng(seed)
    offsets = 0.02 + rng.normal(0, beam_sd, 16)  # the unit reads ~20 mm long, each beam its own way
    frames, _ = lidar_frames(rng, 10, offsets)
    T0 = T_TRUE.compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6))).matrix()
    ref = solve(frames, LIDAR_CAMERA, T0, models=AUTO)
    # seed 7 at 1 mm: range chosen (w 0.82) and beams weighs, the covariance carries both; seed 0 at
    # 4 mm: range alone, its covariance times its held-out factor (1.34)
    assert ref.selection.averaged == averaged
    twice = [Session(n, frames, LIDAR_CAMERA, T0) for n in "AB"]
    sol = solve_sessions(twice, JointOptions(models=AUTO))
    assert sol.selection is not None and sol.selection.chosen == ref.selection.chosen != "none"
    d = np.sqrt(np.diag(ref.covariance))
    for est in (sol.joint, sol.alone["A"], sol.alone["B"]):  # 1e-7 rad and m: doors.py asks 1e-6
        assert np.all(np.abs(gtsam.Pose3(ref.T_cam_lidar).localCoordinates(est.pose)) < 1e-7)
    for n in "AB":  # alone: the batch's answer, its covariance averaged over the models as there
        assert np.all(np.abs(np.sqrt(np.diag(sol.alone[n].covariance)) / d - 1) < 1e-6)
    # "the others" of A is B with B's own prior on the LiDAR's terms: B alone, so A agrees with it
    assert all(t.mahalanobis < 1e-9 for t in sol.session_tests), [t.mahalanobis for t in sol.session_tests]
    z = (sol.lidar_errors["lidar"][1] - ref.lidar[1]) / ref.lidar[2]
    assert np.all(np.abs(z) < 1e-5), z  # in their sigmas: the solver stops at ~1e-6


def test_merged_layout_enters_what_some_session_determined_with_the_prior_once_per_session() -> None:
    a = LidarLayout(beams=(1, 2), dark=True, excluded=(("beam 3", "few"), ("offset[4]", "weak")))
    b = LidarLayout(beams=(2, 3), excluded=(("beam 1", "few"), ("offset[4]", "weak")))
    m = merge_layouts([a, b])
    assert m.beams == (1, 2, 3) and m.dark and dict(m.excluded) == {"offset[4]": "weak"}
    assert np.allclose(m.prior_sigmas(), a.prior_sigmas()[[0, 1, 1, 2]] / np.sqrt(2))
    assert merge_layouts([a]) is a
