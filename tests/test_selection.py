"""The sensor model chosen per run (``estimation.selection``, ``camera_choice``): its score, the
choice in clear cases, the covariance carrying it, the command line writing it."""

from __future__ import annotations

import dataclasses
import math

import gtsam
import numpy as np
import pytest
import yaml
from test_lidar_errors import CAMERA, T_TRUE, lidar_frames, nees

from ilcc_graph.app import main
from ilcc_graph.errors import IndeterminateSystem
from ilcc_graph.estimation import NoiseOptions, solve, solve_problem
from ilcc_graph.estimation import chi2 as chi2_dist
from ilcc_graph.estimation.camera_choice import LIDAR_SUBSETS, subset_problem
from ilcc_graph.estimation.held_out import board_spread, held_out
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.keys import X
from ilcc_graph.estimation.model_solves import select_model
from ilcc_graph.estimation.problem import frames_problem
from ilcc_graph.estimation.selection import (
    MODELS,
    Candidate,
    Selection,
    contradicted,
    mixture,
    range_terms,
)

AUTO = ("none", "range", "beams")


def _frames(seed: int, offsets: np.ndarray, n: int = 8, dark: float = 0.0):  # noqa: ANN202
    rng = np.random.default_rng(seed)
    while True:  # a board between two beams' cones gives no returns: draw again
        try:
            return lidar_frames(rng, n, offsets, dark_offset=dark)[0]
        except ValueError:
            continue


def test_held_out_board_is_the_re_solve_without_its_view() -> None:
    """The held-out step (no re-solve) moves the extrinsic as a re-solve without that board's view
    does (fixed noise; the board's own LiDAR data kept), to a fraction of its sigma."""
    frames = _frames(11, np.zeros(16))
    problem = frames_problem(frames, CAMERA, T_TRUE.matrix())
    sol = solve_problem(problem)
    ho = held_out(sol)
    assert set(ho) == set(sol.boards) and all(h.chi2 > 0 for h in ho.values())
    sigma = np.sqrt(np.diag(sol.extrinsic().covariance))
    names = [b.name for b in problem.boards]
    for k in sol.boards[:3]:
        rest = [names[i] for i in sol.boards if i != k]
        re = solve_problem(
            problem, NoiseOptions(), boards=rest, scales=sol.scales, gate=False, variance_factor=1.0
        )
        moved = np.asarray(sol.values.atPose3(X(0)).localCoordinates(re.values.atPose3(X(0))))
        assert np.all(np.abs(moved - ho[k].shift) < 0.05 * sigma), (moved, ho[k].shift, sigma)
        # its leverage: the share of the extrinsic's information the view takes with it
        C_all = sol.extrinsic().covariance / sol.variance_factor
        lev = 1.0 - np.trace(np.linalg.solve(re.extrinsic().covariance, C_all)) / 6
        assert 0.0 < ho[k].leverage < 1.0 and ho[k].leverage == pytest.approx(lev, abs=0.005), (ho[k], lev)
    # the boards spread the extrinsic as its covariance says (a fixed seed; 1 when honest)
    spread = board_spread(ho, sol.extrinsic().covariance)
    assert 0.4 < spread["hc2"] < 2.5 and 0.4 < spread["jackknife"] < 2.5, spread
    # only the views inform the extrinsic here: their shares sum to all of its information
    assert sum(h.leverage for h in ho.values()) == pytest.approx(1.0, abs=1e-6)


def test_a_range_offset_is_chosen_and_no_error_keeps_none() -> None:
    """Clear cases: a LiDAR reading 20 mm long (no other error) leaves ``none`` no weight and the
    chosen model honest; a LiDAR without errors keeps ``none`` (it predicts the images as well)."""
    frames = _frames(0, np.full(16, 0.02))
    sol = solve(frames, CAMERA, T_TRUE.matrix(), models=AUTO)
    w = {c.name: c.weight for c in sol.selection.candidates}
    assert sol.selection.chosen != "none" and w["none"] < 1e-3, sol.selection.summary()
    assert nees(sol.T_cam_lidar, sol.covariance) < 16.8
    forced = solve(frames, CAMERA, T_TRUE.matrix(), models=("none",))
    assert forced.selection.forced and nees(forced.T_cam_lidar, forced.covariance) > 30  # the wrong model
    for seed in (2, 4):
        sol = solve(_frames(seed, np.zeros(16)), CAMERA, T_TRUE.matrix(), models=AUTO)
        best = max(sol.selection.candidates, key=lambda c: c.weight)
        assert sol.selection.chosen == "none" == best.name and best.weight > 0.5, sol.selection.summary()


