"""A board's returns factor in compact form: the same cost from the returns' moments, for optimising.

A ``BoardPointsFactor`` has one row per return (~1000 per board): every linearisation evaluates and
hands GTSAM an (M x (6 + n)) Jacobian. Each whitened height is linear in a few products of the
variables: with the board normal ``n = R e_z``, its translation ``t``, the active LiDAR parameters
``l`` and a fixed centre ``c`` (the board's measured origin),

    h_j = n . (p_j - c) + n . (c - t) + sum_{a, i} n_a l_i (-u_ja A_ji + e_ja E_ji)

(``A_ji`` the return's range coefficients, ``E_ji`` its elevation coefficients times its range, see
board_points.py), i.e. ``h = F theta`` with fixed features ``F`` (M x (4 + 3k)) and ``theta = (n,
n . (c - t), n (x) l)``. The point rows' cost is ``|P diag(w) F theta|^2 / s`` (w the rows' weights,
P the whitening of the board's random effects: its plane, its beams' offsets; s the points' variance
scale) = ``theta^T G theta``, and ``G`` comes from ``F_w^T F_w`` and ``Q^T F_w`` (Q the orthonormal
basis of the random effects' Jacobian), computed once per board. This factor's error is
``L theta`` with ``L^T L = G`` (4 + 3k rows) plus the three in-plane prior rows: the same cost and
the same Gauss-Newton system (``J^T J``, ``J^T r``) as the full factor, to rounding, at any value of
the variables. It is for the optimiser only: the core's per-row
statistics (redundancies, the gate, the plane's rows) use the full factor.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from factors.board_points import BoardPointsFactor
from factors.grouped import POSE3_DOF, GroupedFactor

__all__ = ["CompactBoardPoints", "Moments", "moments_of"]


@dataclass(frozen=True)
class Moments:
    """What the compact factor keeps of a board's returns: the centre ``c`` (3,) in the LiDAR frame
    (m), ``FtF`` = F_w^T F_w and ``QtF`` = Q^T F_w (None without random effects), unscaled."""

    centre: np.ndarray
    FtF: np.ndarray
    QtF: np.ndarray | None

    @property
    def n_theta(self) -> int:
        return len(self.FtF)


def moments_of(f: BoardPointsFactor) -> Moments:
    """The moments of ``f``'s returns (its features weighted by the unscaled row weights)."""
    c = np.asarray(f.T_measured.translation(), dtype=np.float64)
    M, k = f.n_points, len(f.active)
    F = np.empty((M, 4 + 3 * k))
    F[:, :3] = f.points - c
    F[:, 3] = 1.0
    g = -f.u[:, :, None] * f._A_range[:, None, :]  # (M, 3, k): d h / d (n_a l_i)
    if f._elevation is not None:
        A_elev, elev_dir = f._elevation
        g += elev_dir[:, :, None] * A_elev[:, None, :]
    F[:, 4:] = g.reshape(M, 3 * k)
    Fw = f.weight[:, None] * F
    QtF = None if f._plane is None else f._plane[1].T @ Fw
    return Moments(c, Fw.T @ Fw, QtF)


class CompactBoardPoints(GroupedFactor[gtsam.Pose3, np.ndarray]):
    """``f``'s cost on (``T_lidar_board``, LiDAR parameters ``l``) with ``n_theta + 3`` rows.

    ``moments``: ``moments_of`` of ``f`` or of the unscaled factor ``f`` was scaled from (the
    scales and the plane's whitening are taken from ``f``).
    """

    def __init__(self, f: BoardPointsFactor, moments: Moments | None = None) -> None:
        m = moments_of(f) if moments is None else moments
        self.base, self.moments = f, m
        self.keys = f.keys
        G = m.FtF.copy()
        if f._plane is not None and f._whiten is not None and m.QtF is not None:
            U, c = f._whiten
            UtF = (f._plane[1].T @ U).T @ m.QtF  # U = Q V: U^T F_w = V^T Q^T F_w
            G += UtF.T @ ((2.0 * c + c * c)[:, None] * UtF)
        G /= f.scale
        lam, V = np.linalg.eigh(0.5 * (G + G.T))
        self.L = np.sqrt(np.maximum(lam, 0.0))[:, None] * V.T  # L^T L = G

    @property
    def dim(self) -> int:
        return self.moments.n_theta + 3

    def _variables(self, values: gtsam.Values, keys: Sequence[int]) -> tuple[gtsam.Pose3, np.ndarray]:
        return values.atPose3(keys[0]), values.atVector(keys[1])

    def evaluate(
        self, T: gtsam.Pose3, lidar: np.ndarray, jacobians: bool
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Error (n_theta + 3,) and ``order="F"`` Jacobians w.r.t. ``T`` (., 6) and ``l`` (., n_params)."""
        f = self.base
        la = np.asarray(lidar, dtype=np.float64).reshape(f.n_params)[f.active]
        R, t = T.rotation().matrix(), T.translation()
        n = R[:, 2]
        k = len(la)
        theta = np.empty(self.moments.n_theta)
        theta[:3] = n
        theta[3] = n @ (self.moments.centre - t)
        theta[4:] = np.outer(n, la).ravel()
        r_pts = self.L @ theta
        nt = self.moments.n_theta
        if not jacobians:
            return np.concatenate([r_pts, f.inplane_error(T)]), None, None
        H_T = np.empty((nt + 3, POSE3_DOF), order="F")
        err = np.concatenate([r_pts, f.inplane_error(T, H_T[nt:])])
        # d theta / d (omega, v, l): dn/d omega = (-R e_y, R e_x, 0) (T Exp(xi)), dt/dv = R
        dn = np.column_stack([-R[:, 1], R[:, 0], np.zeros(3)])
        D = np.zeros((self.moments.n_theta, POSE3_DOF + k))
        D[:3, :3] = dn
        D[3, :3] = (self.moments.centre - t) @ dn
        D[3, 3:6] = -n @ R
        D[4:, :3] = (dn[:, None, :] * la[None, :, None]).reshape(3 * k, 3)
        i = np.arange(k)
        for a in range(3):
            D[4 + a * k + i, POSE3_DOF + i] = n[a]  # d (n_a l_i) / d l_i
        LD = self.L @ D
        H_T[:nt] = LD[:, :POSE3_DOF]
        H_l = np.zeros((nt + 3, f.n_params), order="F")
        H_l[:nt, f.active] = LD[:, POSE3_DOF:]
        return err, H_T, H_l
