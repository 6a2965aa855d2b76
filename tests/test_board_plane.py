"""The boards' plane sigmas estimated from the data (``estimation/plane.py``)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from synthetic_graph import board_returns, observe, random_board_pose

from factors.board_points import BoardPointsFactor
from factors.testing import random_pose
from ilcc_graph.board import Board
from ilcc_graph.cameras import Equirectangular
from ilcc_graph.estimation import solve
from ilcc_graph.estimation.assembly import Term
from ilcc_graph.estimation.keys import B, L
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.linear import redundancies
from ilcc_graph.types import GraphFrame

CAMERA = Equirectangular(4000, 2000)
BOARD = Board(6, 8, 0.095, 0.045, 0.02, "white")
VLP16 = np.arange(-15.0, 15.1, 2.0)
T_TRUE = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.03, -0.05, 0.07), np.array([0.05, -0.03, -0.25]))


def bent_frames(rng, n_frames, bend_sigmas, sigma_m=0.01, beam_sigma=0.003, beam_jitter=0.0):
    """Frames whose boards each carry their own random plane of ``bend_sigmas`` (offset m, tilt rad)
    and, per beam and board, a random range offset of ``beam_jitter`` (m)."""
    frames = []
    offsets = rng.normal(0.0, beam_sigma, len(VLP16))
    while len(frames) < n_frames:
        T_lb = random_board_pose(rng, BOARD, distance=(1.5, 3.0))
        obs = observe(rng, CAMERA, T_TRUE, T_lb, BOARD.corners_board(), 0.5)
        if obs is None:
            continue
        bend = (rng.normal(0, bend_sigmas[0]), *rng.normal(0, bend_sigmas[1], 2))
        returns, T_meas, cov = board_returns(
            rng, T_lb, BOARD, VLP16, offsets, 0.004, sigma_m, bend=bend, beam_jitter_m=beam_jitter
        )
        if len(np.unique(returns.ring)) < 4:
            continue
        frames.append(
            GraphFrame(f"{len(frames):04d}", T_meas, cov, BOARD.corners_board(), obs[0], obs[1], returns)
        )
    return frames


def test_plane_rows_give_the_explicit_random_effects_chi2_and_redundancy() -> None:
    """The virtual rows of a marginalised plane give what the plane made explicit (three parameters
    with their prior as pseudo-observations) gives: its chi-square and its redundancy."""
    rng = np.random.default_rng(5)
    T = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.2, -1.0, 0.5), np.array([2.5, -0.4, 0.2]))
    m, scale, sig = 80, 1.7, (0.004, 0.006)
    pb = np.column_stack([rng.uniform(0, 0.8, m), rng.uniform(0, 0.6, m), rng.normal(0, 0.01, m)])
    P = np.array([T.transformFrom(x) for x in pb])
    ring = rng.integers(0, 4, m)
    S = np.zeros((3, 6))
    S[:, [2, 3, 4]] = np.eye(3)
    args = (B(0), L(0), P, 0.01, ring[:, None], np.ones((m, 1)), 4, T, S, np.diag([300.0, 500.0, 500.0]))
    f = BoardPointsFactor(*args, plane_sigma=sig).scaled(scale, 1.0, (0.6, 1.8))
    plain = BoardPointsFactor(*args).scaled(scale, 1.0)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(f.factor())
    graph.add(gtsam.PriorFactorVector(L(0), np.zeros(4), gtsam.noiseModel.Isotropic.Sigma(4, 0.01)))
    graph.add(gtsam.PriorFactorPose3(B(0), T, gtsam.noiseModel.Isotropic.Sigma(6, 0.003)))  # as views would
    values = gtsam.Values()
    values.insert(B(0), T.compose(random_pose(rng, 0.01, 0.01)))
    values.insert(L(0), rng.normal(0, 0.005, 4))
    parts = (("points", 0, m), ("inplane", m, m + 3))
    terms = [Term("board", "", 0, m + 3, parts), Term("lidar", "", None, 4), Term("bearing", "", 0, 6)]
    z = f.plane_rows()
    assert z[2] is None  # no beam term

    def extra(k, t):
        return (("off", 0, m, z[0]), ("tilt", 0, m, z[1])) if k == 0 else ()

    dims = {B(0): 6, L(0): 4}
    info: dict = {}
    got = redundancies(graph, values, terms, dims.__getitem__, extra, info)
    # explicit: rows e = A x + G p + n (n ~ I), pseudo-observations 0 = p + m (m ~ Sigma), prior on l
    e, A_T, A_l = plain.evaluate(values.atPose3(B(0)), values.atVector(L(0)), True)
    A = np.hstack([A_T[:m], A_l[:m]])
    G = f._plane[0] / np.sqrt(scale)
    Sig = np.diag(f.plane_variances())
    V = np.eye(m) + G @ Sig @ G.T
    p_hat = Sig @ G.T @ np.linalg.solve(V, e[:m])
    W_in = np.hstack([A_T[m:], A_l[m:]])
    N = np.zeros((13, 13))  # (pose, l, plane) with every row: data, in-plane prior, l prior, plane prior
    J = np.hstack([A, G])
    N += J.T @ J
    N[:10, :10] += W_in.T @ W_in
    N[6:10, 6:10] += np.eye(4) / 0.01**2
    H = np.zeros((6, 6), order="F")
    gtsam.Pose3.Logmap(T.between(values.atPose3(B(0))), H)
    N[:6, :6] += H.T @ H / 0.003**2
    N[10:, 10:] += np.linalg.inv(Sig)
    C_p = np.linalg.inv(N)[10:, 10:]
    ZPZ = np.eye(3) - np.diag(Sig.diagonal() ** -0.5) @ C_p @ np.diag(Sig.diagonal() ** -0.5)
    for name, idx in (("off", [0]), ("tilt", [1, 2])):
        chi2 = float(p_hat[idx] @ np.linalg.solve(Sig[np.ix_(idx, idx)], p_hat[idx]))
        red = len(idx) - float(np.trace(np.linalg.solve(Sig[np.ix_(idx, idx)], C_p[np.ix_(idx, idx)])))
        assert got[(name, "")][0] == pytest.approx(chi2, rel=1e-6)
        assert got[(name, "")][1] == pytest.approx(red, rel=1e-6)
        assert 0.0 < red < len(idx)
        # the scoring step's information: ||Z^T P Z||^2 of the explicit model's block
        assert info[(name, "")] == pytest.approx(float(np.sum(ZPZ[np.ix_(idx, idx)] ** 2)), rel=1e-6)


def test_estimated_plane_sigma_recovers_bent_boards_and_falls_to_the_floor_on_ideal_ones() -> None:
    rng = np.random.default_rng(11)
    true = (0.004, np.radians(0.4))
    frames = bent_frames(rng, 24, true)
    T0 = T_TRUE.compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6))).matrix()
    opts = LidarErrorOptions(board_plane=(0.008, 0.014), board_plane_estimate=True)  # start 2x too large
    bp = solve(frames, CAMERA, T0, lidar_errors=opts).board_plane
    assert bp is not None and bp.estimated, bp
    assert abs(bp.offset_m - true[0]) < 3 * bp.offset_sd, bp
    assert abs(bp.tilt_rad - true[1]) < 3 * bp.tilt_sd, bp
    assert bp.offset_sd < 0.4 * bp.offset_m and bp.tilt_sd < 0.4 * bp.tilt_rad, bp  # it tells something
    assert "more than a bent print" not in bp.note, bp
    # the same boards ideal (flat): the sigmas fall to the floor (within the estimate's sd: an REML
    # estimate of a zero variance lands at the bound or just above it)
    flat = bent_frames(np.random.default_rng(22), 24, (0.0, 0.0))
    bp = solve(flat, CAMERA, T0, lidar_errors=opts).board_plane
    assert bp.estimated and "at its floor" in bp.note, bp
    assert bp.offset_m < opts.board_plane_floor[0] + 3 * bp.offset_sd < true[0] / 2, bp
    assert bp.tilt_rad < opts.board_plane_floor[1] + 3 * bp.tilt_sd < true[1] / 2, bp


def test_estimated_beam_sigma_recovers_board_to_board_beam_offsets() -> None:
    """Each beam's range offset changing from board to board (2.5 mm): the third component finds it
    within its sd (the plane's components stay near their floor), and falls to its floor without;
    the shared beam offsets then carry that extra uncertainty."""
    rng = np.random.default_rng(31)
    true = 0.0025
    frames = bent_frames(rng, 24, (0.0, 0.0), beam_jitter=true)
    T0 = T_TRUE.compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6))).matrix()
    opts = LidarErrorOptions(board_beam=0.001)  # start 2.5x too small
    sol = solve(frames, CAMERA, T0, lidar_errors=opts)
    bp = sol.board_plane
    assert bp is not None and bp.estimated, bp
    assert abs(bp.beam_m - true) < 3 * bp.beam_sd and bp.beam_sd < 0.3 * true, bp
    without = solve(frames, CAMERA, T0, lidar_errors=LidarErrorOptions(board_beam=None))
    beams = [k for k, n in enumerate(sol.lidar_layout.names) if n.startswith("offset[")]
    assert without.lidar_layout.names == sol.lidar_layout.names and len(beams) >= 10
    assert np.all(np.diag(sol.lidar_covariance)[beams] > 1.3 * np.diag(without.lidar_covariance)[beams])
    flat = bent_frames(np.random.default_rng(32), 24, (0.0, 0.0))
    bp = solve(flat, CAMERA, T0, lidar_errors=opts).board_plane
    assert "beams at its floor" in bp.note or bp.beam_m < opts.board_beam_floor + 3 * bp.beam_sd < true / 2, (
        bp
    )


@pytest.mark.xfail(
    strict=True,
    reason="known (docs/bench_lidar_errors.md finding 10): with bent boards the beams' common level "
    "is still biased high (z +0.6..+3.1 over 8 seeds; the run-off is gone since the plane's offset "
    "is a range offset)",
)
def test_bent_boards_leave_the_beams_common_level_unbiased() -> None:
    """Boards bent 4 mm / 0.4 deg: over several sets the beams' mean offset stays within 3 sigma of the
    truth's and the plane's offset sigma within 3 sd of 4 mm. Fails today (the xfail says why)."""
    misses = []
    for seed in (1, 2, 3, 5, 10, 13):
        truth = np.random.default_rng(seed).normal(0.0, 0.003, len(VLP16))  # bent_frames' first draw
        rng = np.random.default_rng(seed)
        frames = bent_frames(rng, 24, (0.004, np.radians(0.4)))
        T0 = T_TRUE.compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6))).matrix()
        sol = solve(frames, CAMERA, T0, lidar_errors=LidarErrorOptions(board_beam=None))
        beams = [k for k, n in enumerate(sol.lidar_layout.names) if n.startswith("offset[")]
        ids = [int(sol.lidar_layout.names[k][7:-1]) for k in beams]
        err = float(np.mean(np.asarray(sol.lidar[1])[beams]) - np.mean(truth[ids]))
        sd = float(np.sqrt(np.mean(sol.lidar_covariance[np.ix_(beams, beams)])))
        bp = sol.board_plane
        if abs(err) > 3 * sd or abs(bp.offset_m - 0.004) > 3 * bp.offset_sd:
            misses.append((seed, round(1e3 * err, 1), round(1e3 * sd, 2), round(1e3 * bp.offset_m, 1)))
    assert not misses, misses


def test_boards_far_off_their_returns_are_called_out() -> None:
    """Returns 30 mm off their boards (as on the recorded Ouster set): more than a bent print, and
    the solution says so (calibration.yaml's note, the text output, a warning)."""
    rng = np.random.default_rng(11)
    frames = bent_frames(rng, 24, (0.03, np.radians(0.4)))
    T0 = T_TRUE.compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6))).matrix()
    bp = solve(frames, CAMERA, T0, lidar_errors=LidarErrorOptions()).board_plane
    assert bp.estimated and bp.offset_m > 0.015, bp
    assert "more than a bent print" in bp.note and "without --lidar-errors" in bp.note, bp