def test_the_covariance_carries_the_models_the_boards_cannot_tell_apart() -> None:
    """Two models at equal weight: the covariance about the chosen one holds both covariances and
    their estimates' difference, unless the chosen model contains the other; a decisive choice: the
    chosen model's, times its held-out factor."""
    T0 = np.eye(4)
    T1 = gtsam.Pose3(gtsam.Rot3(), np.array([0.003, 0.0, 0.0])).matrix()
    C0, C1 = np.diag([1e-6] * 3 + [1e-6] * 3), np.diag([4e-6] * 3 + [4e-6] * 3)
    est = {"none": (T0, C0), "range": (T1, C1)}
    even = Selection("none", (Candidate("none", weight=0.5), Candidate("range", weight=0.5)))
    C = mixture(est, even)
    Ad = gtsam.Pose3(T1).AdjointMap()  # C1 carried into the chosen estimate's tangent
    d = np.array([0, 0, 0, 0.003, 0, 0])
    np.testing.assert_allclose(C, 0.5 * (C0 + Ad @ C1 @ Ad.T) + 0.5 * np.outer(d, d), atol=1e-15)
    assert C[3, 3] > 0.5 * (C0[3, 3] + C1[3, 3]) + 4e-6  # the difference shows where the models differ
    sure = Selection("range", (Candidate("none", weight=0.0), Candidate("range", weight=1.0, factor=1.5)))
    np.testing.assert_allclose(mixture(est, sure), 1.5 * C1, atol=1e-15)
    # a model the chosen one contains is not carried: range is none with a range offset, so about
    # range (even weights) the covariance is range's own, times its held-out factor
    inner = Selection("range", (Candidate("none", weight=0.5), Candidate("range", weight=0.5, factor=1.2)))
    assert inner.carried() == ("range",) and even.carried() == ("none", "range")
    np.testing.assert_allclose(mixture(est, inner), 1.2 * C1, atol=1e-15)
    # the selection survives calibration.yaml's plain data
    back = Selection.from_dict(even.to_dict())
    assert back.chosen == "none" and [c.weight for c in back.candidates] == [0.5, 0.5]


def test_a_failed_candidate_is_said_and_the_others_choose() -> None:
    frames = _frames(3, np.full(16, 0.02), n=6)
    base = frames_problem(frames, CAMERA, T_TRUE.matrix())

    def solve_or_fail(problem, options):  # noqa: ANN001, ANN202
        if problem.lidar_errors is not None and problem.lidar_errors.beam_offsets:
            raise np.linalg.LinAlgError("singular")
        return solve_problem(problem, options)

    sols, sel = select_model(base, [MODELS[n] for n in AUTO], solve=solve_or_fail)
    assert set(sols) == {"none", "range"} and sel.chosen == "range"
    beams = next(c for c in sel.candidates if c.name == "beams")
    assert beams.failure == "singular" and beams.weight == 0.0
    assert "beams failed" in sel.summary()


def test_a_dark_print_every_board_shares_leaves_none_out() -> None:
    """Black squares reading 4 mm long move every board's plane alike: the range model's terms show it
    (Wald chi-square far beyond ``TERMS_P``), so ``none`` is left out with its scores and the reason,
    and keeps no weight; without errors nothing is left out (the test above keeps ``none``)."""
    for seed in (0, 2):
        sol = solve(_frames(seed, np.zeros(16), dark=0.004), CAMERA, T_TRUE.matrix(), models=AUTO)
        none = next(c for c in sol.selection.candidates if c.name == "none")
        assert none.weight == 0.0 and none.left_out and "range model's range terms" in none.left_out
        assert math.isfinite(none.log_density) and none.failure is None  # scored, then left out
        assert sol.selection.chosen == "range" and "none" in sol.selection.summary()
        assert "left out" in sol.selection.summary()
        assert abs(sum(c.weight for c in sol.selection.candidates) - 1.0) < 1e-9
        assert nees(sol.T_cam_lidar, sol.covariance) < 16.8
        back = Selection.from_dict(sol.selection.to_dict())
        assert next(c for c in back.candidates if c.name == "none").left_out == none.left_out
    base = frames_problem(_frames(2, np.zeros(16)), CAMERA, T_TRUE.matrix())
    sols, _ = select_model(base, [MODELS[n] for n in AUTO])
    terms = {n: range_terms(sols[n]) for n in ("range", "beams")}
    assert terms["range"][1] == 2 and contradicted(terms, [MODELS[n] for n in AUTO]) == {}
    # chi2 30 for 2 dof (p 3e-7): none left out; 12 for 2 (p 0.0025) keeps it
    assert set(contradicted({"range": (30.0, 2)}, [MODELS[n] for n in AUTO])) == {"none"}
    assert contradicted({"range": (12.0, 2), "beams": (90.0, 13)}, [MODELS[n] for n in AUTO]) == {}


