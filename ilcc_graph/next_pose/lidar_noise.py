"""The LiDAR board prior's covariance predicted for a board pose (``BoardNoiseModel``), fitted to
the covariances the LiDAR stage gave (``fit_noise_model``); see the package docstring."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from ilcc_graph.board import Board
from ilcc_graph.lidar.covariance import assemble_covariance, ray_coupling, sampling_covariance
from ilcc_graph.lidar.soft_edge import soft_intensity
from ilcc_graph.lidars import LidarModel
from ilcc_graph.next_pose.pose_geometry import MIN_BEAMS, beam_hits
from ilcc_graph.types import GraphFrame

__all__ = ["BoardNoiseModel", "fit_noise_model"]


def _plane_parts(b: np.ndarray, ring: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3, 3) iid and per-beam-bias parts of the plane fit's (rx, ry, tz) covariance, unit variances."""
    A = np.column_stack([b[:, 1], -b[:, 0], np.ones(len(b))])
    Ninv = np.linalg.inv(A.T @ A)
    groups = np.unique(ring, return_inverse=True)[1]
    S = np.zeros((int(groups.max()) + 1, 3))
    np.add.at(S, groups, A)
    return Ninv, Ninv @ S.T @ S @ Ninv


def _footprint_sigma(lidar: LidarModel, rng: float) -> float:
    return 0.5 * (0.01 + lidar.beam_divergence_rad * rng) / 2.0


def _soft_part(b: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(3, 3) inverse information of the soft-edged intensity model (unit contrast and noise) of
    (rz, tx, ty), from its gradients ``g`` (M, 2) at the returns ``b``."""
    J = np.column_stack([g[:, 0] * b[:, 1] - g[:, 1] * b[:, 0], -g[:, 0], -g[:, 1]])
    return np.linalg.inv(J.T @ J + 1e-12 * np.eye(3))


def _sampling_part(b: np.ndarray, ring: np.ndarray, board: Board, blur: float) -> np.ndarray:
    """(3, 3) the stage's edge-sampling covariance of (rz, tx, ty) for returns ``b``."""
    colour = board.colour_at(b[:, :2])
    cls = np.where(np.isfinite(colour), np.round(np.nan_to_num(colour)), -1).astype(int)
    samp = sampling_covariance(b[:, :2], cls, ring, board, blur)
    return samp if np.all(np.isfinite(samp)) else np.zeros((3, 3))


@dataclass(frozen=True)
class _Parts:
    plane: tuple[np.ndarray, np.ndarray]
    inplane: tuple[np.ndarray, np.ndarray | None]  # the sampling part only when asked for
    K: np.ndarray


def _parts(
    T_lidar_board: np.ndarray, board: Board, lidar: LidarModel, sampling: bool = True
) -> _Parts | None:
    b, ring, u = beam_hits(T_lidar_board, board, lidar)
    if len(b) < 12 or len(np.unique(ring)) < MIN_BEAMS:
        return None
    blur = _footprint_sigma(lidar, float(np.linalg.norm(np.asarray(T_lidar_board)[:3, 3])))
    _, g = soft_intensity(b[:, :2], board, 0.0, 1.0, blur)
    samp = _sampling_part(b, ring, board, blur) if sampling else None
    K = ray_coupling(b[:, :2], u, np.sum(g * g, axis=1))
    return _Parts(_plane_parts(b, ring), (_soft_part(b, g), samp), K)


@dataclass(frozen=True)
class BoardNoiseModel:
    """The LiDAR board prior's covariance for a board pose (module docstring): ``plane`` (a, b) and
    ``inplane`` (c, d) scales; ``frames``: how many observed boards they were fitted on."""

    plane: tuple[float, float]
    inplane: tuple[float, float]
    frames: int = 0

    @classmethod
    def default(cls, lidar: LidarModel) -> BoardNoiseModel:
        """Without observed boards: the LiDAR's range noise along the normal, a 3 mm bias per beam,
        the soft model at a contrast-to-noise of 10 and the sampling as it is."""
        return cls((lidar.range_sigma_m**2, 0.003**2), (0.1**2, 1.0))

    def covariance(self, T_lidar_board: np.ndarray, board: Board, lidar: LidarModel) -> np.ndarray | None:
        """(6, 6) predicted Pose3 covariance of the board's LiDAR pose, or None when fewer than
        ``MIN_BEAMS`` beams cross it."""
        p = _parts(T_lidar_board, board, lidar, sampling=self.inplane[1] > 0)
        return None if p is None else self._assemble(p)

    def _assemble(self, p: _Parts) -> np.ndarray:
        out = self.plane[0] * p.plane[0] + self.plane[1] * p.plane[1]
        inn = self.inplane[0] * p.inplane[0]
        if p.inplane[1] is not None:
            inn = inn + self.inplane[1] * p.inplane[1]
        return assemble_covariance(out, inn, p.K)


_IO, _II = [0, 1, 5], [2, 3, 4]


def fit_noise_model(frames: Sequence[GraphFrame], board: Board, lidar: LidarModel) -> BoardNoiseModel:
    """The scales of :class:`BoardNoiseModel` fitted to the LiDAR stage's covariances of ``frames``
    (non-negative least squares on the diagonals, each relative to its observed value); the
    default for what fewer than two usable frames cannot tell."""
    rows_o, rows_i = [], []
    for f in frames:
        p = _parts(f.T_lidar_board, board, lidar)
        C = np.asarray(f.board_cov, dtype=np.float64)
        if p is None or not np.all(np.isfinite(C)):
            continue
        soft, samp = p.inplane
        assert samp is not None  # _parts gives the sampling part when asked (the default)
        Co = C[np.ix_(_IO, _IO)]
        Ci = C[np.ix_(_II, _II)] - p.K @ Co @ p.K.T  # what the coupling does not explain
        for k in range(3):
            if Co[k, k] > 0:
                rows_o.append([p.plane[0][k, k] / Co[k, k], p.plane[1][k, k] / Co[k, k]])
            if Ci[k, k] > 0:
                rows_i.append([soft[k, k] / Ci[k, k], samp[k, k] / Ci[k, k]])
    d = BoardNoiseModel.default(lidar)

    def fit(rows: list, fallback: tuple[float, float]) -> tuple[float, float]:
        if len(rows) < 6:
            return fallback
        x, _ = nnls(np.asarray(rows), np.ones(len(rows)))
        return (float(x[0]), float(x[1])) if np.any(x > 0) else fallback

    return BoardNoiseModel(fit(rows_o, d.plane), fit(rows_i, d.inplane), len(rows_o) // 3)
