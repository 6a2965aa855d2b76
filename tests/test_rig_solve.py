"""The rig in one graph (issue 24): the start from the stages' answers (poses, half turns), the joint
solve (NEES per pair, one pair = today's batch, boards only cameras or only LiDARs saw), verify.

Graph-level synthetic rigs (``synthetic_graph.rig_moments``): each observation drawn from its stated
covariance, its corner order half-turned at random; and one small simulated rig end to end.
"""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import pytest
from scipy.special import chdtri, chndtr
from synthetic_graph import observe, rig_moments
from test_lidar_errors import BOARD as LIDAR_BOARD
from test_lidar_errors import CAMERA as LIDAR_CAMERA
from test_lidar_errors import T_TRUE, lidar_frames

from ilcc_graph.board import Board
from ilcc_graph.cameras import Pinhole
from ilcc_graph.config import Config
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation import NoiseOptions, solve
from ilcc_graph.estimation.rig_solve import RigOptions, between, solve_rig, to_reference
from ilcc_graph.estimation.selection import AUTO
from ilcc_graph.estimation.verify import StoredRig, detectable_change, verify_rig
from ilcc_graph.init.rig_start import RigStart, place_boards, rig_start
from ilcc_graph.run.prepare import prepare
from ilcc_graph.types import BoardFit, Estimate, FrameResult, GraphFrame, ImageCorners, MomentResult

BOARD = Board(6, 8, 0.075)
EMPTY = (np.zeros((0, 3)), np.zeros(0))  # a board fit's segment points and intensities, not used
R_CV = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # OpenCV axes from a LiDAR's


def pinhole(width: int = 1280, height: int = 960, hfov_deg: float = 110.0) -> Pinhole:
    f = 0.5 * width / np.tan(np.radians(hfov_deg) / 2)
    K = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return Pinhole(width, height, K, np.array([-0.02, 0.004, 0.0, 0.0, 0.0]))


def ring(n: int = 4, hfov_deg: float = 110.0) -> tuple[dict[str, Pinhole], dict[str, gtsam.Pose3]]:
    """Cameras looking out every 360/n degrees, 10 cm off the base LiDAR's axis, 20 cm up:
    (models, ``T_cam_base``)."""
    cams, poses = {}, {}
    for k in range(n):
        yaw = 2 * np.pi * k / n
        R = (
            R_CV
            @ gtsam.Rot3.Rz(yaw).matrix().T
            @ gtsam.Rot3.Expmap(np.radians([1.0, -2.0, 1.5 * k])).matrix()
        )
        c = np.array([0.1 * np.cos(yaw), 0.1 * np.sin(yaw), 0.2])
        cams[f"cam{k}"], poses[f"cam{k}"] = pinhole(hfov_deg=hfov_deg), gtsam.Pose3(gtsam.Rot3(R), -R @ c)
    return cams, poses


#: a second LiDAR 30 cm behind and 15 cm above the base, turned 100 deg left and tipped
REAR = gtsam.Pose3(
    gtsam.Rot3.Ypr(np.radians(100.0), np.radians(4.0), np.radians(-2.0)), np.array([-0.3, 0.0, 0.15])
)


def true_poses(T_cam_base: dict, T_base_lidar: dict) -> dict[str, np.ndarray]:
    """``T_base_s`` of every sensor (the base LiDAR first)."""
    out = {n: np.asarray(T.matrix()) for n, T in T_base_lidar.items()}
    out.update({n: np.asarray(T.inverse().matrix()) for n, T in T_cam_base.items()})
    return out


def error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    xi = gtsam.Pose3(T_est).localCoordinates(gtsam.Pose3(T_true))
    return float(np.degrees(np.linalg.norm(xi[:3]))), float(1e3 * np.linalg.norm(xi[3:]))


def nees(est: Estimate, T_true: np.ndarray) -> float:
    xi = gtsam.Pose3(est.T).localCoordinates(gtsam.Pose3(T_true))
    return float(xi @ np.linalg.solve(est.covariance, xi))