def test_range_terms_the_boards_do_not_determine_are_not_tested() -> None:
    """A candidate whose LiDAR terms the boards barely determine (the marginal refused as
    ``IndeterminateSystem``) gives no test (0, 0): the choice goes on instead of failing the run."""
    base = frames_problem(_frames(0, np.zeros(16), dark=0.004), CAMERA, T_TRUE.matrix())
    sol = solve_problem(MODELS["beams"].problem(base))
    chi2, dof = range_terms(sol)
    assert dof == sol.lidar_estimate(0)[0].size and chi2 > 0  # type: ignore[index]

    def barely(lidar: int = 0) -> np.ndarray:
        raise IndeterminateSystem("the data barely determine the errors of LiDAR 0")

    sol.lidar_covariance = barely  # type: ignore[method-assign]
    assert range_terms(sol) == (0.0, 0)


def test_a_dense_lidar_whose_boards_share_a_range_error_is_not_overconfident(tmp_path, capsys) -> None:
    """A Livox Mid-40 (about 100,000 points a scan in a 38 deg cone) with the simulator's dark print:
    each board's plane is known far better than the 0.7 mm by which every one lies long. Held out,
    ``none`` predicted the images best (the extrinsic absorbs what all boards share) and was chosen
    with weight 1.0000: NEES 70 (tx 7.5 sigma). Through the command line: ``none`` left out, said,
    and an honest result."""
    data, out = tmp_path / "data", tmp_path / "out"
    args = ["simulate", str(data), "--lidar", "livox-mid40", "--camera", "pinhole",
            "--frames", "12", "--seed", "3"]  # fmt: skip
    assert main(args) == 0
    assert main(["calibrate", str(data), "--out", str(out), "--no-report"]) == 0
    assert "(left out: the range model's range terms are far from zero" in capsys.readouterr().out
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    model = cal["sensor_errors"]["model"]
    none = next(c for c in model["candidates"] if c["name"] == "none")
    assert model["chosen"] != "none" and none["weight"] == 0.0 and "range terms" in none["left_out"]
    T_true = gtsam.Pose3(
        np.array(yaml.safe_load((data / "ground_truth.yaml").read_text())["T_cam_lidar"], float)
    )
    xi = gtsam.Pose3(np.array(cal["T_cam_lidar"], float)).localCoordinates(T_true)
    assert float(xi @ np.linalg.solve(np.array(cal["covariance"], float), xi)) < 16.8


@pytest.fixture(scope="module")
def offset_set(tmp_path_factory):  # noqa: ANN201
    """Seven small pinhole frames of a LiDAR reading 20 mm long (besides its per-beam offsets)."""
    out = tmp_path_factory.mktemp("sel") / "data"
    args = ["simulate", str(out), "--lidar", "hdl32", "--camera", "pinhole", "--width", "800",
            "--frames", "7", "--seed", "5", "--range-offset-mm", "20"]  # fmt: skip
    assert main(args) == 0
    return out


