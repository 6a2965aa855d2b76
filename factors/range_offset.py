"""A LiDAR range offset in the board-pose prior: the board seen by a LiDAR that reads ``b`` long.

Model (real VLP-16 units are reported to read ~30 mm long): every return lies at ``(r + b)`` along
its ray instead of ``r``, i.e. a true point ``p`` (LiDAR frame) is measured at ``p + b p / |p|``.
The LiDAR stage fits a *rigid* board to such points, so what it reports is the rigid motion that
best explains this displacement field over the board. In the board frame (``o`` the LiDAR origin
there, ``o = T_lidar_board^-1 * 0``), a board point ``P`` moves by ``b d(P)``,
``d(P) = (P - o) / |P - o|``; a right perturbation ``T * Expmap(xi)``, ``xi = (w, v)``, moves it by
``w x P + v = A(P) xi`` with ``A(P) = [-[P]x, I]``. Least squares over sample points ``P_k`` of the
board's face gives, to first order in ``b``::

    T_measured = T_lidar_board * Expmap(b g(o)),   g(o) = N^-1 sum_k A_k^T d_k,   N = sum_k A_k^T A_k.

``g`` is mostly ``R^T u`` (a shift of ``b`` along the ray ``u`` to the board) plus a small tilt: the
in-plane stretch ``(b / d)(I - u u^T)`` of a board seen obliquely turns its fitted plane towards the
ray by about ``(b / d) sin(a) cos(a)`` (``a`` the incidence angle), 5 mrad for 30 mm at 3 m and 45 deg.

``RangeOffsetBoardFactor`` replaces the board's ``PriorFactorPose3``: keys (``T_lidar_board`` Pose3,
``b`` Vector1, metres); error ``T_measured_by_lidar.localCoordinates(T * Expmap(b g))`` (6,), with the
LiDAR stage's 6x6 covariance. For ``b = 0`` it is exactly ``PriorFactorPose3``. Jacobians are analytic,
chained from GTSAM's ``transformTo``, ``Expmap``, ``compose``, ``between`` and ``Logmap`` derivatives.
"""

from __future__ import annotations

import gtsam
import numpy as np

from factors.grouped import POSE3_DOF, skew

__all__ = ["RangeOffsetBoardFactor", "range_offset_direction", "range_offset_error", "shifted_board_pose"]