def solve_all(moments, cams, lidars, reference=None, options=RigOptions(), truth=None):  # noqa: ANN001, ANN201
    """The start (from the data, or with the ``truth``'s poses) and the solve."""
    if truth is None:
        start = rig_start(moments, BOARD, list(lidars), list(cams))
    else:
        base = next(iter(lidars))
        start = RigStart(base, truth, *place_boards(moments, truth, BOARD, base))
    return start, solve_rig(moments, start, BOARD, list(lidars), cams, reference, options)


# ------------------------------------------------------------------------------------ the start
def test_start_recovers_poses_and_half_turns() -> None:
    rng = np.random.default_rng(20)
    cams, T_cb = ring(4)
    lidars = {"top": gtsam.Pose3(), "rear": REAR}
    moments, _ = rig_moments(rng, 16, cams, T_cb, BOARD, lidars)
    start = rig_start(moments, BOARD, list(lidars), list(cams))
    assert not start.unplaced and not start.dropped
    truth = true_poses(T_cb, lidars)
    for s, T in start.T_base_sensor.items():
        rot, trans = error(T, truth[s])
        assert rot < 1.0 and trans < 50.0, (s, rot, trans)  # a start, well inside the solve's reach
    # every observation's order agrees with the moment's board: its corners where the truth puts them
    perm = BOARD.half_turn_permutation()
    for m in moments:
        flips = start.flips[m.name]
        assert set(flips) == set(m.sensors)
        T_board = start.T_base_board[m.name]
        for s, fit in m.boards.items():
            c = fit.corners_lidar[perm] if flips[s] else fit.corners_lidar
            p = BOARD.corners_board() @ T_board[:3, :3].T + T_board[:3, 3]
            q = c @ truth[s][:3, :3].T + truth[s][:3, 3]
            assert np.sqrt(np.mean(np.sum((p - q) ** 2, axis=1))) < 0.05
        if "top" in m.boards:
            assert not flips["top"]  # the board's frame is the base LiDAR's fit
    kinds = {(lk.a, lk.b): lk for lk in start.links}
    assert kinds[("top", "rear")].kind == "lidar-lidar" and kinds[("top", "rear")].agreeing >= 2


def test_start_drops_an_observation_that_fits_neither_order() -> None:
    rng = np.random.default_rng(21)
    cams, T_cb = ring(2)
    moments, _ = rig_moments(rng, 12, cams, T_cb, BOARD)
    k = next(i for i, m in enumerate(moments) if "cam0" in m.corners)
    c = moments[k].corners["cam0"]
    turn = gtsam.Rot3.Expmap(np.array([0.0, 0.15, 0.0]))  # the camera's corners 0.15 rad off
    bad = replace(c, bearings=np.array([turn.rotate(b) for b in c.bearings]))
    moments[k] = replace(moments[k], corners={**moments[k].corners, "cam0": bad})
    start = rig_start(moments, BOARD, ["lidar"], list(cams))
    assert [(m, s) for m, s, _ in start.dropped] == [(moments[k].name, "cam0")]
    assert "inconsistent" in start.dropped[0][2]


# ------------------------------------------------------------------------------------ the solve
def test_joint_solve_is_consistent_for_every_pair() -> None:
    """NEES of every pair's relative pose over 12 rigs (6 expected; 90 draws per pair pooled)."""
    cams, T_cb = ring(4)
    lidars = {"top": gtsam.Pose3(), "rear": REAR}
    truth = true_poses(T_cb, lidars)
    names = list(truth)
    values: dict[tuple[str, str], list[float]] = {}
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        moments, _ = rig_moments(rng, 24, cams, T_cb, BOARD, lidars)
        _, sol = solve_all(moments, cams, lidars, reference="cam1", truth=truth)
        assert sol.reference == "cam1" and np.allclose(sol.T_ref_sensor["cam1"], np.eye(4))
        assert np.allclose(sol.joint(["cam1"]), 0.0)
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                values.setdefault((a, b), []).append(
                    nees(sol.relative(a, b), np.linalg.solve(truth[a], truth[b]))
                )
    means = {k: float(np.mean(v)) for k, v in values.items()}
    pooled = float(np.mean(list(means.values())))
    assert 4.8 < pooled < 7.5, means
    assert all(2.5 < v < 11.0 for v in means.values()), means


