"""The paper's gray zone and cost, the in-plane fit and the stage's pose/corner conventions."""

from __future__ import annotations

import numpy as np
import pytest

from ilcc_graph.board import Board
from ilcc_graph.lidar import LidarOptions, estimate_board
from ilcc_graph.lidar._synthetic import SynthScene, synth_scan
from ilcc_graph.lidar.cost import gray_zone, grid_l1_distance, intensity_classes, model_colour, paper_cost
from ilcc_graph.lidar.fit import fit_in_plane, powell_batched
from ilcc_graph.lidars import lidar_model

BOARD = Board(6, 8, 0.075)


def test_gray_zone_from_the_two_peaks() -> None:
    rng = np.random.default_rng(0)
    r = np.r_[rng.normal(10, 1.5, 800), rng.normal(70, 3, 700), rng.uniform(10, 70, 100)]
    tau_l, tau_h, r_l, r_h = gray_zone(r, epsilon=2.0)
    assert abs(r_l - 10) < 1.5 and abs(r_h - 70) < 2.0
    assert tau_l == pytest.approx(tau_h) and tau_h == pytest.approx(0.5 * (r_l + r_h))
    tl4, th4, _, _ = gray_zone(r, epsilon=4.0)  # tau_l = (3 R_L + R_H)/4, tau_h = (R_L + 3 R_H)/4
    assert tl4 == pytest.approx(0.75 * r_l + 0.25 * r_h) and th4 == pytest.approx(0.25 * r_l + 0.75 * r_h)
    cls = intensity_classes(np.array([5.0, 30.0, 50.0, 90.0]), tl4, th4)
    assert cls.tolist() == [0, -1, -1, 1]
    with pytest.raises(ValueError, match="equal"):
        gray_zone(np.full(10, 3.0))


def _reference_cost(params: np.ndarray, q: np.ndarray, cls: np.ndarray, board: Board) -> float:
    """The paper's C_m written point by point with Board.colour_at (slow, obviously right)."""
    th, tx, ty = params
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    total = 0.0
    for qi, ci in zip(q, cls, strict=True):
        b = R @ qi + [tx, ty]
        colour = board.colour_at(b[None])[0]
        dist = float(grid_l1_distance(b, board))
        if np.isnan(colour):
            total += dist  # off the model: always
        elif ci >= 0 and int(colour) != ci:
            total += dist  # wrong colour outside the gray zone
    return total


@pytest.mark.parametrize(
    "board",
    [BOARD, Board(5, 8, 0.1, lower_left="white"), Board(6, 8, 0.095, margin_long=0.045, margin_short=0.02)],
)
def test_cost_matches_the_pointwise_definition_and_is_vectorised(board: Board) -> None:
    rng = np.random.default_rng(1)
    q = rng.uniform(-0.5, 0.5, (300, 2))
    cls = rng.integers(-1, 2, 300).astype(np.int8)
    poses = np.c_[rng.uniform(-np.pi, np.pi, 5), rng.uniform(0.1, 0.5, 5), rng.uniform(0.1, 0.4, 5)]
    batch = paper_cost(poses, q, cls, board)
    for k, x in enumerate(poses):
        ref = _reference_cost(x, q, cls, board)
        assert float(paper_cost(x, q, cls, board)) == pytest.approx(ref, rel=1e-9, abs=1e-12)
        assert batch[k] == pytest.approx(ref, rel=1e-9, abs=1e-12)


def test_cost_on_hand_made_points() -> None:
    s = BOARD.square_size
    centres = np.array([[0.5 * s, 0.5 * s], [1.5 * s, 0.5 * s], [2.5 * s, 0.5 * s]])  # black, white, black
    ident = np.zeros(3)
    assert paper_cost(ident, centres, np.array([0, 1, 0], np.int8), BOARD) == 0.0  # right colours: free
    # a white reading on the first (black) square costs its L1 distance to the nearest lines: s/2 + s/2
    assert paper_cost(ident, centres, np.array([1, 1, 0], np.int8), BOARD) == pytest.approx(s)
    # gray readings cost nothing on the board
    assert paper_cost(ident, centres, np.array([-1, -1, -1], np.int8), BOARD) == 0.0
    # off the board costs the distance to the nearest lines whatever the reading
    off = np.array([[-0.02, 0.3 * s]])
    assert paper_cost(ident, off, np.array([-1], np.int8), BOARD) == pytest.approx(0.02 + 0.3 * s)
    # a shift by one square flips every colour: the true pose is the cheaper
    q = np.stack(np.meshgrid((np.arange(8) + 0.5) * s, (np.arange(6) + 0.5) * s), -1).reshape(-1, 2)
    cls = model_colour(q, BOARD)[0].astype(np.int8)
    assert paper_cost(np.array([0.0, s, 0.0]), q, cls, BOARD) > paper_cost(ident, q, cls, BOARD) == 0.0


