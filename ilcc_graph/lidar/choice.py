"""Choosing the board among the candidates that pass the tests, and the expected-board hint.

Several segments of a cluttered room can pass the paper's tests (a poster, a door panel, a
board-sized box). The stage fits the chessboard to the best few (ordered by contrast x
uniformity, or by closeness to the expected board) and keeps the fit whose pattern explains the
intensities best: the share of black/white returns whose colour matches the fitted pattern
(``colour_agreement``), less the paper's cost per return in squares; with an expected board, less
its distance from the prediction in tolerances.

An :class:`~ilcc_graph.types.ExpectedBoard` (predicted pose, position and angle tolerance) also
restricts the search to a box around the predicted board: the board's extent grown by the
position tolerance in its plane, and the tolerance plus the tilt the angle tolerance allows
across it.
"""

from __future__ import annotations

import numpy as np

from ..board import Board
from ..types import BoardFit, ExpectedBoard
from .detection import Candidate
from .options import breach

__all__ = ["expected_mask", "prediction_error", "candidate_order", "fit_score", "beyond_expected"]


def _centre_board(board: Board) -> np.ndarray:
    x0, x1, y0, y1 = board.extent()
    return np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.0])


def expected_mask(points: np.ndarray, board: Board, expected: ExpectedBoard) -> np.ndarray:
    """(N,) bool: points (N, 3) LiDAR frame inside the generous box around the expected board."""
    T = expected.T_lidar_board
    b = (np.asarray(points, np.float64) - T[:3, 3]) @ T[:3, :3]  # board frame
    x0, x1, y0, y1 = board.extent()
    tol = expected.position_tol_m
    half_diag = 0.5 * float(np.hypot(x1 - x0, y1 - y0))
    depth = tol + half_diag * np.sin(np.deg2rad(min(expected.angle_tol_deg, 90.0)))
    return (
        (b[:, 0] >= x0 - tol) & (b[:, 0] <= x1 + tol)
        & (b[:, 1] >= y0 - tol) & (b[:, 1] <= y1 + tol)
        & (np.abs(b[:, 2]) <= depth)
    )  # fmt: skip


def prediction_error(
    centre: np.ndarray, normal: np.ndarray, board: Board, expected: ExpectedBoard
) -> tuple[float, float]:
    """(distance m, angle deg) of a board centre (3,) and unit normal (3,) from the prediction.

    Both are unchanged by the board's half turn, so either equivalent predicted pose will do; the
    normal's sign is ignored.
    """
    T = expected.T_lidar_board
    c_pred = T[:3, :3] @ _centre_board(board) + T[:3, 3]
    cos_a = abs(float(np.asarray(normal) @ T[:3, 2])) / max(float(np.linalg.norm(normal)), 1e-12)
    return float(np.linalg.norm(np.asarray(centre) - c_pred)), float(np.degrees(np.arccos(min(cos_a, 1.0))))


def candidate_order(
    cands: list[Candidate], points: np.ndarray, board: Board, expected: ExpectedBoard | None
) -> list[Candidate]:
    """Candidates best first: nearest the prediction (in tolerances) when there is one, else by
    black/white contrast times uniformity (a printed chessboard has both)."""
    if expected is None:
        return sorted(cands, key=lambda c: -c.contrast * c.uniformity)

    def miss(c: Candidate) -> float:
        d, a = prediction_error(points[c.indices].mean(axis=0), c.normal, board, expected)
        return d / expected.position_tol_m + a / expected.angle_tol_deg

    return sorted(cands, key=miss)


def fit_score(fit: BoardFit, board: Board, expected: ExpectedBoard | None) -> float:
    """Higher is better: colour agreement less the cost per return in squares (without a print the
    LiDAR shows: the share of samples the outline explains, scaled down when few rays pass beside
    the board), less (with a prediction) the distance and angle from it in tolerances, halved; -inf
    beyond the tolerances.

    For an outline fit the score ranks candidates and ends the search; it refuses nothing. Its share
    of rays passing beside the board counts the samples within reach of the outline, a band that
    widens with the plane noise (4 sigma of a return's in-plane shift, ``shape.outline_mode``) into
    the board, not beyond it where nothing returns (the sky, an open scene): the same board scored
    0.99 at 0 mm, 0.89 at 15 mm and 0.76 at 30 mm of noise. Whether the outline places the board is
    the posterior's covariance, refused beyond ``max_inplane_2sigma_squares`` (``pose``)."""
    n = max(fit.diagnostics.get("n_points", 1.0), 1.0)
    d = fit.diagnostics
    if d.get("no_contrast"):  # no print to judge by: how well its outline is the board's, and how much
        # of it the scan shows (rays passing beside it; a third of the samples or more: all of it)
        share = d.get("shape_n_out", 0.0) / max(d.get("shape_n_in", 0.0) + d.get("shape_n_out", 0.0), 1.0)
        score = d.get("shape_agreement", 0.0) * min(1.0, 3.0 * share)
    else:
        # (no cost when the pattern was moved to where the outline is: Powell's was at the slid pose)
        cost = 0.0 if not np.isfinite(fit.cost) else fit.cost
        score = d.get("colour_agreement", 0.0) - cost / (n * board.square_size)
    if expected is not None:
        T = fit.T_lidar_board
        dist, a = prediction_error(T[:3, :3] @ _centre_board(board) + T[:3, 3], T[:3, 2], board, expected)
        if dist > expected.position_tol_m or a > expected.angle_tol_deg:
            return -np.inf
        score -= 0.5 * (dist / expected.position_tol_m + a / expected.angle_tol_deg)
    return float(score)


def beyond_expected(fit: BoardFit, board: Board, expected: ExpectedBoard | None) -> str:
    """Why a fit beyond the expected board's tolerances is refused, with its distance and angle."""
    if expected is None:
        return "the fit's score is not finite"
    T = fit.T_lidar_board
    d, a = prediction_error(T[:3, :3] @ _centre_board(board) + T[:3, 3], T[:3, 2], board, expected)
    return "the fitted board lies beyond the expected board's tolerances " + (
        breach("position_tol_m", d, ">", expected.position_tol_m, "m")
        if d > expected.position_tol_m
        else breach("angle_tol_deg", a, ">", expected.angle_tol_deg, "deg")
    )