def test_one_camera_and_one_lidar_is_the_batch() -> None:
    rng = np.random.default_rng(22)
    cams, T_cb = ring(1, hfov_deg=120.0)
    moments, _ = rig_moments(rng, 10, cams, T_cb, BOARD)
    _, sol = solve_all(moments, cams, {"lidar": None}, options=RigOptions(models=("none",)))
    assert sol.selection is not None and sol.selection.forced and sol.selection.chosen == "none"
    pair = [
        FrameResult(m.name, True, None, m.boards["lidar"], m.corners["cam0"])
        for m in moments
        if "lidar" in m.boards and "cam0" in m.corners
    ]
    prep = prepare(pair, Config(BOARD, None, cams["cam0"]))
    ref = solve(prep.frames, cams["cam0"], prep.T_init, models=["none"])
    est = sol.relative("cam0", "lidar")
    assert np.allclose(est.T, ref.T_cam_lidar, atol=1e-9)
    # the variance components are iterated to a fixed point from each graph's own start (the rig's
    # start, the pair's UPnP): they meet to about 2e-7 relative (1.2618232 against 1.2618235 measured
    # on this machine), and every covariance scales with them; a different graph differs by far more
    assert np.allclose(est.covariance, ref.covariance, rtol=1e-6, atol=1e-14)
    assert sol.variance_factor == ref.variance_factor and len(sol.T_base_board) == len(ref.T_lidar_board)


def test_one_camera_and_one_lidar_choose_the_model_as_the_batch() -> None:
    """Boards with returns of a LiDAR reading 20 mm long, each beam its own way: the rig chooses
    among the pair's default models (``selection.AUTO``) as the batch does, to the same answer and
    covariance; forced to ``none`` it is the biased answer the choice avoids."""
    rng = np.random.default_rng(33)
    frames, truth_boards = lidar_frames(rng, 10, 0.02 + rng.normal(0, 0.004, 16))
    flat = {"lidar": gtsam.Pose3()}

    def fit(f: GraphFrame) -> BoardFit:
        corners = f.points_board @ f.T_lidar_board[:3, :3].T + f.T_lidar_board[:3, 3]
        return BoardFit(f.T_lidar_board, f.board_cov, corners, *EMPTY, False, returns=f.returns)

    def view(f: GraphFrame) -> ImageCorners:
        return ImageCorners(LIDAR_CAMERA.project(f.bearings), f.bearings, f.cov_px, False)

    moments = [MomentResult(f.name, {"lidar": fit(f)}, {"cam0": view(f)}) for f in frames]
    truth = true_poses({"cam0": T_TRUE}, flat)
    start = RigStart("lidar", truth, *place_boards(moments, truth, LIDAR_BOARD, "lidar"))
    cams = {"cam0": LIDAR_CAMERA}
    sol = solve_rig(moments, start, LIDAR_BOARD, ["lidar"], cams)
    ref = solve(frames, LIDAR_CAMERA, T_TRUE.matrix(), models=AUTO)
    assert sol.selection.chosen == ref.selection.chosen != "none" and not sol.selection.forced
    for a, b in zip(sol.selection.candidates, ref.selection.candidates, strict=True):
        assert a.name == b.name and a.boards == b.boards == 10
        x, y = ([c.log_density, c.chi2, c.weight, c.factor] for c in (a, b))
        assert np.allclose(x, y, rtol=1e-7, atol=1e-12), (a, b)
    est = sol.relative("cam0", "lidar")
    assert np.allclose(est.T, ref.T_cam_lidar, atol=1e-9)
    assert np.allclose(est.covariance, ref.covariance, rtol=1e-7, atol=1e-14)
    assert nees(est, T_TRUE.matrix()) < 16.8  # chi2(6) 99 %
    forced = solve_rig(moments, start, LIDAR_BOARD, ["lidar"], cams, options=RigOptions(models=("none",)))
    assert nees(forced.relative("cam0", "lidar"), T_TRUE.matrix()) > 30.0
    # a second camera seeing every board: each camera's views are held out in turn
    T_cam1 = gtsam.Pose3(gtsam.Rot3.Rz(0.4), np.array([0.2, 0.1, 0.0])).compose(T_TRUE)
    seen = [
        observe(rng, LIDAR_CAMERA, T_cam1, truth_boards[f.name], LIDAR_BOARD.corners_board()) for f in frames
    ]
    both = [
        replace(m, corners={**m.corners, "cam1": ImageCorners(LIDAR_CAMERA.project(b), b, c, False)})
        for m, (b, c) in zip(moments, seen, strict=True)  # type: ignore[misc]
    ]
    truth2 = true_poses({"cam0": T_TRUE, "cam1": T_cam1}, flat)
    start2 = RigStart("lidar", truth2, *place_boards(both, truth2, LIDAR_BOARD, "lidar"))
    two = solve_rig(both, start2, LIDAR_BOARD, ["lidar"], {**cams, "cam1": LIDAR_CAMERA})
    chosen = next(c for c in two.selection.candidates if c.name == two.selection.chosen)
    assert two.selection.chosen != "none" and chosen.boards == 20, two.selection.summary()
    assert chosen.chi2 < 2 * 6 * chosen.boards  # each view scored against its own camera's image
    for c in ("cam0", "cam1"):
        assert nees(two.relative(c, "lidar"), np.linalg.inv(truth2[c])) < 16.8


