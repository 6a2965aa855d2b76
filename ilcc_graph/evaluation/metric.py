"""How right is an extrinsic? The paper's intensity-based re-projection error and corner errors.

The intensity metric follows Wang et al. 2017, Section 6.3 (their Equation 14), as we read it
(written out in ``docs/report.md``):

1. The board's LiDAR points ``p_i`` are taken into the camera with ``T_cam_lidar`` and projected.
2. Only points that land inside one of the quadrilaterals of the *detected* image corners count
   (``N_in`` of them). Each cell's homography maps the point to the image pattern's coordinates
   ``(a, b)`` (in squares; inner corner (i, j) sits at ``(j+1, i+1)``, the board frame over ``s``).
3. A point's colour from its intensity uses the gray zone with ``epsilon_g = 4``
   (``tau_l = (3 R_L + R_H) / 4``, ``tau_h = (R_L + 3 R_H) / 4``); points in the zone count as
   agreeing (``f_g = 0``).
4. A point whose intensity colour differs from the pattern's colour at ``(a, b)`` costs
   ``f_d``: the L1 distance to the nearest grid lines, ``s (|a - round a| + |b - round b|)``
   metres on the board; divided by the point's range it is an angle.
5. Frame value ``E = sum_in(f_d / range) / N_in / rho`` with the attendance rate
   ``rho = N_in / N_expected``: ``N_expected`` counts the points that the LiDAR fit puts inside
   the inner-corner rectangle, so points pushed off the pattern by a wrong extrinsic raise the
   error. Reported in mrad; a perfect extrinsic gives about zero.

All functions are pure: numpy and the project's camera/board models in, dataclasses out. The
per-frame and overall numbers, and what they are computed from, are in ``evaluation``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..board import Board
from ..cameras import CameraModel
from ..image.previews import circular_mean_u

__all__ = [
    "EPSILON_G",
    "EvalFrame",
    "MetricPoints",
    "FrameEvaluation",
    "Evaluation",
    "gray_zone",
    "intensity_colour",
    "cell_coordinates",
    "circular_mean_u",
    "metric_points",
    "metric_points_many",
    "transform_points",
]

#: The paper's gray-zone width for evaluation (Section 6.3): the middle half between the peaks.
EPSILON_G = 4.0


# --------------------------------------------------------------------------------- data
@dataclass(frozen=True)
class EvalFrame:
    """What the metric needs from one frame.

    name: frame stem.
    points_lidar: (M, 3) the board segment's points, LiDAR frame, metres.
    intensity: (M,) their reflectance intensities.
    uv: (K, 2) detected image corners, pixels, board index order (up to the half turn).
    corners_lidar: (K, 3) the LiDAR corners (for the corner re-projection error) or None.
    T_lidar_board: (4, 4) the LiDAR board fit (for the attendance rate) or None.
    """

    name: str
    points_lidar: np.ndarray
    intensity: np.ndarray
    uv: np.ndarray
    corners_lidar: np.ndarray | None = None
    T_lidar_board: np.ndarray | None = None


@dataclass(frozen=True)
class MetricPoints:
    """Per-point workings of the intensity metric for one frame (for overlays and tests).

    uv: (M, 2) projected pixels (NaN when not imaged). inside: (M,) within a detected cell.
    ab: (M, 2) image-pattern coordinates in squares (NaN outside). colour: (M,) intensity colour,
    0 black, 1 white, -1 gray. pattern: (M,) pattern colour at ``ab`` (NaN outside).
    mismatch: (M,) inside, not gray, colours differ. f_d: (M,) metres (0 unless mismatch).
    range_m: (M,) distance from the LiDAR. expected: (M,) the LiDAR fit puts it inside the
    inner-corner rectangle (all False when the fit is unknown). gray: (tau_l, tau_h).
    """

    uv: np.ndarray
    inside: np.ndarray
    ab: np.ndarray
    colour: np.ndarray
    pattern: np.ndarray
    mismatch: np.ndarray
    f_d: np.ndarray
    range_m: np.ndarray
    expected: np.ndarray
    gray: tuple[float, float]


@dataclass(frozen=True)
class FrameEvaluation:
    """Numbers for one frame under one extrinsic.

    intensity_mrad: the paper's re-projection error (module docstring), mrad; inf when no board
        point lands inside the detected corners although some should; NaN when not computable.
    n_points, n_inside, n_mismatch: board points, those inside the detected cells, those whose
        colours disagree. attendance: N_in / N_expected (<= 1; NaN when unknown).
    corner_rms_px, corner_max_px: LiDAR corners re-projected vs detected corners, pixels.
    corner_rms_mrad: the same as angles between bearings.
    half_turn: the corner errors used the board's half-turned order (better match).
    range_m: median range of the board points.
    """

    name: str
    intensity_mrad: float
    n_points: int
    n_inside: int
    n_mismatch: int
    attendance: float
    corner_rms_px: float = float("nan")
    corner_max_px: float = float("nan")
    corner_rms_mrad: float = float("nan")
    half_turn: bool = False
    range_m: float = float("nan")


def _mean_3sigma(x: np.ndarray) -> tuple[float, float]:
    x = np.asarray(x, dtype=np.float64)
    x = x[~np.isnan(x)]
    if x.size == 0:
        return float("nan"), float("nan")
    if not np.all(np.isfinite(x)):
        return float("inf"), float("nan")
    return float(np.mean(x)), float(3.0 * np.std(x))


@dataclass(frozen=True)
class Evaluation:
    """Per-frame and overall numbers of one extrinsic on a set of frames.

    frames: one :class:`FrameEvaluation` per frame, input order. The overall numbers are the mean
    over frames and three standard deviations of the per-frame values (population std).
    """

    frames: tuple[FrameEvaluation, ...]
    T_cam_lidar: np.ndarray = field(default_factory=lambda: np.eye(4))

    def _stat(self, key: str) -> tuple[float, float]:
        return _mean_3sigma(np.array([getattr(f, key) for f in self.frames], dtype=np.float64))

    @property
    def intensity_mrad(self) -> tuple[float, float]:
        """(mean, 3 x SD) over frames of the paper's metric, mrad."""
        return self._stat("intensity_mrad")

    @property
    def corner_px(self) -> tuple[float, float]:
        """(mean, 3 x SD) over frames of the RMS corner error, pixels."""
        return self._stat("corner_rms_px")

    @property
    def corner_mrad(self) -> tuple[float, float]:
        """(mean, 3 x SD) over frames of the RMS corner bearing error, mrad."""
        return self._stat("corner_rms_mrad")

    def by_name(self) -> dict[str, FrameEvaluation]:
        return {f.name: f for f in self.frames}

    def summary(self) -> dict[str, float]:
        """Flat numbers for tables and YAML."""
        (im, i3), (pm, p3), (bm, b3) = self.intensity_mrad, self.corner_px, self.corner_mrad
        return {
            "frames": float(len(self.frames)),
            "intensity_mrad_mean": im,
            "intensity_mrad_3sigma": i3,
            "corner_px_mean": pm,
            "corner_px_3sigma": p3,
            "corner_mrad_mean": bm,
            "corner_mrad_3sigma": b3,
        }