def _plane_samples(board: Board, T2: np.ndarray, rng: np.random.Generator, keep=None):
    """Dense samples of the board in plane coordinates q, intensities from the colours (blur-free)."""
    x0, x1, y0, y1 = board.extent()
    b = np.c_[rng.uniform(x0, x1, 1500), rng.uniform(y0, y1, 1500)]
    if keep is not None:
        b = b[keep(b)]
    inten = np.where(board.colour_at(b) > 0.5, 70.0, 8.0) + rng.normal(0, 2, len(b))
    th, tx, ty = T2  # q = R(th)^T (b - t)
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    q = (b - [tx, ty]) @ R
    return q - q.mean(axis=0), inten, b


@pytest.mark.parametrize(
    "board", [Board(6, 8, 0.075), Board(5, 8, 0.075, lower_left="white"), Board(7, 9, 0.06)]
)
@pytest.mark.parametrize("angle", [0.3, 2.0, -2.6])
def test_in_plane_fit_recovers_the_pattern_any_angle_and_colour(board: Board, angle: float) -> None:
    rng = np.random.default_rng(7)
    q, inten, b = _plane_samples(board, np.array([angle, 0.1, -0.05]), rng)
    fit = fit_in_plane(q, inten, board, LidarOptions())
    th, tx, ty = fit.params
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    b_hat = q @ R.T + [tx, ty]
    err = np.linalg.norm(b_hat - b, axis=1)
    if board.half_turn_symmetric:  # the other origin is as good
        w, h = board.pattern_size_m
        err = np.minimum(err, np.linalg.norm(b_hat - ([w, h] - b), axis=1))
    assert np.median(err) < 0.004


def test_in_plane_fit_when_part_of_the_board_is_missing() -> None:
    # the top part cut off (outside the beams): PCA axes no longer follow the board's sides
    rng = np.random.default_rng(3)
    board = Board(6, 8, 0.075, lower_left="white")
    q, inten, b = _plane_samples(
        board, np.array([0.7, 0.0, 0.0]), rng, keep=lambda b: b[:, 1] + 0.5 * b[:, 0] < 0.45
    )
    fit = fit_in_plane(q, inten, board, LidarOptions())
    th, tx, ty = fit.params
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    assert np.median(np.linalg.norm(q @ R.T + [tx, ty] - b, axis=1)) < 0.004


def test_powell_batched_minimises_a_quadratic() -> None:
    target = np.array([0.3, -0.02, 0.05])
    fun = lambda X: ((X - target) ** 2 * [1.0, 50.0, 80.0]).sum(axis=-1)  # noqa: E731
    x, f, n = powell_batched(fun, np.zeros(3), np.array([0.5, 0.1, 0.1]), xtol=1e-6, max_iter=40)
    assert np.allclose(x, target, atol=1e-5) and n > 0


@pytest.mark.parametrize("lower_left", ["black", "white"])
def test_estimate_board_pose_and_corner_conventions(lower_left: str) -> None:
    board = Board(5, 8, 0.075, lower_left=lower_left)  # not half-turn symmetric: one right answer
    model = lidar_model("hdl32")
    scan, T = synth_scan(
        board, model, SynthScene(distance=2.0, in_plane_deg=35, person=True), np.random.default_rng(4)
    )
    fit = estimate_board(scan, board, model)
    R = fit.T_lidar_board[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-9) and np.linalg.det(R) == pytest.approx(1.0)
    assert R[:, 2] @ fit.T_lidar_board[:3, 3] < 0  # z towards the LiDAR
    truth = board.corners_board() @ T[:3, :3].T + T[:3, 3]
    assert fit.corners_lidar.shape == (board.n_corners, 3)
    assert np.sqrt(((fit.corners_lidar - truth) ** 2).sum(axis=1).mean()) < 0.003
    assert not fit.half_turn_ambiguous
    assert fit.covariance.shape == (6, 6) and np.all(np.linalg.eigvalsh(fit.covariance) > 0)
    assert fit.points_lidar.shape[0] == fit.intensity.shape[0] > 100