def test_one_camera_and_one_lidar_refine_the_intrinsics_as_the_batch() -> None:
    """Stated focal lengths 2 % off and 16 boards: the rig's one solve refines the camera's
    intrinsics as the batch does (``camera_choice``, the pair's ``auto``), to the same answer,
    intrinsics and covariance; stated as asked, it keeps them."""
    from test_selection import _pinhole_frames

    frames, stated, T_cl = _pinhole_frames(7, 1.02, n=16)
    board = Board(6, 8, 0.095)  # _pinhole_frames' board
    assert np.allclose(board.corners_board(), frames[0].points_board)

    def fit(f: GraphFrame) -> BoardFit:
        corners = f.points_board @ f.T_lidar_board[:3, :3].T + f.T_lidar_board[:3, 3]
        return BoardFit(f.T_lidar_board, f.board_cov, corners, *EMPTY, False)

    moments = [
        MomentResult(f.name, {"lidar": fit(f)}, {"cam0": ImageCorners(f.uv, f.bearings, f.cov_px, False)})
        for f in frames
    ]
    truth = true_poses({"cam0": T_cl}, {"lidar": gtsam.Pose3()})
    start = RigStart("lidar", truth, *place_boards(moments, truth, board, "lidar"))
    cams = {"cam0": stated}
    auto = RigOptions(intrinsics_choice="auto")
    sol = solve_rig(moments, start, board, ["lidar"], cams, options=auto)
    ref = solve(frames, stated, T_cl.matrix(), models=AUTO, intrinsics_choice="auto")
    assert ref.selection.camera is not None and ref.selection.camera.refined, ref.selection.camera
    assert sol.selection.camera == ref.selection.camera
    est = sol.relative("cam0", "lidar")
    assert np.allclose(est.T, ref.T_cam_lidar, atol=1e-9)
    assert np.allclose(est.covariance, ref.covariance, rtol=1e-6, atol=1e-14)
    got = sol.intrinsics("cam0")
    assert got is not None and ref.intrinsics is not None
    assert list(got.names) == ref.intrinsics[0] and np.array_equal(got.stated, stated.intrinsics())
    assert np.allclose(got.values, ref.intrinsics[1], rtol=1e-9)
    assert np.allclose(got.sigmas, ref.intrinsics[2], rtol=1e-6)
    kept = solve_rig(moments, start, board, ["lidar"], cams)  # RigOptions' default: as stated
    assert kept.selection.camera is None and kept.intrinsics("cam0") is None