def test_calibrate_prints_and_writes_the_model_chosen(offset_set, tmp_path, capsys) -> None:
    out = tmp_path / "auto"
    assert main(["calibrate", str(offset_set), "--out", str(out), "--no-report", "--jobs", "1"]) == 0
    text = capsys.readouterr().out
    model = yaml.safe_load((out / "calibration.yaml").read_text())["sensor_errors"]["model"]
    assert model["chosen"] in ("range", "beams") and not model["forced"]
    # 20 mm long: the boards fitted again on corrected ranges, then only the models with range terms
    # are candidates (run.range_refit, selection.candidates)
    assert {c["name"] for c in model["candidates"]} == set(AUTO) - {"none"}
    assert abs(sum(c["weight"] for c in model["candidates"]) - 1.0) < 1e-9
    assert f"sensor model: {model['chosen']} (held-out images of" in text
    assert "next board pose:" in text and not (out / "next_pose.png").exists()  # --no-report: in words only
    # forced to none, the 20 mm the boards sit beyond their images is left in the residuals, far above
    # the stated noise: no answer is written (exit 3) and the cause is named (issue 38)
    out = tmp_path / "none"
    argv = ["calibrate", str(offset_set), "--out", str(out), "--no-report", "--sensor-model", "none"]
    assert main(argv) == 3
    assert not (out / "calibration.yaml").exists()
    failure = yaml.safe_load((out / "failure.yaml").read_text())
    assert "far above the detectors' stated noise" in failure["error"], failure
    advice = failure["advice"]
    assert advice.startswith("likely: the LiDAR's ranges") and "beyond" in advice, failure
    out = tmp_path / "beams"  # a model with range terms, forced: written and said
    argv = ["calibrate", str(offset_set), "--out", str(out), "--no-report", "--sensor-model", "beams"]
    assert main(argv) == 0
    model = yaml.safe_load((out / "calibration.yaml").read_text())["sensor_errors"]["model"]
    assert model["chosen"] == "beams" and model["forced"]
    assert "sensor model: beams (as asked)" in capsys.readouterr().out


def _pinhole_frames(seed: int, stated_scale: float, n: int = 12):  # noqa: ANN202
    """(frames, the stated camera): boards before a pinhole, pixels from the true camera; bearings
    from a stated camera whose focal lengths are ``stated_scale`` times the true ones."""
    from synthetic_graph import board_prior, random_board_pose, random_spd

    from ilcc_graph.board import Board
    from ilcc_graph.cameras import Pinhole
    from ilcc_graph.types import GraphFrame

    rng = np.random.default_rng(seed)
    true = Pinhole(1280, 960, np.array([[800.0, 0, 640], [0, 800.0, 480], [0, 0, 1]]), np.zeros(4))
    theta = true.intrinsics()
    stated = true.with_intrinsics(np.concatenate([theta[:2] * stated_scale, theta[2:]]))
    R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # LiDAR x forward -> OpenCV z
    T_cl = gtsam.Pose3(gtsam.Rot3(R), np.array([0.02, -0.1, 0.05]))
    board = Board(6, 8, 0.095)
    frames = []
    while len(frames) < n:
        T_lb = random_board_pose(
            rng, board, towards=np.array([1.0, 0.0, 0.0]), spread=0.5, distance=(1.5, 4.0)
        )
        p = np.asarray(T_cl.compose(T_lb).transformFrom(board.corners_board().T)).T
        uv = true.project(p)
        if not np.all(np.isfinite(uv)) or not np.all(true.in_image(uv)):
            continue
        cov = np.stack([random_spd(rng, [0.3, 0.3]) for _ in uv])
        uv = uv + np.stack([rng.multivariate_normal(np.zeros(2), c) for c in cov])
        T_meas, board_cov = board_prior(rng, T_lb, board)
        name = f"{len(frames):04d}"
        frames.append(
            GraphFrame(name, T_meas, board_cov, board.corners_board(), stated.bearing(uv), cov, None, uv)
        )
    return frames, stated, T_cl


@pytest.mark.parametrize(("scale", "refined"), [(1.0, False), (1.02, True)])
def test_intrinsics_are_refined_when_the_boards_determine_them_off_the_stated(scale, refined) -> None:
    """Stated focal lengths 2 % off, 16 boards (halves of 8, as many as the intrinsics): refined (the
    boards tell them, two halves agree) and the extrinsic honest; stated right: kept as stated."""
    frames, stated, T_cl = _pinhole_frames(7, scale, n=16)
    sol = solve(frames, stated, T_cl.matrix(), models=AUTO, intrinsics_choice="auto")
    cam = sol.selection.camera
    assert cam is not None and cam.refined == refined, cam.reason
    assert (sol.intrinsics is not None) == refined
    xi = gtsam.Pose3(sol.T_cam_lidar).localCoordinates(T_cl)
    assert float(xi @ np.linalg.solve(sol.covariance, xi)) < 16.8
    assert "camera intrinsics" in sol.selection.summary()