def test_few_boards_keep_the_configured_plane_sigma_and_say_so() -> None:
    rng = np.random.default_rng(12)
    frames = bent_frames(rng, 4, (0.004, 0.007))
    opts = LidarErrorOptions(board_plane_estimate=True)
    sol = solve(frames, CAMERA, T_TRUE.matrix(), lidar_errors=opts)
    bp = sol.board_plane
    assert not bp.estimated and (bp.offset_m, bp.tilt_rad) == opts.board_plane
    assert "fewer than 5" in bp.note, bp
    # fixed sigmas: the same solution as without the option
    fixed = solve(frames, CAMERA, T_TRUE.matrix(), lidar_errors=LidarErrorOptions(board_plane_estimate=False))
    assert np.array_equal(fixed.T_cam_lidar, sol.T_cam_lidar)
    assert np.array_equal(fixed.covariance, sol.covariance)
    assert fixed.board_plane.note == "configured"


def test_plane_estimate_options_are_checked() -> None:
    with pytest.raises(ValueError, match="board_plane_floor"):
        LidarErrorOptions(board_plane_estimate=True, board_plane_floor=(0.01, 0.0007))
    with pytest.raises(ValueError, match="board_plane_max"):
        LidarErrorOptions(board_plane=(0.05, 0.007))
    assert LidarErrorOptions().board_plane_estimate  # the default (docs/bench_lidar_errors.md)
    LidarErrorOptions(board_plane=None)  # no plane: nothing to estimate


def test_cli_board_plane_maps_to_the_options() -> None:
    from ilcc_graph.app.flags import run_options as _run_options
    from ilcc_graph.app.parser import build_parser
    from ilcc_graph.errors import InputError

    def opts(*extra):
        return _run_options(build_parser().parse_args(["calibrate", "data", *extra])).lidar_errors

    assert opts() is None
    assert opts("--lidar-errors") == LidarErrorOptions() and LidarErrorOptions().board_plane_estimate
    assert opts("--lidar-errors", "--board-plane", "estimated").board_plane_estimate
    assert not opts("--lidar-errors", "--board-plane", "fixed").board_plane_estimate
    with pytest.raises(InputError, match="--board-plane"):
        opts("--board-plane", "fixed")