def test_cameras_stated_alike_are_two_lenses() -> None:
    """Two cameras of one rig stated with the same model: refined, each gets its own intrinsics
    (``View.lens``), not one set shared as sessions of one camera share theirs."""
    from ilcc_graph.estimation.intrinsics import IntrinsicsOptions

    rng = np.random.default_rng(5)
    cams, T_cb = ring(2, hfov_deg=120.0)
    assert cams["cam0"] == cams["cam1"]
    moments, _ = rig_moments(rng, 24, cams, T_cb, BOARD)
    refine = RigOptions(models=("none",), intrinsics=IntrinsicsOptions(refine=True))
    _, sol = solve_all(moments, cams, {"lidar": None}, options=refine)
    got = [sol.intrinsics(c) for c in cams]
    assert all(g is not None for g in got)
    assert sol.solution is not None and len(sol.solution.assembly.cameras) == 2
    assert not np.allclose(got[0].values, got[1].values)  # type: ignore[union-attr]
    _, stated = solve_all(moments, cams, {"lidar": None}, options=RigOptions(models=("none",)))
    assert all(stated.intrinsics(c) is None for c in cams)


def test_each_camera_of_a_rig_is_judged_as_a_pair_judges_its_camera() -> None:
    """Two cameras, one stated with its focal lengths 2 % off, the other right, 20 boards each: with
    ``auto`` the rig refines the first one's intrinsics only (each camera judged alone, the others as
    stated, as a pair judges its camera), and both poses are honest; as stated, the first is not."""
    rng = np.random.default_rng(8)
    cams, T_cb = ring(2, hfov_deg=120.0)
    moments, _ = rig_moments(rng, 40, cams, T_cb, BOARD, min_views=1)
    seen = {c: sum(c in m.corners for m in moments) for c in cams}
    assert min(seen.values()) >= 18, seen
    true0 = cams["cam0"]
    theta = true0.intrinsics()
    off = true0.with_intrinsics(np.concatenate([theta[:2] * 1.02, theta[2:]]))
    stated_moments = []  # cam0's bearings as its stated (wrong) intrinsics give them
    for m in moments:
        if (c0 := m.corners.get("cam0")) is not None:
            m = replace(m, corners={**m.corners, "cam0": replace(c0, bearings=off.bearing(c0.uv))})
        stated_moments.append(m)
    stated = {"cam0": off, "cam1": cams["cam1"]}
    truth = true_poses(T_cb, {"lidar": gtsam.Pose3()})
    start = RigStart("lidar", truth, *place_boards(stated_moments, truth, BOARD, "lidar"))
    opts = RigOptions(intrinsics_choice="auto")
    auto = solve_rig(stated_moments, start, BOARD, ["lidar"], stated, options=opts)
    choice = auto.selection.camera
    assert choice is not None and choice.refined and "cam0: the boards move them" in choice.reason, choice
    assert auto.intrinsics("cam0") is not None and auto.intrinsics("cam1") is None
    for c in cams:
        assert nees(auto.relative(c, "lidar"), np.linalg.inv(truth[c])) < 16.8, c
    kept = solve_rig(stated_moments, start, BOARD, ["lidar"], stated)
    assert nees(kept.relative("cam0", "lidar"), np.linalg.inv(truth["cam0"])) > 16.8


