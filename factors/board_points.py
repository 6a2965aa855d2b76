"""A board's LiDAR returns in the graph, with the LiDAR's own errors as shared variables.

Keys: the board pose ``T_lidar_board`` (Pose3, ``p_lidar = T * p_board``) and the LiDAR's
intrinsic parameters ``l`` (a Vector shared by every board: per-beam range offsets, the dark-print
offset, a range scale, per-beam elevation offsets; which entry is which is the caller's layout).

Each return j (measured point ``p_j``, unit ray ``u_j``, range ``rho_j``) is corrected to first order

    q_j(l) = p_j - u_j (a_j . l) + rho_j e_j (b_j . l)

where ``a_j . l`` is its range error (measured minus true range, metres; e.g. its beam's offset, plus
the dark-print offset on black print, plus ``rho_j`` times the scale error) and ``b_j . l`` its
elevation error (rad), ``e_j`` the unit vector of increasing elevation at ``u_j``. ``a_j`` and
``b_j`` are sparse: each holds a few (parameter index, coefficient) pairs. The residual is the
corrected return's height above the board's plane, ``z`` of ``T^-1 q_j`` in the board frame,
divided by its sigma. The board's in-plane position comes from the LiDAR stage's intensity fit,
which the points do not see: a 3-dof prior ``W S Logmap(T_meas^-1 T)`` (S selects and couples the
components, W the square-root information of that fit) closes the board's pose. Jacobians are
analytic; one factor per board (see docs/factors.md for why few, large Python factors).

A real board is not the ideal plane of its LiDAR returns: the print and its backing bend, and the
LiDAR's errors that no term models (incidence, mixed edge returns) move a board's returns as a
whole. With ``plane_sigma = (offset_m, tilt_rad)`` each board's heights carry a random plane
``delta |n . u| + alpha x + beta y`` (board-frame x, y of each return; the offset ``delta`` a range
offset of the board's returns, along their rays) of those sigmas, marginalised in the
whitening: the rows are whitened by ``(I + G Sigma G^T)^(-1/2)`` (G the whitened Jacobian of the
plane's three parameters), computed in the 3-dimensional span of G. The returns then determine a
board's plane no better than that, while the LiDAR's shared terms still average over the boards.
With ``beam_sigma`` (and each return's beam in ``beams``) each beam's returns on the board also share
a random range offset of that sigma: a beam's error that changes from board to board (with range,
incidence, the print under it), which the shared per-beam offsets cannot hold. Its columns join G.
``scaled`` multiplies the plane's offset and tilt variances and the beams' variance by factors (their
variance components, estimated by the core from ``plane_rows``: the random effects' predicted values
in whitened rows).
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

from factors.grouped import POSE3_DOF, GroupedFactor

__all__ = ["BoardPointsFactor", "elevation_directions"]

#: A board's random effects: G (M, q) their whitened Jacobian, Q (M, q) and R (q, q) with G = Q R,
#: their variances (q,) and the kind of each column (q,) (0 the plane's offset, 1 its tilts, 2 a beam).
_Effects = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def elevation_directions(u: np.ndarray) -> np.ndarray:
    """(M, 3) unit vectors of increasing elevation at unit rays ``u`` (M, 3), LiDAR frame (z up)."""
    u = np.asarray(u, dtype=np.float64)
    h = np.hypot(u[:, 0], u[:, 1])
    az = np.arctan2(u[:, 1], u[:, 0])
    el = np.arctan2(u[:, 2], h)
    return np.column_stack([-np.sin(el) * np.cos(az), -np.sin(el) * np.sin(az), np.cos(el)])


def _dense_coefficients(index: np.ndarray, coef: np.ndarray, active: np.ndarray) -> np.ndarray:
    """(M, len(active)) the sparse (M, k) ``index`` / ``coef`` pairs as dense rows over ``active``
    (sorted; entries with coefficient 0 may name any index)."""
    out = np.zeros((len(index), len(active)))
    if len(active):
        col = np.minimum(np.searchsorted(active, index), len(active) - 1)
        np.add.at(out, (np.repeat(np.arange(len(index)), index.shape[1]), col.ravel()), coef.ravel())
    return out


def _checked_terms(
    what: str, index: np.ndarray, coef: np.ndarray | None, M: int, n_params: int
) -> tuple[np.ndarray, np.ndarray]:
    """(index int64 (M, k), coef float64 (M, k)) of the ``what`` terms (``range``, ``elevation``),
    checked: equal shapes, one row per return, indices within ``0..n_params - 1``."""
    i, c = np.asarray(index, dtype=np.int64), np.asarray(coef, dtype=np.float64)
    if i.shape != c.shape or i.ndim != 2 or i.shape[0] != M:
        raise ValueError(f"BoardPointsFactor: {what}_index/coef must be (M, k), got {i.shape}, {c.shape}")
    if i.size and (i.min() < 0 or i.max() >= n_params):
        raise ValueError(f"BoardPointsFactor: {what}_index outside 0..{n_params - 1}")
    return i, c


class BoardPointsFactor(GroupedFactor[gtsam.Pose3, np.ndarray]):
    """One board's returns and in-plane prior on (``T_lidar_board``, LiDAR parameters ``l``).

    Parameters
    ----------
    key_board, key_lidar : GTSAM keys (Pose3, Vector of dimension ``n_params``).
    points : (M, 3) measured returns, LiDAR frame, metres.
    sigma : (M,) one-sigma range noise of each return, metres, or one for all (its plane-height
        sigma is ``sigma * |n . u|``, n the normal of ``T_measured``: a noise model fixed at
        construction).
    range_index, range_coef : (M, k) parameter indices and coefficients of ``a_j`` (pad with
        coefficient 0); ``elevation_index``, ``elevation_coef`` likewise for ``b_j`` (or None).
    n_params : dimension of ``l``.
    T_measured : the LiDAR stage's board pose (4, 4) or Pose3.
    inplane_select : (3, 6) S, inplane_sqrt_info : (3, 3) W of the in-plane prior.
    plane_sigma : (offset m, tilt rad) of each board's own random plane, or None (ideal plane).
    beam_sigma, beams : sigma (m) of a random range offset per beam on this board, and the beam of
        each return (M,) (None: none).
    """

    def __init__(
        self,
        key_board: int,
        key_lidar: int,
        points: np.ndarray,
        sigma: np.ndarray | float,
        range_index: np.ndarray,
        range_coef: np.ndarray,
        n_params: int,
        T_measured: np.ndarray | gtsam.Pose3,
        inplane_select: np.ndarray,
        inplane_sqrt_info: np.ndarray,
        elevation_index: np.ndarray | None = None,
        elevation_coef: np.ndarray | None = None,
        plane_sigma: tuple[float, float] | None = None,
        beam_sigma: float | None = None,
        beams: np.ndarray | None = None,
    ) -> None:
        p = np.asarray(points, dtype=np.float64)
        M = len(p)
        if p.shape != (M, 3) or M < 3 or not np.all(np.isfinite(p)):
            raise ValueError(f"BoardPointsFactor: points must be finite (M >= 3, 3), got {p.shape}")
        s = np.broadcast_to(np.asarray(sigma, dtype=np.float64), (M,)).copy()
        if not np.all(s > 0):
            raise ValueError("BoardPointsFactor: sigma must be > 0")
        ri, rc = _checked_terms("range", range_index, range_coef, M, n_params)
        self.keys = (int(key_board), int(key_lidar))
        self.points = p
        self.rho = np.linalg.norm(p, axis=1)
        self.u = p / self.rho[:, None]
        self.sigma = s
        self.n_params = int(n_params)
        ei = ec = None
        if elevation_index is not None:
            ei, ec = _checked_terms("elevation", elevation_index, elevation_coef, M, n_params)
        # the parameters these returns depend on, and the dense (M, n_active) coefficients of a_j and
        # rho_j b_j on them: the corrections and Jacobians are then two small matrix products
        used = [ri[rc != 0]] + ([] if ei is None else [ei[ec != 0]])
        self.active = np.unique(np.concatenate(used)).astype(np.int64)
        self._A_range = _dense_coefficients(ri, rc, self.active)
        # the elevation terms: dense coefficients of rho_j b_j (M, n_active) and e_j (M, 3), or None
        self._elevation: tuple[np.ndarray, np.ndarray] | None = None
        if ei is not None:
            self._elevation = (
                _dense_coefficients(ei, self.rho[:, None] * ec, self.active),
                elevation_directions(self.u),
            )
        self.T_measured = T_measured if isinstance(T_measured, gtsam.Pose3) else gtsam.Pose3(T_measured)
        self.S = np.asarray(inplane_select, dtype=np.float64).reshape(3, POSE3_DOF)
        self.W = np.asarray(inplane_sqrt_info, dtype=np.float64).reshape(3, 3)
        n0 = self.T_measured.rotation().matrix()[:, 2]
        self.weight = 1.0 / (s * np.maximum(np.abs(self.u @ n0), 0.05))  # 1 / plane-height sigma
        self.scale = 1.0  # variance scale of the point rows (``scaled``)
        self.inplane_scale = 1.0
        self.plane_scale = (1.0, 1.0, 1.0)  # variance scales of the plane's offset, tilt and the beams
        # the random effects (_Effects), or None
        self._plane: _Effects | None = self._random_effects(plane_sigma, beam_sigma, beams)
        self._whiten = self._plane_whitening()

    def _random_effects(
        self, plane_sigma: tuple[float, float] | None, beam_sigma: float | None, beams: np.ndarray | None
    ) -> _Effects | None:
        """The random effects of this board (its plane's offset and tilt, each beam's range offset) as
        (G whitened columns (M, r), its QR factors Q and R, variances (r,), kinds (r,): 0 offset, 1
        tilt, 2 beam), or None (no effects)."""
        M, n0 = self.n_points, self.T_measured.rotation().matrix()[:, 2]
        cols: list[np.ndarray] = []
        var: list[float] = []
        kind: list[int] = []
        if plane_sigma is not None:
            so, st = (float(v) for v in plane_sigma)
            if not (so > 0 and st > 0):
                raise ValueError(f"BoardPointsFactor: plane_sigma must be > 0, got {plane_sigma!r}")
            R0, t0 = self.T_measured.rotation().matrix(), self.T_measured.translation()
            xy = ((self.points - t0) @ R0)[:, :2]
            # the offset as a range offset of all the board's returns (along their rays, as a
            # common range offset of the beams moves them): the boards' zero-mean offsets then
            # fix the beams' common level; along the normal, only the incidence's variation across
            # each board would tell the two apart, and the common level ran off (bench finding 10)
            cols.append(np.column_stack([np.abs(self.u @ n0), xy]))
            var += [so**2, st**2, st**2]
            kind += [0, 1, 1]
        if beam_sigma is not None:
            if not float(beam_sigma) > 0:
                raise ValueError(f"BoardPointsFactor: beam_sigma must be > 0, got {beam_sigma!r}")
            bm = np.asarray(beams).reshape(-1) if beams is not None else None
            if bm is None or bm.shape != (M,):
                raise ValueError("BoardPointsFactor: beam_sigma needs the beam of each return (M,)")
            ids = np.unique(bm)
            cols.append((bm[:, None] == ids[None, :]) * np.abs(self.u @ n0)[:, None])
            var += [float(beam_sigma) ** 2] * len(ids)
            kind += [2] * len(ids)
        if not cols:
            return None
        G = self.weight[:, None] * np.hstack(cols)
        Q, Rg = np.linalg.qr(G)
        return (G, Q, Rg, np.array(var), np.array(kind))

    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def dim(self) -> int:
        """Error dimension: one row per return, then three for the in-plane prior."""
        return self.n_points + 3

    def scaled(
        self,
        points_scale: float,
        inplane_scale: float,
        plane_scale: tuple[float, float] = (1.0, 1.0),
        beam_scale: float = 1.0,
    ) -> BoardPointsFactor:
        """The same data with the point, in-plane, plane (offset, tilt) and beam variances multiplied
        by the given factors."""
        import copy

        other = copy.copy(self)
        other.scale, other.inplane_scale = self.scale * points_scale, self.inplane_scale * inplane_scale
        po, pt, pb = self.plane_scale
        other.plane_scale = (po * plane_scale[0], pt * plane_scale[1], pb * beam_scale)
        other._whiten = other._plane_whitening()
        return other

    def plane_variances(self) -> np.ndarray | None:
        """(q,) the random effects' variances as scaled (the plane's offset m^2 and tilt rad^2 twice,
        then each beam's offset m^2), or None without any."""
        return None if self._plane is None else self._variances(self._plane)

    def _variances(self, plane: _Effects) -> np.ndarray:
        return plane[3] * np.asarray(self.plane_scale)[plane[4]]

    def _plane_whitening(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(U (M, q), c (q,)): the point rows' whitening is ``r + U (c * (U^T r))``."""
        if self._plane is None:
            return None
        _, Q, Rg, _, _ = self._plane
        A = Rg @ np.diag(self._variances(self._plane)) @ Rg.T
        lam, V = np.linalg.eigh(A / self.scale)
        return Q @ V, 1.0 / np.sqrt(1.0 + np.maximum(lam, 0.0)) - 1.0

    def plane_rows(self) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None] | None:
        """(Z_offset (M, 1), Z_tilt (M, 2), Z_beams (M, beams)), each None when that effect is
        absent: the random effects as seen in the whitened point rows, ``Z = V^(-1/2) G Sigma^(1/2)``
        (V the rows' covariance with the effects, G their Jacobian, Sigma their covariance; all in the
        rows' current whitening). With whitened residuals r, ``Z^T r`` are the effects' predicted
        values over their sigmas (their chi-square is ``|Z^T r|^2``) and ``trace(Z^T Z)`` minus what
        the graph's other variables explain of them is their redundancy (variance components of a
        random effect). None without any."""
        if self._plane is None:
            return None
        G = self._plane[0] / np.sqrt(self.scale)
        Z = self._plane_apply(G) * np.sqrt(self._variances(self._plane))
        kind = self._plane[4]
        parts = [Z[:, kind == k] for k in range(3)]
        offset, tilt, beams = (z if z.shape[1] else None for z in parts)
        return offset, tilt, beams

    def _plane_apply(self, r: np.ndarray) -> np.ndarray:
        """The board-plane whitening applied to point rows ``r`` (M,) or (M, k)."""
        if self._whiten is None:
            return r
        U, c = self._whiten
        proj = U.T @ r
        return r + U @ (c[:, None] * proj if r.ndim == 2 else c * proj)

    def corrected(self, lidar: np.ndarray) -> np.ndarray:
        """(M, 3) the returns corrected by the LiDAR parameters ``lidar`` (n_params,)."""
        la = np.asarray(lidar, dtype=np.float64)[self.active]
        q = self.points - self.u * (self._A_range @ la)[:, None]
        if self._elevation is not None:
            A_elev, elev_dir = self._elevation
            q = q + (A_elev @ la)[:, None] * elev_dir
        return q

    def inplane_error(self, T: gtsam.Pose3, H_T: np.ndarray | None = None) -> np.ndarray:
        """The in-plane prior's whitened error (3,) at the board pose ``T``; fills ``H_T`` (3, 6), when
        given, with its Jacobian w.r.t. ``T``."""
        Wi = self.W / np.sqrt(self.inplane_scale)
        if H_T is None:
            return Wi @ (self.S @ np.asarray(gtsam.Pose3.Logmap(self.T_measured.between(T))))
        H_log = np.zeros((POSE3_DOF, POSE3_DOF), order="F")
        H_btw = np.zeros((POSE3_DOF, POSE3_DOF), order="F")
        xi = np.asarray(gtsam.Pose3.Logmap(self.T_measured.between(T, None, H_btw), H_log))
        H_T[:] = Wi @ self.S @ H_log @ H_btw
        return Wi @ (self.S @ xi)

    def evaluate(
        self, T: gtsam.Pose3, lidar: np.ndarray, jacobians: bool
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Whitened error (M + 3,) and ``order="F"`` Jacobians w.r.t. ``T`` (M+3, 6) and ``l`` (M+3, n)."""
        lidar = np.asarray(lidar, dtype=np.float64).reshape(self.n_params)
        R, t = T.rotation().matrix(), T.translation()
        n = R[:, 2]
        pb = (self.corrected(lidar) - t) @ R  # board frame
        w = self.weight / np.sqrt(self.scale)
        M, k = self.n_points, len(self.active)
        if not jacobians:
            return np.concatenate([self._plane_apply(w * pb[:, 2]), self.inplane_error(T)]), None, None
        H_T = np.empty((M + 3, POSE3_DOF), order="F")
        r_in = self.inplane_error(T, H_T[M:])
        # the point rows' [error | d/d T | d/d l_active], whitened together by the board plane
        rows = np.empty((M, 1 + POSE3_DOF + k))
        rows[:, 0] = w * pb[:, 2]
        # z of Exp(xi)^-1 p_b: d/d omega = -(p_b x e_z) = (-y, x, 0), d/d v = (0, 0, -1)
        rows[:, 1] = -w * pb[:, 1]
        rows[:, 2] = w * pb[:, 0]
        rows[:, 3:6] = 0.0
        rows[:, 6] = -w
        rows[:, 7:] = -(w * (self.u @ n))[:, None] * self._A_range
        if self._elevation is not None:
            A_elev, elev_dir = self._elevation
            rows[:, 7:] += (w * (elev_dir @ n))[:, None] * A_elev
        rows = self._plane_apply(rows)
        err = np.concatenate([rows[:, 0], r_in])
        H_T[:M] = rows[:, 1:7]
        H_l = np.zeros((M + 3, self.n_params), order="F")
        H_l[:M, self.active] = rows[:, 7:]
        return err, H_T, H_l

    def _variables(self, values: gtsam.Values, keys: Sequence[int]) -> tuple[gtsam.Pose3, np.ndarray]:
        return values.atPose3(keys[0]), values.atVector(keys[1])