#: the camera's choice with the subsets the boards' ranges can tell (``camera_choice.LIDAR_SUBSETS``)
WITH_SUBSETS = IntrinsicsOptions(subsets=LIDAR_SUBSETS)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_focal_length_stated_off_is_refined_with_few_boards_as_a_subset(seed) -> None:
    """Stated focal lengths 1 % off, no sigma stated, 10 boards (too few for two halves of all 8
    intrinsics): with ``LIDAR_SUBSETS`` the choice refines fx, fy, k1 and the extrinsic is honest;
    all or none (the default) keeps them as stated, and the boards at 1.5-4 m then sit 1 % off along
    the camera's rays."""
    frames, stated, T_cl = _pinhole_frames(seed, 1.01, n=10)
    sol = solve(frames, stated, T_cl.matrix(), models=AUTO, intrinsics=WITH_SUBSETS, intrinsics_choice="auto")
    cam = sol.selection.camera
    assert cam is not None and cam.refined, cam.reason
    assert "fx, fy, k1 alone: the boards move them" in cam.reason and cam.significance_dof == 3, cam.reason
    assert sol.intrinsics is not None
    names, values, _ = sol.intrinsics
    assert abs(values[names.index("fx")] / stated.intrinsics()[0] - 1 / 1.01) < 0.003, values
    xi = gtsam.Pose3(sol.T_cam_lidar).localCoordinates(T_cl)
    assert float(xi @ np.linalg.solve(sol.covariance, xi)) < 16.8
    held = solve(frames, stated, T_cl.matrix(), models=AUTO, intrinsics_choice="auto")
    assert held.selection.camera is not None and "alone" not in held.selection.camera.reason
    xh = gtsam.Pose3(held.T_cam_lidar).localCoordinates(T_cl)
    assert float(xh @ np.linalg.solve(held.covariance, xh)) > 100  # what the subset saves


def test_intrinsics_stated_right_stay_with_few_boards() -> None:
    """Stated right, 10 boards, with ``LIDAR_SUBSETS``: neither all intrinsics nor any subset is
    refined; once the first subset refines the stated values within their sigma, the smaller ones
    are not solved."""
    frames, stated, T_cl = _pinhole_frames(3, 1.0, n=10)
    sol = solve(frames, stated, T_cl.matrix(), models=AUTO, intrinsics=WITH_SUBSETS, intrinsics_choice="auto")
    cam = sol.selection.camera
    assert cam is not None and not cam.refined and sol.intrinsics is None, cam.reason
    assert "fx, fy, k1 alone: the refined ones are the stated ones within their sigma" in cam.reason, (
        cam.reason
    )
    assert cam.reason.count(" alone: ") == 1, cam.reason


def test_intrinsics_with_stated_sigmas_are_not_refined_as_a_subset() -> None:
    """A config that states the intrinsics' sigmas: those are propagated as stated, no subset is
    tried (``camera_choice.subset_problem`` None), whatever the boards say."""
    frames, stated, T_cl = _pinhole_frames(0, 1.01, n=10)
    with_sigma = dataclasses.replace(stated, intrinsics_sigma=np.full(len(stated.intrinsic_names), 1e-3))
    problem = frames_problem(frames, with_sigma, T_cl.matrix())
    assert all(subset_problem(problem, names) is None for names in LIDAR_SUBSETS)
    sol = solve(
        frames, with_sigma, T_cl.matrix(), models=AUTO, intrinsics=WITH_SUBSETS, intrinsics_choice="auto"
    )
    assert sol.selection.camera is not None and "alone" not in sol.selection.camera.reason


@pytest.mark.slow
def test_a_recorded_lens_the_boards_call_off_is_said(acfr_data, calibrated) -> None:
    """acfr-vlp16-fisheye: refined, its stated intrinsics move far beyond their sigma, but two halves of
    its 19 boards refine them differently; they stay as stated, and the reason says the stated ones
    look off and how to carry their uncertainty (before: only that the halves disagree)."""
    out = calibrated(acfr_data)
    camera = yaml.safe_load((out / "calibration.yaml").read_text())["sensor_errors"]["model"]["camera"]
    q = float(chi2_dist.ppf(0.99, camera["significance_dof"]))
    assert not camera["refined"] and camera["significance_chi2"] > 10 * q, camera
    assert camera["reproducibility_chi2"] > float(chi2_dist.ppf(0.99, camera["reproducibility_dof"]))
    assert "the stated ones look off" in camera["reason"] and "camera.intrinsics_sigma" in camera["reason"]