def test_a_board_only_two_cameras_saw_chains_them() -> None:
    """cam1 never sees a board with the LiDAR: it is placed and solved through cam0's boards."""
    rng = np.random.default_rng(23)
    cams, T_cb = ring(2, hfov_deg=120.0)
    T_cb["cam1"] = T_cb["cam0"].compose(gtsam.Pose3(gtsam.Rot3.Ry(0.5), np.array([0.3, 0.0, 0.0])))
    shared, _ = rig_moments(rng, 8, cams, T_cb, BOARD, min_views=2, lidar_sees=lambda k, n: False)
    alone, _ = rig_moments(rng, 10, {"cam0": cams["cam0"]}, T_cb, BOARD)
    moments = [replace(m, name=f"s{m.name}") for m in shared] + alone
    start, sol = solve_all(moments, cams, {"lidar": None})
    assert ("cam0", "cam1") in start.tree and not sol.dropped
    truth = true_poses(T_cb, {"lidar": gtsam.Pose3()})
    for s in ("cam0", "cam1"):
        assert nees(sol.pose(s), truth[s]) < 22.5
    assert nees(sol.relative("cam0", "cam1"), np.linalg.solve(truth["cam0"], truth["cam1"])) < 22.5
    assert sum(1 for b in sol.solution.problem.boards if b.covariance is None) == 8


def test_boards_only_lidars_saw_tie_the_lidars() -> None:
    """Half of the boards are seen by the two LiDARs alone (no camera): they are kept and tighten the
    LiDAR-LiDAR pose."""
    rng = np.random.default_rng(24)
    cams, T_cb = ring(1, hfov_deg=120.0)
    lidars = {"top": gtsam.Pose3(), "rear": REAR}
    with_cam, _ = rig_moments(rng, 8, cams, T_cb, BOARD, lidars, lidar_sees=lambda k, n: True)
    no_cam, _ = rig_moments(rng, 8, {}, {}, BOARD, lidars, min_views=0, lidar_sees=lambda k, n: True)
    moments = with_cam + [replace(m, name=f"l{m.name}") for m in no_cam]
    _, both = solve_all(moments, cams, lidars)
    _, some = solve_all(with_cam, cams, lidars)
    assert not both.dropped and len(both.T_base_board) == 16
    truth = true_poses(T_cb, lidars)
    assert nees(both.pose("rear"), truth["rear"]) < 22.5
    assert np.trace(both.pose("rear").covariance) < 0.8 * np.trace(some.pose("rear").covariance)


def test_between_and_reference_frames() -> None:
    rng = np.random.default_rng(25)
    Ta, Tb = gtsam.Pose3.Expmap(rng.normal(0, 1, 6)), gtsam.Pose3.Expmap(rng.normal(0, 1, 6))
    C = np.cov(rng.normal(size=(12, 40)))
    H1, H2, Hi = (np.zeros((6, 6), order="F") for _ in range(3))
    Ta.inverse(Hi).compose(Tb, H1, H2)
    J = np.hstack([H1 @ Hi, H2])  # T_a^-1 T_b, GTSAM's own derivatives
    est = between(Ta.matrix(), Tb.matrix(), C)
    assert np.allclose(est.T, Ta.between(Tb).matrix())
    assert np.allclose(est.covariance, J @ C @ J.T, atol=1e-10)
    # re-expressing in another sensor's frame keeps every relative pose and its covariance
    T_base = {"a": np.eye(4), "b": Ta.matrix(), "c": Tb.matrix()}
    Cb = np.zeros((18, 18))
    Cb[6:, 6:] = np.cov(rng.normal(size=(12, 40)))
    T_ref, C_ref = to_reference(T_base, Cb, "c")
    assert np.allclose(T_ref["c"], np.eye(4)) and np.allclose(C_ref[12:, 12:], 0.0, atol=1e-15)
    e1 = between(T_base["a"], T_base["b"], Cb[:12, :12])
    e2 = between(T_ref["a"], T_ref["b"], C_ref[:12, :12])
    assert np.allclose(e1.T, e2.T) and np.allclose(e1.covariance, e2.covariance, atol=1e-12)


