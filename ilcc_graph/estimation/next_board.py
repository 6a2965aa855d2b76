"""What one more board would add to a solved problem's extrinsic, with the problem's sensor terms.

A new board couples ``T_cam_lidar`` (``X(0)``) not only to its own pose ``B(new)`` but, through the
chosen sensor model, to the range terms every board shares (``O(0)`` of the ``offset`` model, the
offsets in ``L(0)`` of ``range`` and ``beams``): the offset that makes the translation along the rays
weak (tz on a rig facing its boards) stays in the promise instead of being forgotten. To first order
the LiDAR stage's rigid fit of a board whose returns read ``beta`` long reports its pose moved by
``beta g(o)`` (``factors.range_offset``), ``beta`` the mean range error of its returns: ``a . theta``,
``a`` the board's mean coefficient of each range term (1 for the common offset, the dark share of the
face for the dark-print offset, each beam's share of the returns for its offset, the range for the
scale). The board's information is built from the graph's own factors (its corners' bearing factor,
its prior through ``RangeOffsetBoardFactor`` on ``beta``), linearised at the solution with the
measurements predicted there, ``B(new)`` marginalised out: a ``(6 + k, 6 + k)`` information on the
globals (``X(0)``, then the range terms). ``extrinsic_gain`` turns it into the information the
extrinsic's marginal gains, which adds to any covariance of ``T_cam_lidar`` (the reported one, with
its components' uncertainty and stated intrinsics; docs/bench_next_pose_promise.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import gtsam
import numpy as np

from factors.range_offset import range_offset_error, shifted_board_pose
from ilcc_graph.cameras import CameraModel
from ilcc_graph.estimation.graphs import frame_bearing_factor, samples_from_corners
from ilcc_graph.estimation.keys import POSE3_DOF, L, O, X
from ilcc_graph.estimation.noise import Solution
from ilcc_graph.types import PoseTerms

__all__ = ["SolvedGlobals", "board_information", "extrinsic_gain", "solved_globals"]


@dataclass(frozen=True)
class SolvedGlobals:
    """The solved problem's globals a new board touches.

    T_cam_lidar: (4, 4) the extrinsic ``X(e)``. covariance: (6 + k, 6 + k) the joint marginal
    covariance in the solved graph of ``X(e)`` (rotation first) and the k range terms (metres; the
    scale unitless). terms: the k terms' names (``LidarLayout.names``, or ``offset`` for ``O(0)``).
    theta: (k,) their estimates. units: (k,) each term's unit (``LidarLayout.units``).
    """

    T_cam_lidar: np.ndarray
    covariance: np.ndarray
    terms: tuple[str, ...] = ()
    theta: np.ndarray = field(default_factory=lambda: np.zeros(0))
    units: tuple[str, ...] = ()

    @property
    def dim(self) -> int:
        return len(self.covariance)

    def pose_terms(self, factor: float = 1.0) -> PoseTerms | None:
        """The extrinsic with its range terms as calibration.yaml keeps them (``types.PoseTerms``),
        the joint covariance times ``factor`` (the chosen model's held-out factor, as the reported
        covariance is); None without terms."""
        if not self.terms:
            return None
        C = factor * np.asarray(self.covariance, dtype=np.float64)
        return PoseTerms(self.T_cam_lidar, tuple(self.terms), tuple(self.units), np.asarray(self.theta), C)

    def coefficients(self, dark_share: float, beams: Sequence[int], range_m: float) -> np.ndarray:
        """(k,) ``a``: a board's mean coefficient of each range term, for its returns' ``dark_share``,
        the ``beams`` on it (an equal share each) and its ``range_m``; 0 for elevation terms."""
        a = np.zeros(len(self.terms))
        for i, t in enumerate(self.terms):
            if t == "offset":
                a[i] = 1.0
            elif t == "dark":
                a[i] = dark_share
            elif t == "scale":
                a[i] = range_m
            elif t.startswith("offset[") and beams:
                a[i] = float(int(t[7:-1]) in beams) / len(beams)
        return a


def solved_globals(sol: Solution, e: int = 0) -> SolvedGlobals:
    """The globals of a solved problem (``noise.solve_problem``): extrinsic ``X(e)`` (a rig's camera
    e) and the base LiDAR's range terms of its sensor model (``O(0)``, or the range terms of
    ``L(0)``), their joint marginal covariance (the variance factor included)."""
    T = np.asarray(sol.values.atPose3(X(e)).matrix(), dtype=np.float64)
    if sol.problem.range_offset_sigma_m is not None and sol.values.exists(O(0)):
        C = sol.marginals.joint([X(e), O(0)], [POSE3_DOF, 1])
        theta0 = np.asarray(sol.values.atVector(O(0)), dtype=np.float64)
        return SolvedGlobals(T, C, ("offset",), theta0, ("m",))
    layout = sol.assembly.layouts.get(0)
    if layout is None or not sol.values.exists(L(0)):
        return SolvedGlobals(T, sol.marginals.joint([X(e)], [POSE3_DOF]))
    names = layout.names
    keep = [i for i, n in enumerate(names) if not n.startswith("elevation")]
    C = sol.marginals.joint([X(e), L(0)], [POSE3_DOF, layout.dim])
    idx = np.r_[np.arange(POSE3_DOF), POSE3_DOF + np.asarray(keep, dtype=np.int64)]
    theta = np.asarray(sol.values.atVector(L(0)), dtype=np.float64)[keep]
    units = tuple(layout.units[i] for i in keep)
    return SolvedGlobals(T, C[np.ix_(idx, idx)], tuple(names[i] for i in keep), theta, units)


def board_information(
    g: SolvedGlobals,
    T_lidar_board: np.ndarray,
    board_cov: np.ndarray,
    points_board: np.ndarray,
    bearings: np.ndarray,
    cov_px: np.ndarray,
    camera: CameraModel,
    coefficients: np.ndarray | None = None,
    samples: np.ndarray | None = None,
) -> np.ndarray | None:
    """(g.dim, g.dim) information a board at ``T_lidar_board`` (LiDAR frame) adds to the globals:
    its LiDAR covariance ``board_cov`` (6, 6), its corners ``points_board`` (K, 3, board frame) seen
    along ``bearings`` (K, 3, camera frame, predicted at ``g.T_cam_lidar``) with pixel covariances
    ``cov_px`` (K, 2, 2), ``coefficients`` ``a`` of the range terms (``SolvedGlobals.coefficients``;
    ``samples``: the board-face points of its range prior, default ``samples_from_corners`` as the
    graph's); None when the view gives no factor (too few usable corners)."""
    fac, _ = frame_bearing_factor(0, 1, points_board, bearings, cov_px, camera)
    if fac is None:
        return None
    T_lb = gtsam.Pose3(np.asarray(T_lidar_board, dtype=np.float64))
    _, Ax, Ab = fac.evaluate(gtsam.Pose3(g.T_cam_lidar), T_lb, True)
    n = g.dim + POSE3_DOF  # the globals, then B(new)
    J = np.zeros((len(Ax), n))
    J[:, :POSE3_DOF], J[:, g.dim :] = Ax, Ab
    H = J.T @ J
    W = np.linalg.inv(np.asarray(board_cov, dtype=np.float64))
    a = np.zeros(g.dim - POSE3_DOF) if coefficients is None else np.asarray(coefficients, dtype=np.float64)
    if not np.any(a):
        H[g.dim :, g.dim :] += W
    else:  # the board prior through its mean range error beta = a . theta (RangeOffsetBoardFactor)
        samples = samples_from_corners(points_board) if samples is None else samples
        beta = float(a @ g.theta)
        measured = shifted_board_pose(T_lb, beta, samples)
        H_T, H_b = np.zeros((POSE3_DOF, POSE3_DOF), order="F"), np.zeros((POSE3_DOF, 1), order="F")
        range_offset_error(measured, T_lb, beta, samples, H_T, H_b)
        Jp = np.zeros((POSE3_DOF, n))
        Jp[:, POSE3_DOF : g.dim], Jp[:, g.dim :] = H_b @ a[None, :], H_T
        H += Jp.T @ W @ Jp
    Hgg, Hgb, Hbb = H[: g.dim, : g.dim], H[: g.dim, g.dim :], H[g.dim :, g.dim :]
    info = Hgg - Hgb @ np.linalg.solve(Hbb, Hgb.T)
    return 0.5 * (info + info.T)


def extrinsic_gain(g: SolvedGlobals, information: np.ndarray) -> np.ndarray:
    """(6, 6) the information ``T_cam_lidar``'s marginal gains when ``information`` (g.dim, g.dim)
    is added to the solved globals: ``inv(C_after_X) - inv(C_X)``. Without other globals it is the
    extrinsic block itself."""
    if g.dim == POSE3_DOF:
        return np.asarray(information, dtype=np.float64)
    before = np.linalg.inv(g.covariance)
    after = np.linalg.inv(before + information)[:POSE3_DOF, :POSE3_DOF]
    gain = np.linalg.inv(after) - np.linalg.inv(g.covariance[:POSE3_DOF, :POSE3_DOF])
    return 0.5 * (gain + gain.T)
