"""OpenCV's pinhole camera, ``camera.model: pinhole``, and its radial-tangential distortion.

Camera frame OpenCV's (z forward, x right, y down). Config keys: ``model, width, height, K``
(3x3 or 9 numbers row-major) and ``dist`` (OpenCV order k1, k2, p1, p2[, k3[, k4, k5, k6]]: 4, 5
or 8 numbers; missing or [] = none). :class:`RadTan` is the distortion polynomial alone, shared
with other models that apply it to their own normalised coordinates.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar, Literal, overload

import numpy as np

from ..checks import MISSING, Checker
from .camera_model import R_FLU_OPENCV, LensModel, Normalised
from .common import config_dist, config_K, finite_vector, first_fold, solve_increasing
from .registry import register

_THETA_HI = np.pi / 2 - 1e-6  # radii are searched as r = tan(theta) up to here
#: k3.. that move no pixel by more than this are left out of a Kalibr camchain (Kalibr has no k3):
#: a twentieth of a pixel, below the noise of any corner detector (0.1-0.3 px). A refined k3 of a lens
#: with none moves pixels by 0.01-0.03 px, which must not block the export; a real k3 moves them by px.
KALIBR_PX = 0.05
#: Names of OpenCV's distortion coefficients, in its order.
DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


def _radial(d8: np.ndarray, r2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """rad(r2) of the coefficients ``d8`` (OpenCV's order), d rad / d r2 and the rational denominator."""
    k1, k2, _, _, k3, k4, k5, k6 = d8
    num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
    dnum = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    dden = k4 + r2 * (2 * k5 + 3 * k6 * r2)
    with np.errstate(divide="ignore", invalid="ignore"):
        return num / den, (dnum * den - num * dden) / (den * den), den


@functools.lru_cache(maxsize=1024)
def _r_max(d8: tuple[float, ...]) -> float:
    """``RadTan.r_max`` of the coefficients ``d8``: where the radial map g(r) = r rad(r^2) stops
    increasing, searched as r = tan(theta), theta < 90 deg. Kept per coefficients: a solve that
    refines the intrinsics builds the same camera for every view it evaluates."""
    k = np.array(d8)

    def dg_dtheta_sign(th: np.ndarray) -> np.ndarray:
        r = np.tan(th)
        rad, drad, den = _radial(k, r * r)
        return np.where(den > 0, rad + 2 * r * r * drad, -1.0)

    th = first_fold(dg_dtheta_sign, _THETA_HI)
    return np.inf if th >= _THETA_HI else float(np.tan(th))


@dataclass(frozen=True, eq=False)
class RadTan:
    """OpenCV's distortion of normalised coordinates (a, b) -> (xd, yd), as ``cv2.projectPoints``.

    ``d8`` = (k1, k2, p1, p2, k3, k4, k5, k6). With r2 = a^2 + b^2,
    ``rad = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)``,
    ``xd = a rad + 2 p1 a b + p2 (r2 + 2 a^2)``, ``yd = b rad + p1 (r2 + 2 b^2) + 2 p2 a b``.
    ``r_max``: the radius r = |(a, b)| where the radial map r -> r rad(r2) stops increasing
    (inf when it never does); beyond it the image of a point would be a ghost.
    """

    d8: np.ndarray
    r_max: float = field(init=False, default=np.inf)

    @classmethod
    def of(cls, dist: np.ndarray) -> RadTan:
        """From OpenCV's 0, 4, 5 or 8 coefficients (the rest zero)."""
        d8 = np.zeros(8)
        d8[: len(dist)] = dist
        return cls(d8)

    def __post_init__(self) -> None:
        object.__setattr__(self, "r_max", _r_max(tuple(float(x) for x in self.d8)))

    def radial(self, r2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """rad(r2), d rad / d r2 and the rational denominator."""
        return _radial(self.d8, r2)

    @overload
    def distort(
        self, a: np.ndarray, b: np.ndarray, jac: Literal[True]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...
    @overload
    def distort(
        self, a: np.ndarray, b: np.ndarray, jac: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]: ...
    def distort(
        self, a: np.ndarray, b: np.ndarray, jac: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Normalised (a, b) -> distorted (xd, yd) and d(xd, yd)/d(a, b) (N, 2, 2) when ``jac``."""
        p1, p2 = self.d8[2], self.d8[3]
        r2 = a * a + b * b
        rad, drad, _ = self.radial(r2)
        xd = a * rad + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
        yd = b * rad + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
        if not jac:
            return xd, yd, None
        D = np.empty((a.size, 2, 2))
        D[:, 0, 0] = rad + 2 * a * a * drad + 2 * p1 * b + 6 * p2 * a
        D[:, 0, 1] = 2 * a * b * drad + 2 * p1 * a + 2 * p2 * b
        D[:, 1, 0] = 2 * a * b * drad + 2 * p1 * a + 2 * p2 * b
        D[:, 1, 1] = rad + 2 * b * b * drad + 6 * p1 * b + 2 * p2 * a
        return xd, yd, D

    def d_coefficients(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(N, 2, 8) d (xd, yd) / d d8 at normalised (a, b), columns in :data:`DIST_NAMES` order."""
        r2 = a * a + b * b
        rad, _, den = self.radial(r2)
        powers = np.stack([r2, r2 * r2, r2 * r2 * r2], axis=1)  # r2, r2^2, r2^3
        with np.errstate(divide="ignore", invalid="ignore"):
            d_rad = np.empty((a.size, 8))
            d_rad[:, [0, 1, 4]] = powers / den[:, None]  # numerator: k1, k2, k3
            d_rad[:, 5:] = -(rad / den)[:, None] * powers  # denominator: k4, k5, k6
        d_rad[:, 2:4] = 0.0
        J = np.empty((a.size, 2, 8))
        J[:, 0], J[:, 1] = a[:, None] * d_rad, b[:, None] * d_rad
        J[:, 0, 2] = J[:, 1, 3] = 2 * a * b
        J[:, 1, 2] = r2 + 2 * b * b
        J[:, 0, 3] = r2 + 2 * a * a
        return J

    def _newton(
        self, a: np.ndarray, b: np.ndarray, xd: np.ndarray, yd: np.ndarray, iters: int = 50
    ) -> tuple[np.ndarray, np.ndarray]:
        """Solve distort(a, b) = (xd, yd) from a start (a, b); Newton with backtracking on the unsolved."""
        a, b = a.copy(), b.copy()
        act = np.flatnonzero(np.isfinite(a) & np.isfinite(b) & np.isfinite(xd) & np.isfinite(yd))
        tol = 1e-15 * (1 + np.hypot(xd, yd))
        for _ in range(iters):
            if act.size == 0:
                break
            aa, bb, tx, ty = a[act], b[act], xd[act], yd[act]
            fx, fy, D = self.distort(aa, bb, True)
            ex, ey = fx - tx, fy - ty
            err = np.hypot(ex, ey)
            det = D[:, 0, 0] * D[:, 1, 1] - D[:, 0, 1] * D[:, 1, 0]
            with np.errstate(divide="ignore", invalid="ignore"):
                da = (D[:, 1, 1] * ex - D[:, 0, 1] * ey) / det
                db = (-D[:, 1, 0] * ex + D[:, 0, 0] * ey) / det
            good = np.isfinite(da) & np.isfinite(db) & (err > tol[act])
            da, db = np.where(good, da, 0.0), np.where(good, db, 0.0)
            step = np.ones_like(aa)
            a1, b1 = aa - da, bb - db
            f1x, f1y, _ = self.distort(a1, b1, False)
            e1 = np.hypot(f1x - tx, f1y - ty)
            for _ in range(30):  # backtrack where the full step does not reduce the residual
                worse = good & ~(e1 < err)
                if not worse.any():
                    break
                step[worse] *= 0.5
                w = np.flatnonzero(worse)
                a1[w], b1[w] = aa[w] - step[w] * da[w], bb[w] - step[w] * db[w]
                f1x_w, f1y_w, _ = self.distort(a1[w], b1[w], False)
                e1[w] = np.hypot(f1x_w - tx[w], f1y_w - ty[w])
            accept = good & (e1 < err)
            a[act[accept]], b[act[accept]] = a1[accept], b1[accept]
            act = act[accept & (e1 > tol[act])]
        return a, b

    def undistort(self, xd: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(a, b, ok): normalised coordinates whose distortion is (xd, yd); ok False where none
        inside ``r_max`` reproduces them to 1e-10."""
        # radial-only inverse as the start, then Newton on the full model
        rho_d = np.hypot(xd, yd)
        r_hi = self.r_max if np.isfinite(self.r_max) else np.tan(_THETA_HI)

        def g(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            rad, drad, _ = self.radial(r * r)
            return r * rad, rad + 2 * r * r * drad

        # tangential terms can push pixels a little beyond the radial map's maximum: start those at r_hi
        r_top = r_hi * (1 - 1e-9)
        g_top = g(np.array([r_top]))[0][0]
        r = solve_increasing(g, np.minimum(rho_d, g_top), r_top)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(rho_d > 0, r / rho_d, 1.0)
        a, b = xd * s, yd * s
        a, b = self._newton(a, b, xd, yd)
        fx, fy, _ = self.distort(a, b, False)
        err = np.hypot(fx - xd, fy - yd)
        ok = (err <= 1e-10 * (1 + rho_d)) & (a * a + b * b < self.r_max**2)
        return a, b, ok


@register("pinhole")
@dataclass(frozen=True, eq=False)
class Pinhole(LensModel):
    """OpenCV's pinhole model, as ``cv2.projectPoints``; frame z forward, x right, y down.

    ``dist`` = (k1, k2, p1, p2[, k3[, k4, k5, k6]]) (0, 4, 5 or 8 numbers; 8 = rational model),
    applied to (a, b) = (x/z, y/z) by :class:`RadTan`;
    ``u = fx xd + skew yd + cx``, ``v = fy yd + cy`` (OpenCV ignores skew; keep it 0 to match).
    ``r_max``: the radius |(a, b)| where the radial map stops increasing (inf when it never
    does); points beyond it project to NaN.
    """

    R_flu_cam: ClassVar[np.ndarray] = R_FLU_OPENCV
    ros_models: ClassVar[tuple[str, ...]] = ("plumb_bob", "rational_polynomial")
    aliases: ClassVar[tuple[str, ...]] = (
        "perspective", "opencv", "plumb_bob", "rational_polynomial", "radtan", "brown", "brown_conrady",
    )  # fmt: skip
    kalibr_models: ClassVar[tuple[tuple[str, str], ...]] = (("pinhole", "radtan"), ("pinhole", "none"))
    config_keys: ClassVar[tuple[str, ...]] = (*LensModel.config_keys, "dist", "intrinsics_sigma")
    dist: np.ndarray = field(default_factory=lambda: np.zeros(0))
    r_max: float = field(init=False, repr=False, default=np.inf)
    _rt: RadTan = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._check_lens()
        object.__setattr__(self, "dist", finite_vector(self.dist, "dist"))
        if self.dist.size not in (0, 4, 5, 8):
            raise ValueError(
                f"pinhole dist must have 0, 4, 5 or 8 numbers (k1, k2, p1, p2[, k3[, k4, k5, k6]]), "
                f"got {self.dist.size}"
            )
        object.__setattr__(self, "_rt", RadTan.of(self.dist))
        object.__setattr__(self, "r_max", self._rt.r_max)
        self._check_intrinsics_sigma()

    def _radial(self, r2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """rad(r2), d rad / d r2 and the rational denominator (see :class:`RadTan`)."""
        return self._rt.radial(r2)

    # -- intrinsics after fx, fy, cx, cy: the coefficients of ``dist``
    @property
    def param_names(self) -> tuple[str, ...]:
        return DIST_NAMES[: self.dist.size]

    def params(self) -> np.ndarray:
        return np.array(self.dist)

    def _with_params(self, K: np.ndarray, q: np.ndarray) -> Pinhole:
        return replace(self, K=K, dist=q)

    def _normalised(self, p: np.ndarray, jac: bool, jac_params: bool) -> Normalised:
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            iz = np.where(z > 0, 1.0 / z, np.nan)
        a, b = x * iz, y * iz
        ok = (z > 0) & (a * a + b * b < self.r_max**2)
        xd, yd, D = self._rt.distort(a, b, jac)
        D_p = D_q = None
        if D is not None:  # jac
            dab = np.zeros((p.shape[0], 2, 3))
            dab[:, 0, 0] = dab[:, 1, 1] = iz
            dab[:, 0, 2] = -a * iz
            dab[:, 1, 2] = -b * iz
            D_p = D @ dab
        if jac_params:
            D_q = self._rt.d_coefficients(a, b)[:, :, : self.dist.size]
        return xd, yd, ok, D_p, D_q

    def _bearing(self, uv: np.ndarray) -> np.ndarray:
        a, b, ok = self._rt.undistort(*self._from_pixels(uv))
        n = np.sqrt(a * a + b * b + 1)
        out = np.stack([a / n, b / n, 1 / n], axis=1)
        out[~ok] = np.nan
        return out

    # -- config, export, simulation
    @classmethod
    def from_config(cls, c: Checker, d: dict, width: int, height: int) -> Pinhole:
        K = config_K(c, d.get("K", MISSING), "camera.K")
        return cls(width, height, K, config_dist(c, d, (4, 5, 8), [0.0] * 5))

    def ros_camera_info(self) -> tuple[str, list[float]] | None:
        dist = [float(v) for v in self.dist]
        if len(dist) == 8:
            return "rational_polynomial", dist
        return "plumb_bob", (dist + [0.0] * 5)[:5]

    @classmethod
    def ros_dist(cls, D: list[float]) -> list[float]:
        D = [float(v) for v in D]
        return (D + [0.0] * 5)[: max(5, len(D))]

    @classmethod
    def kalibr_section(cls, intrinsics: list[float], coeffs: list[float]) -> dict[str, Any]:
        K = cls._kalibr_K(0, intrinsics, coeffs, (0, 4))
        return {"K": K, "dist": cls.ros_dist(coeffs) if coeffs else []}  # radtan: k1, k2, p1, p2 and k3 = 0

    def kalibr(self) -> tuple[dict[str, Any], list[str]]:
        notes = []
        if np.any(self.dist[4:] != 0.0):  # Kalibr's radtan has k1, k2, p1, p2 only
            moved = self._pixels_moved_without_k3()
            if not moved <= KALIBR_PX:
                raise ValueError(
                    "Kalibr's radtan distortion has 4 coefficients (k1, k2, p1, p2); this camera's "
                    f"k3.. = {self.dist[4:].tolist()} move its pixels by up to {moved:.2g} px, so Kalibr "
                    "cannot hold it"
                )
            notes.append(
                f"k3.. = {self.dist[4:].tolist()} left out: they move no pixel by more than {moved:.2g} px."
            )
        return {
            "camera_model": "pinhole",
            "intrinsics": self._kalibr_fxfycxcy(),
            "distortion_model": "radtan",
            "distortion_coeffs": np.pad(self.dist, (0, max(0, 4 - self.dist.size)))[:4].tolist(),
        }, notes

    def _pixels_moved_without_k3(self) -> float:
        """Largest pixel shift over the image (a 33 x 33 grid of its pixels) from dropping k3.."""
        uv = np.stack(
            np.meshgrid(np.linspace(-0.5, self.width - 0.5, 33), np.linspace(-0.5, self.height - 0.5, 33)), -1
        )
        rays = self.bearing(uv.reshape(-1, 2))
        rays = rays[np.all(np.isfinite(rays), axis=1)]
        four = replace(self, dist=np.pad(self.dist[:4], (0, self.dist.size - 4)))
        d = np.linalg.norm(four.project(rays) - self.project(rays), axis=1)
        return float(np.max(d)) if d.size and np.all(np.isfinite(d)) else float("inf")

    @classmethod
    def default(cls, width: int | None = None) -> Pinhole:
        """W x 5W/8 (default 1920 x 1200), 90 deg horizontal field, mild barrel distortion."""
        w = 1920 if width is None else int(width)
        h = (w * 5) // 8
        f = 0.5 * w
        K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
        return cls(w, h, K, np.array([-0.05, 0.01, 0.0, 0.0, 0.0]))