def test_bad_input() -> None:
    rng = np.random.default_rng(26)
    cams, T_cb = ring(1, hfov_deg=120.0)
    moments, _ = rig_moments(rng, 4, cams, T_cb, BOARD)
    start = rig_start(moments, BOARD, ["lidar"], list(cams))
    with pytest.raises(ValueError, match="base"):
        solve_rig(moments, start, BOARD, ["other", "lidar"], cams)
    lonely = [replace(m, corners={}) for m in moments]
    with pytest.raises(CalibrationImpossible, match="two sensors"):
        solve_rig(lonely, rig_start(lonely, BOARD, ["lidar"], []), BOARD, ["lidar"], {})
    with pytest.raises(ValueError, match="unknown kernel"):
        solve_rig(moments, start, BOARD, ["lidar"], cams, options=RigOptions(noise=NoiseOptions(robust="x")))


def test_range_offset_of_the_base_lidar() -> None:
    rng = np.random.default_rng(29)
    cams, T_cb = ring(3, hfov_deg=120.0)
    moments, _ = rig_moments(rng, 24, cams, T_cb, BOARD, range_offset_m=0.03)
    truth = true_poses(T_cb, {"lidar": gtsam.Pose3()})
    _, sol = solve_all(moments, cams, {"lidar": None}, options=RigOptions(range_offset=True), truth=truth)
    value, sigma = sol.range_offset
    assert abs(value - 0.03) < 3 * sigma and not sol.unsolved
    for s in cams:
        assert nees(sol.pose(s), truth[s]) < 22.5


def test_robust_kernel_limits_bad_corners() -> None:
    """Nine corners 20 mrad off (three in each of three views): Cauchy stays near the clean answer;
    the noise policy's gate drops the three moments instead."""
    rng = np.random.default_rng(28)
    cams, T_cb = ring(2, hfov_deg=120.0)
    clean, _ = rig_moments(rng, 12, cams, T_cb, BOARD, turn=False)
    truth = true_poses(T_cb, {"lidar": gtsam.Pose3()})
    moments, hit = list(clean), []
    turn = gtsam.Rot3.Expmap(np.array([0.0, 0.02, 0.0]))
    for k, m in enumerate(clean):
        cam = next((c for c in m.corners), None)
        if cam is None or len(hit) == 3:
            continue
        b = m.corners[cam].bearings.copy()
        b[[3, 10, 20]] = [turn.rotate(x) for x in b[[3, 10, 20]]]
        moments[k] = replace(m, corners={**m.corners, cam: replace(m.corners[cam], bearings=b)})
        hit.append((m.name, cam))

    def run(ms, noise=NoiseOptions()):  # noqa: ANN001, ANN202
        return solve_all(ms, cams, {"lidar": None}, options=RigOptions(noise=noise), truth=truth)[1]

    ref = run(clean)
    no_gate = NoiseOptions(chi2_gate_prob=None, view_components=False)
    plain, robust = run(moments, no_gate), run(moments, replace(no_gate, robust="cauchy"))
    assert sorted(n for n, _ in run(moments).dropped) == sorted(n for n, _ in hit)
    for s in {c for _, c in hit}:
        d_plain = nees(ref.pose(s), plain.T_ref_sensor[s])
        d_robust = nees(ref.pose(s), robust.T_ref_sensor[s])
        assert d_plain > 5.0 and d_robust < 0.1 * d_plain, (s, d_plain, d_robust)


# ------------------------------------------------------------------------------------ verify
def _moved(T_cam_base: gtsam.Pose3, deg: float = 0.0, mm: float = 0.0) -> gtsam.Pose3:
    """A camera's ``T_cam_base`` after its mount turned ``deg`` about its own y axis and moved
    ``mm`` along its own x axis (``T_base_cam @ delta``)."""
    delta = gtsam.Pose3(gtsam.Rot3.Ry(np.radians(deg)), np.array([1e-3 * mm, 0.0, 0.0]))
    return delta.inverse().compose(T_cam_base)