# ---------------------------------------------------------------------------- helpers
def transform_points(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(N, 3) points ``p`` mapped by the 4x4 transform ``T``."""
    T = np.asarray(T, dtype=np.float64)
    return np.asarray(p, dtype=np.float64).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]


def gray_zone(intensity: np.ndarray, epsilon: float = EPSILON_G, bins: int = 100) -> tuple[float, float]:
    """(tau_l, tau_h) of the paper's gray zone.

    The intensities are split by Otsu's threshold on a ``bins`` histogram; ``R_L`` and ``R_H`` are
    the centres of the fullest bin on each side; ``tau_l = ((eps-1) R_L + R_H) / eps`` and
    ``tau_h = (R_L + (eps-1) R_H) / eps``. Constant intensities give (nan, nan).
    """
    r = np.asarray(intensity, dtype=np.float64)
    r = r[np.isfinite(r)]
    if r.size < 2 or np.ptp(r) <= 0:
        return float("nan"), float("nan")
    hist, edges = np.histogram(r, bins=bins)
    centres = 0.5 * (edges[1:] + edges[:-1])
    n_low = np.cumsum(hist)[:-1].astype(np.float64)
    n_high = r.size - n_low
    s_low = np.cumsum(hist * centres)[:-1]
    m_low = s_low / np.maximum(n_low, 1.0)
    m_high = (np.sum(hist * centres) - s_low) / np.maximum(n_high, 1.0)
    k = int(np.argmax(n_low * n_high * (m_high - m_low) ** 2))
    r_low = float(centres[: k + 1][np.argmax(hist[: k + 1])])
    r_high = float(centres[k + 1 :][np.argmax(hist[k + 1 :])])
    return ((epsilon - 1) * r_low + r_high) / epsilon, (r_low + (epsilon - 1) * r_high) / epsilon


def intensity_colour(intensity: np.ndarray, tau: tuple[float, float]) -> np.ndarray:
    """(M,) int8 colour from intensity: 0 black (r <= tau_l), 1 white (r >= tau_h), -1 gray."""
    r = np.asarray(intensity, dtype=np.float64)
    lo, hi = tau
    out = np.full(r.shape, -1, dtype=np.int8)
    if np.isfinite(lo) and np.isfinite(hi):
        out[r <= lo] = 0
        out[r >= hi] = 1
    return out


_H_CACHE: dict[bytes, np.ndarray] = {}
#: margin (px) of a cell's bounding box in ``cell_coordinates``
_BOX_PX = 0.01


def _unit_square_homographies(quads: np.ndarray) -> np.ndarray:
    """(C, 3, 3) homographies taking each quad (C, 4, 2) corners to (0,0), (1,0), (1,1), (0,1).

    Kept for the last few corner grids seen (a frame's grid is the same under every extrinsic the
    valley study tries); a copy is returned."""
    key = np.ascontiguousarray(quads, dtype=np.float64).tobytes()
    if key not in _H_CACHE:
        if len(_H_CACHE) >= 64:
            _H_CACHE.pop(next(iter(_H_CACHE)))
        _H_CACHE[key] = _homographies(quads)
    return _H_CACHE[key].copy()


def _homographies(quads: np.ndarray) -> np.ndarray:
    dst = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    C = quads.shape[0]
    A = np.zeros((C, 8, 8))
    b = np.zeros((C, 8))
    for n in range(4):
        x, y = quads[:, n, 0], quads[:, n, 1]
        X, Y = dst[n]
        A[:, 2 * n, 0:3] = np.stack([x, y, np.ones(C)], axis=1)
        A[:, 2 * n, 6:8] = np.stack([-X * x, -X * y], axis=1)
        A[:, 2 * n + 1, 3:6] = np.stack([x, y, np.ones(C)], axis=1)
        A[:, 2 * n + 1, 6:8] = np.stack([-Y * x, -Y * y], axis=1)
        b[:, 2 * n], b[:, 2 * n + 1] = X, Y
    H = np.full((C, 9), np.nan)
    ok = np.abs(np.linalg.det(A)) > 1e-12
    if np.any(ok):
        H[ok, :8] = np.linalg.solve(A[ok], b[ok][..., None])[..., 0]
        H[ok, 8] = 1.0
    return H.reshape(C, 3, 3)


def _unwrap(uv: np.ndarray, u_ref: float, camera: CameraModel) -> np.ndarray:
    """Panorama columns brought next to ``u_ref`` across the seam (other cameras: unchanged)."""
    if not camera.periodic_u:
        return uv
    out = np.array(uv, dtype=np.float64, copy=True)
    out[:, 0] = u_ref + camera.wrap_du(out[:, 0] - u_ref)
    return out


def cell_coordinates(uv: np.ndarray, corners_uv: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray]:
    """Which points lie in a cell of the detected corner grid, and where in the pattern.

    Parameters
    ----------
    uv : (M, 2) pixels (already unwrapped next to the corners for panoramas).
    corners_uv : (K, 2) detected inner corners, board index order.
    board : the chessboard (for the grid shape).

    Returns
    -------
    inside : (M,) bool.
    ab : (M, 2) pattern coordinates in squares (board frame / square size), NaN outside.
    """
    ni, nj = board.inner_shape
    G = np.asarray(corners_uv, dtype=np.float64).reshape(ni, nj, 2)
    quads = np.stack([G[:-1, :-1], G[:-1, 1:], G[1:, 1:], G[1:, :-1]], axis=2).reshape(-1, 4, 2)
    ci, cj = np.divmod(np.arange(quads.shape[0]), nj - 1)
    H = _unit_square_homographies(quads)
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    M = uv.shape[0]
    inside = np.zeros(M, dtype=bool)
    ab = np.full((M, 2), np.nan)
    finite = np.all(np.isfinite(uv), axis=1)
    if M == 0 or not np.any(finite):
        return inside, ab
    q = np.concatenate([uv[finite], np.ones((int(finite.sum()), 1))], axis=1)  # (F, 3)
    centre = np.concatenate([quads.mean(axis=1), np.ones((quads.shape[0], 1))], axis=1)
    w_centre = np.sum(H[:, 2, :] * centre, axis=1)
    # a point in a cell lies in its corners' bounding box: only those pairs are tested (a point a
    # hundredth of a pixel outside maps well outside the unit square)
    lo, hi = quads.min(axis=1) - _BOX_PX, quads.max(axis=1) + _BOX_PX  # (C, 2)
    cell = np.full(len(q), len(quads))  # the first cell hit, len(quads): none
    xy = np.full((len(q), 2), np.nan)
    for c in range(len(quads)):
        near = np.flatnonzero(
            (q[:, 0] >= lo[c, 0]) & (q[:, 0] <= hi[c, 0]) & (q[:, 1] >= lo[c, 1]) & (q[:, 1] <= hi[c, 1])
        )
        near = near[cell[near] > c]  # cells are tried in order: the first hit wins
        if not near.size:
            continue
        w = np.tensordot(H[c : c + 1], q[near], axes=([2], [1]))[0]  # (3, n)
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = w[0] / w[2], w[1] / w[2]
            hit = (x >= 0) & (x <= 1) & (y >= 0) & (y <= 1) & (np.sign(w[2]) == np.sign(w_centre[c]))
        got = near[hit]
        cell[got] = c
        xy[got, 0], xy[got, 1] = x[hit], y[hit]
    any_hit = cell < len(quads)
    idx = np.flatnonzero(finite)[any_hit]
    hit_cell = cell[any_hit]
    inside[idx] = True
    ab[idx, 0] = cj[hit_cell] + 1 + xy[any_hit, 0]
    ab[idx, 1] = ci[hit_cell] + 1 + xy[any_hit, 1]
    return inside, ab


# ------------------------------------------------------------------------ the metric
#: at most this many (cell, point) pairs are tested in one pass of ``metric_points_many``
_CELL_PAIRS = 2_000_000


def metric_points(
    frame: EvalFrame,
    camera: CameraModel,
    board: Board,
    T_cam_lidar: np.ndarray,
    epsilon: float = EPSILON_G,
) -> MetricPoints:
    """Per-point workings of the intensity metric (module docstring) for one frame."""
    return metric_points_many(frame, camera, board, [T_cam_lidar], epsilon)[0]


def metric_points_many(
    frame: EvalFrame,
    camera: CameraModel,
    board: Board,
    Ts: Sequence[np.ndarray],
    epsilon: float = EPSILON_G,
) -> list[MetricPoints]:
    """``metric_points`` of one frame under each extrinsic of ``Ts`` (4x4 each), in order: the
    frame's own parts (gray zone, expected points, ranges) once, the points of many extrinsics
    placed in the detected cells in one pass (the valley study tries 66 extrinsics per frame)."""
    p = np.asarray(frame.points_lidar, dtype=np.float64).reshape(-1, 3)
    corners_uv = np.asarray(frame.uv, dtype=np.float64).reshape(-1, 2)
    if corners_uv.shape[0] != board.n_corners:
        raise ValueError(
            f"metric_points: frame {frame.name!r} has {corners_uv.shape[0]} image corners, "
            f"the board has {board.n_corners}"
        )
    u_ref = (
        circular_mean_u(corners_uv[:, 0], camera.width)
        if camera.periodic_u
        else float(np.nanmedian(corners_uv[:, 0]))
    )
    corners = _unwrap(corners_uv, u_ref, camera)
    tau = gray_zone(frame.intensity, epsilon)
    colour = intensity_colour(frame.intensity, tau)
    s = board.square_size
    expected = np.zeros(len(p), dtype=bool)
    if frame.T_lidar_board is not None and len(p):
        xy = transform_points(np.linalg.inv(np.asarray(frame.T_lidar_board, dtype=np.float64)), p)[:, :2]
        ni, nj = board.inner_shape
        expected = (xy[:, 0] >= s) & (xy[:, 0] <= nj * s) & (xy[:, 1] >= s) & (xy[:, 1] <= ni * s)
    range_m = np.linalg.norm(p, axis=1)
    cells = (board.inner_shape[0] - 1) * (board.inner_shape[1] - 1)
    step = max(1, _CELL_PAIRS // max(1, cells * len(p)))
    out = []
    for k0 in range(0, len(Ts), step):
        chunk = Ts[k0 : k0 + step]
        if len(p):
            uv = camera.project(np.concatenate([transform_points(T, p) for T in chunk]))
        else:
            uv = np.zeros((0, 2))
        inside, ab = cell_coordinates(_unwrap(uv, u_ref, camera), corners, board)
        pattern = np.full(len(uv), np.nan)
        if np.any(inside):
            pattern[inside] = board.colour_at(ab[inside] * s)
        for k in range(len(chunk)):
            rows = slice(k * len(p), (k + 1) * len(p))
            with np.errstate(invalid="ignore"):
                mismatch = inside[rows] & (colour >= 0) & (colour != pattern[rows])
            f_d = np.zeros(len(p))
            a = ab[rows][mismatch]
            f_d[mismatch] = s * np.sum(np.abs(a - np.round(a)), axis=1)
            out.append(
                MetricPoints(
                    uv=uv[rows],
                    inside=inside[rows],
                    ab=ab[rows],
                    colour=colour,
                    pattern=pattern[rows],
                    mismatch=mismatch,
                    f_d=f_d,
                    range_m=range_m,
                    expected=expected,
                    gray=tau,
                )
            )
    return out