class _Samples:
    """Precomputed ``A_k`` (M, 3, 6) and ``N^-1`` (6, 6) of sample points on the board's face."""

    def __init__(self, samples_board: np.ndarray) -> None:
        P = np.asarray(samples_board, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != 3 or len(P) < 3 or not np.all(np.isfinite(P)):
            raise ValueError(f"samples_board: expected finite (M>=3, 3) board-frame points, got {P.shape}")
        A = np.zeros((len(P), 3, POSE3_DOF))
        A[:, :, :3] = -skew(P)
        A[:, :, 3:] = np.eye(3)
        N = np.einsum("kia,kib->ab", A, A)
        if np.linalg.cond(N) > 1e12:
            raise ValueError("samples_board: the sample points are collinear; they must span the board")
        self.P = P
        self.A = A
        self.Ninv = np.linalg.inv(N)


def range_offset_direction(
    o_board: np.ndarray, samples_board: np.ndarray | _Samples, H_o: np.ndarray | None = None
) -> np.ndarray:
    """``g(o)`` (6,): the board pose's right-tangent change per metre of range offset.

    Parameters
    ----------
    o_board : (3,) LiDAR origin in the board frame, metres.
    samples_board : (M, 3) points of the board's face in the board frame (e.g. a grid over its extent).
    H_o : optional (6, 3) array filled with ``d g / d o``.
    """
    s = samples_board if isinstance(samples_board, _Samples) else _Samples(samples_board)
    q = s.P - np.asarray(o_board, dtype=np.float64).reshape(1, 3)
    r = np.linalg.norm(q, axis=1)
    d = q / r[:, None]
    g = s.Ninv @ np.einsum("kia,ki->a", s.A, d)
    if H_o is not None:
        D_d_o = -(np.eye(3)[None] - d[:, :, None] * d[:, None, :]) / r[:, None, None]  # (M, 3, 3)
        H_o[:] = s.Ninv @ np.einsum("kia,kij->aj", s.A, D_d_o)
    return g


def shifted_board_pose(
    T_lidar_board: gtsam.Pose3, offset_m: float, samples_board: np.ndarray | _Samples
) -> gtsam.Pose3:
    """The board pose a LiDAR reading ``offset_m`` long reports (first order): ``T * Expmap(b g(o))``."""
    o = T_lidar_board.transformTo(np.zeros(3))
    return T_lidar_board.compose(gtsam.Pose3.Expmap(offset_m * range_offset_direction(o, samples_board)))


def range_offset_error(
    T_measured: gtsam.Pose3,
    T_lidar_board: gtsam.Pose3,
    offset_m: float,
    samples_board: np.ndarray | _Samples,
    H_T: np.ndarray | None = None,
    H_b: np.ndarray | None = None,
) -> np.ndarray:
    """``T_measured.localCoordinates(T_lidar_board * Expmap(b g(o)))`` (6,), rotation first.

    Parameters
    ----------
    T_measured : the board pose the LiDAR stage reported (LiDAR frame).
    T_lidar_board : the true board pose (the graph variable).
    offset_m : ``b``, metres (measured range minus true range).
    samples_board : (M, 3) board-face points, board frame.
    H_T, H_b : optional (6, 6) and (6, 1) arrays filled with the derivatives w.r.t. ``T_lidar_board``
        (GTSAM Pose3 tangent) and ``b``.
    """
    s = samples_board if isinstance(samples_board, _Samples) else _Samples(samples_board)
    want = H_T is not None or H_b is not None
    if not want:
        h = shifted_board_pose(T_lidar_board, offset_m, s)
        return np.asarray(gtsam.Pose3.Logmap(T_measured.between(h)), dtype=np.float64)
    D_o_T = np.zeros((3, POSE3_DOF), order="F")
    o = T_lidar_board.transformTo(np.zeros(3), D_o_T)
    D_g_o = np.zeros((POSE3_DOF, 3))
    g = range_offset_direction(o, s, D_g_o)
    D_E_x = np.zeros((POSE3_DOF, POSE3_DOF), order="F")
    E = gtsam.Pose3.Expmap(offset_m * g, D_E_x)
    D_h_T = np.zeros((POSE3_DOF, POSE3_DOF), order="F")
    D_h_E = np.zeros((POSE3_DOF, POSE3_DOF), order="F")
    h = T_lidar_board.compose(E, D_h_T, D_h_E)
    D_rel_h = np.zeros((POSE3_DOF, POSE3_DOF), order="F")
    rel = T_measured.between(h, None, D_rel_h)
    D_e_rel = np.zeros((POSE3_DOF, POSE3_DOF), order="F")
    e = np.asarray(gtsam.Pose3.Logmap(rel, D_e_rel), dtype=np.float64)
    D_e_h = D_e_rel @ D_rel_h
    D_e_E = D_e_h @ D_h_E @ D_E_x  # w.r.t. the tangent argument b g
    if H_T is not None:
        H_T[:] = D_e_h @ D_h_T + offset_m * D_e_E @ D_g_o @ D_o_T
    if H_b is not None:
        H_b[:] = (D_e_E @ g).reshape(POSE3_DOF, 1)
    return e


class RangeOffsetBoardFactor:
    """The board-pose prior with a range offset: keys (``T_lidar_board`` Pose3, ``b`` Vector1, metres).

    Parameters
    ----------
    key_lidar_board, key_offset : GTSAM keys.
    T_measured : (4, 4) or Pose3, the LiDAR stage's board pose.
    covariance : (6, 6) its Pose3-tangent covariance (rotation first).
    samples_board : (M, 3) board-face points in the board frame over which the LiDAR fit averages.
    """

    def __init__(
        self,
        key_lidar_board: int,
        key_offset: int,
        T_measured: np.ndarray | gtsam.Pose3,
        covariance: np.ndarray,
        samples_board: np.ndarray,
    ) -> None:
        self.keys = (int(key_lidar_board), int(key_offset))
        self.T_measured = T_measured if isinstance(T_measured, gtsam.Pose3) else gtsam.Pose3(T_measured)
        self.covariance = np.asarray(covariance, dtype=np.float64)
        self.samples = _Samples(samples_board)

    def _error(
        self, this: gtsam.CustomFactor, values: gtsam.Values, H: gtsam.JacobianVector | None
    ) -> np.ndarray:
        keys = this.keys()
        T, b = values.atPose3(keys[0]), float(values.atVector(keys[1])[0])
        if H is None:
            return range_offset_error(self.T_measured, T, b, self.samples)
        H_T = np.zeros((POSE3_DOF, POSE3_DOF), order="F")
        H_b = np.zeros((POSE3_DOF, 1), order="F")
        e = range_offset_error(self.T_measured, T, b, self.samples, H_T, H_b)
        H[0], H[1] = H_T, H_b
        return e

    def factor(self) -> gtsam.CustomFactor:
        """The GTSAM factor with ``noiseModel.Gaussian.Covariance(covariance, smart=False)`` (GTSAM's
        default ``smart=True`` zeroes off-diagonals below 1e-9: real correlations in rad^2 and m^2)."""
        noise = gtsam.noiseModel.Gaussian.Covariance(self.covariance, False)
        return gtsam.CustomFactor(noise, list(self.keys), self._error)