def _capture(seed: int, cams: dict, T_cb: dict, lidars: dict, per_camera: int = 4) -> list:
    """A short capture: ``per_camera`` boards in front of each camera."""
    rng, out = np.random.default_rng(seed), []
    for c in cams:
        ms, _ = rig_moments(rng, per_camera, {c: cams[c]}, T_cb, BOARD, lidars)
        out += [replace(m, name=f"{c}-{m.name}") for m in ms]
    return out


def test_verify_flags_a_moved_camera_and_passes_the_others() -> None:
    cams, T_cb = ring(2, hfov_deg=120.0)
    lidars = {"top": gtsam.Pose3(), "rear": REAR}
    moments = _capture(30, cams, T_cb, lidars, per_camera=15)
    _, sol = solve_all(moments, cams, lidars, reference="cam0", truth=true_poses(T_cb, lidars))
    stored = StoredRig.from_solution(sol)
    for seed, change in enumerate([None, (1.0, 0.0), (0.0, 40.0), (10.0, 0.0)]):
        T_new = dict(T_cb) if change is None else {**T_cb, "cam1": _moved(T_cb["cam1"], *change)}
        res = verify_rig(stored, _capture(40 + seed, cams, T_new, lidars), BOARD, list(lidars), cams)
        assert set(res.sensors) == {"top", "rear", "cam1"} and res.reference == "cam0"
        verdicts = {s: c.verdict for s, c in res.sensors.items()}
        if change is None:
            assert "fail" not in verdicts.values(), res.sensors
            continue
        assert res.verdict == verdicts["cam1"] == "fail", res.sensors
        assert verdicts["top"] != "fail" and verdicts["rear"] != "fail", res.sensors
        c = res.sensors["cam1"]
        if change[0] == 10.0:  # a gross turn: its boards are far from where the stored poses put them
            assert "disagrees" in c.reason
        else:
            assert c.p_value < res.alpha_sensor and c.boards == 4
            assert abs(c.rotation_deg - change[0]) < 4 * np.degrees(np.sqrt(np.trace(c.covariance[:3, :3])))
            assert abs(c.translation_mm - change[1]) < 4e3 * np.sqrt(np.trace(c.covariance[3:, 3:]))
            assert res.global_test[2] < 0.01


def test_verify_one_pair_and_the_detectable_change() -> None:
    cams, T_cb = ring(1, hfov_deg=120.0)
    moments, _ = rig_moments(np.random.default_rng(31), 16, cams, T_cb, BOARD)
    _, sol = solve_all(moments, cams, {"lidar": None})
    cal = sol.relative("cam0", "lidar")
    stored = StoredRig.pair(cal.T, cal.covariance, "cam0", "lidar")
    assert np.allclose(stored.pose("cam0").covariance, sol.pose("cam0").covariance, atol=1e-14)
    same, _ = rig_moments(np.random.default_rng(32), 5, cams, T_cb, BOARD)
    ok = verify_rig(stored, same, BOARD, ["lidar"], cams)
    assert ok.verdict in ("pass", "warn") and ok.sensors["cam0"].verdict != "fail"
    c = ok.sensors["cam0"]
    axes, rot, trans = detectable_change(c.covariance, ok.alpha_sensor, 0.95)
    assert np.allclose([a.detectable for a in c.axes], np.concatenate([np.degrees(axes[:3]), 1e3 * axes[3:]]))
    # a change of the detectable size along an axis has the noncentrality that gives the power
    W = np.linalg.inv(c.covariance)
    lam = axes[0] ** 2 * W[0, 0]
    q = chdtri(6, ok.alpha_sensor)
    assert abs((1.0 - chndtr(q, 6, lam)) - 0.95) < 1e-6
    assert rot >= axes[:3].min() - 1e-12 and trans >= axes[3:].min() - 1e-12
    unseen = verify_rig(stored, [replace(m, corners={}) for m in same], BOARD, ["lidar"], cams)
    assert unseen.sensors["cam0"].verdict == "warn" and "unchecked" in unseen.sensors["cam0"].reason
    with pytest.raises(ValueError, match="not in the stored"):
        verify_rig(stored, same, BOARD, ["lidar", "rear"], cams)
