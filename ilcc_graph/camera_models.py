"""Camera models: pixel <-> bearing, with analytic Jacobians (``shared/interface.md``, "Camera models").

Pixels follow OpenCV (pixel centres at integers, the image spans [-0.5, W-0.5] x [-0.5, H-0.5]).
Camera frames: equirectangular x forward, y left, z up; pinhole and fisheye OpenCV's (z forward,
x right, y down). Every function is vectorised over leading axes: points ``(..., 3)``, pixels
``(..., 2)``. Each projection sits beside its derivative; ``project_with_jacobian`` returns both.

A point the camera cannot image projects to NaN: behind a pinhole, on the optical axis' far side
beyond the lens' field of view, and for both distorted models beyond the radius where the
distortion polynomial folds back (the image of such points would be a ghost), see
``Pinhole.r_max`` and ``Fisheye.theta_max``. ``make_camera`` is the only dispatch on camera type.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

_TWO_PI = 2.0 * np.pi


# ----------------------------------------------------------------------------- helpers
def _as_points(p: np.ndarray, dim: int, what: str) -> tuple[np.ndarray, tuple[int, ...]]:
    """Coerce to float64 (N, dim); return it with the leading shape to restore."""
    a = np.asarray(p, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != dim:
        raise ValueError(f"{what} must have shape (..., {dim}), got {a.shape}")
    return a.reshape(-1, dim), a.shape[:-1]


def _check_K(K: Any) -> np.ndarray:
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"K must be a finite 3x3 matrix, got {K.tolist() if K.size <= 16 else K.shape}")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise ValueError(
            f"K must be [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K.tolist()}"
        )
    return K


def _check_size(width: Any, height: Any) -> tuple[int, int]:
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise ValueError(f"camera {name} must be a positive integer (pixels), got {v!r}")
    return int(width), int(height)


def _solve_increasing(f, target: np.ndarray, hi: float, iters: int = 100) -> np.ndarray:
    """Solve f(x) = target for x in [0, hi], f increasing there with f(0) = 0; safeguarded Newton.

    ``f(x) -> (value, derivative)``. Targets outside [0, f(hi)] must be masked by the caller.
    """
    lo_b = np.zeros_like(target)
    hi_b = np.full_like(target, hi)
    x = np.clip(target, 0.0, hi)  # f(x) ~ x near 0 for every lens here
    for _ in range(iters):
        fx, dfx = f(x)
        r = fx - target
        lo_b = np.where(r < 0, x, lo_b)
        hi_b = np.where(r > 0, x, hi_b)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_new = x - r / dfx
        bad = ~np.isfinite(x_new) | (x_new <= lo_b) | (x_new >= hi_b)
        x_new = np.where(bad, 0.5 * (lo_b + hi_b), x_new)
        done = np.abs(x_new - x) <= 1e-15 * np.maximum(1.0, np.abs(x))
        x = x_new
        if np.all(done | (r == 0)):
            break
    return x


def _first_fold(dfdx, hi: float, n: int = 20001) -> float:
    """Smallest x in (0, hi) where dfdx(x) <= 0 (bisection-refined), or ``hi`` when there is none."""
    xs = np.linspace(0.0, hi, n)
    bad = ~(dfdx(xs) > 0)
    if not bad.any():
        return hi
    k = int(np.argmax(bad))
    lo, up = xs[max(k - 1, 0)], xs[k]
    for _ in range(60):
        mid = 0.5 * (lo + up)
        if dfdx(np.array([mid]))[0] > 0:
            lo = mid
        else:
            up = mid
    return float(lo)


# --------------------------------------------------------------------------- the base
@dataclass(frozen=True, eq=False)
class CameraModel(ABC):
    """A calibrated camera: pixel (u, v) <-> unit bearing in the camera frame.

    width, height: image size in pixels.
    """

    kind: ClassVar[str] = ""
    #: Rotation from this camera's frame to a forward-left-up frame (x forward, y left, z up):
    #: identity for the panorama, OpenCV's z-forward/x-right/y-down axes otherwise.
    R_flu_cam: ClassVar[np.ndarray] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    width: int
    height: int

    # -- projection and its Jacobian
    @abstractmethod
    def _project(self, p: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """p (N, 3) -> uv (N, 2) and, when ``jac``, d uv / d p (N, 2, 3); NaN where not imaged."""

    @abstractmethod
    def _bearing(self, uv: np.ndarray) -> np.ndarray:
        """uv (N, 2) -> unit bearings (N, 3); NaN where no ray maps to the pixel."""

    def project(self, p_cam: np.ndarray) -> np.ndarray:
        """Pixels (..., 2) of camera-frame points (..., 3); NaN where the point cannot be imaged."""
        p, lead = _as_points(p_cam, 3, "p_cam")
        return self._project(p, False)[0].reshape(*lead, 2)

    def d_uv_d_point(self, p_cam: np.ndarray) -> np.ndarray:
        """Jacobian (..., 2, 3) of ``project`` at camera-frame points (..., 3).

        At a unit bearing it is the pixel's derivative w.r.t. the bearing (it annihilates ``p``:
        projection is scale invariant). NaN where ``project`` is NaN.
        """
        p, lead = _as_points(p_cam, 3, "p_cam")
        return self._project(p, True)[1].reshape(*lead, 2, 3)

    def project_with_jacobian(self, p_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(uv (..., 2), d uv / d p (..., 2, 3)) in one pass."""
        p, lead = _as_points(p_cam, 3, "p_cam")
        uv, J = self._project(p, True)
        return uv.reshape(*lead, 2), J.reshape(*lead, 2, 3)

    def bearing(self, uv: np.ndarray) -> np.ndarray:
        """Unit bearings (..., 3), camera frame, of pixels (..., 2); NaN where no ray maps there."""
        q, lead = _as_points(uv, 2, "uv")
        return self._bearing(q).reshape(*lead, 3)

    # -- uncertainty
    def bearing_tangent_cov(self, b: np.ndarray, cov_px: np.ndarray, basis: np.ndarray) -> np.ndarray:
        """Pixel covariance -> bearing covariance in a tangent basis.

        Parameters
        ----------
        b : (N, 3) unit bearings, camera frame.
        cov_px : (N, 2, 2) pixel covariances (px^2) of their images.
        basis : (N, 3, 2) orthonormal tangent bases at ``b`` (e.g. ``gtsam.Unit3(b).basis()``).

        Returns
        -------
        (N, 2, 2) covariance of the tangent coordinates: with ``J_t = d_uv_d_point(b) @ basis``,
        ``inv(J_t) @ cov_px @ inv(J_t).T``; NaN where ``J_t`` is singular or undefined.
        """
        b = np.asarray(b, dtype=np.float64).reshape(-1, 3)
        cov_px = np.asarray(cov_px, dtype=np.float64).reshape(-1, 2, 2)
        basis = np.asarray(basis, dtype=np.float64).reshape(-1, 3, 2)
        if not (len(b) == len(cov_px) == len(basis)):
            raise ValueError(
                f"bearing_tangent_cov: b, cov_px, basis must have the same N, got "
                f"{len(b)}, {len(cov_px)}, {len(basis)}"
            )
        Jt = self._project(b, True)[1] @ basis
        det = Jt[:, 0, 0] * Jt[:, 1, 1] - Jt[:, 0, 1] * Jt[:, 1, 0]
        inv = np.empty_like(Jt)
        inv[:, 0, 0], inv[:, 1, 1] = Jt[:, 1, 1], Jt[:, 0, 0]
        inv[:, 0, 1], inv[:, 1, 0] = -Jt[:, 0, 1], -Jt[:, 1, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv /= np.where(det == 0, np.nan, det)[:, None, None]
        return inv @ cov_px @ np.swapaxes(inv, 1, 2)

    # -- image membership
    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """(...,) bool: pixel inside [-0.5, W-0.5] x [-0.5, H-0.5] (and finite)."""
        q, lead = _as_points(uv, 2, "uv")
        with np.errstate(invalid="ignore"):
            ok = (q[:, 0] >= -0.5) & (q[:, 0] <= self.width - 0.5)
            ok &= (q[:, 1] >= -0.5) & (q[:, 1] <= self.height - 0.5)
        return ok.reshape(lead)

    def fov_contains(self, p_cam: np.ndarray) -> np.ndarray:
        """(...,) bool: the camera-frame point (..., 3) is imaged inside the picture."""
        return self.in_image(self.project(p_cam))

    # -- config
    def to_dict(self) -> dict[str, Any]:
        """Our config schema's ``camera`` section."""
        return {"model": self.kind, "width": self.width, "height": self.height}

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.to_dict() == other.to_dict()  # type: ignore[union-attr]

    def __hash__(self) -> int:
        return hash(repr(self.to_dict()))


# -------------------------------------------------------------------- equirectangular
@dataclass(frozen=True, eq=False)
class Equirectangular(CameraModel):
    """Full-sphere panorama, W x H (normally W = 2H); frame x forward, y left, z up.

    ``az = atan2(y, x)`` in (-pi, pi], ``el = atan2(z, hypot(x, y))``,
    ``u = W (0.5 - az / 2pi) - 0.5``, ``v = H (0.5 - el / pi) - 0.5``.
    u wraps modulo W across the seam at az = pi (u = -0.5 == W - 0.5).
    """

    kind: ClassVar[str] = "equirectangular"
    R_flu_cam: ClassVar[np.ndarray] = np.eye(3)

    def __post_init__(self) -> None:
        w, h = _check_size(self.width, self.height)
        object.__setattr__(self, "width", w)
        object.__setattr__(self, "height", h)

    def _project(self, p: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        W, H = float(self.width), float(self.height)
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        rho2 = x * x + y * y
        r2 = rho2 + z * z
        az = np.arctan2(y, x)
        az = np.where(az <= -np.pi, np.pi, az)  # (-pi, pi]: the seam belongs to the left edge
        el = np.arctan2(z, np.sqrt(rho2))
        uv = np.stack([W * (0.5 - az / _TWO_PI) - 0.5, H * (0.5 - el / np.pi) - 0.5], axis=1)
        uv[r2 == 0] = np.nan
        if not jac:
            return uv, None
        rho = np.sqrt(rho2)
        with np.errstate(divide="ignore", invalid="ignore"):
            d_az = np.stack([-y / rho2, x / rho2, np.zeros_like(x)], axis=1)
            d_el = np.stack([-z * x / (rho * r2), -z * y / (rho * r2), rho / r2], axis=1)
        J = np.stack([(-W / _TWO_PI) * d_az, (-H / np.pi) * d_el], axis=1)
        J[rho2 == 0] = np.nan
        return uv, J

    def _bearing(self, uv: np.ndarray) -> np.ndarray:
        az = _TWO_PI * (0.5 - (uv[:, 0] + 0.5) / self.width)
        el = np.pi * (0.5 - (uv[:, 1] + 0.5) / self.height)
        c = np.cos(el)
        return np.stack([c * np.cos(az), c * np.sin(az), np.sin(el)], axis=1)

    def wrap_u(self, u: np.ndarray) -> np.ndarray:
        """Column coordinate(s) wrapped into [-0.5, W-0.5): the panorama is periodic in u with period W."""
        return np.mod(np.asarray(u, dtype=np.float64) + 0.5, self.width) - 0.5

    def wrap_du(self, du: np.ndarray) -> np.ndarray:
        """Column difference(s) wrapped into [-W/2, W/2): the shortest way across the seam."""
        W = self.width
        return np.mod(np.asarray(du, dtype=np.float64) + 0.5 * W, W) - 0.5 * W


# ---------------------------------------------------------------------- intrinsics base
@dataclass(frozen=True, eq=False)
class _Intrinsic(CameraModel):
    """Shared by the lens models: K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] and ``dist``."""

    K: np.ndarray = field(default_factory=lambda: np.eye(3))
    dist: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def _check_common(self) -> None:
        w, h = _check_size(self.width, self.height)
        object.__setattr__(self, "width", w)
        object.__setattr__(self, "height", h)
        K = _check_K(self.K)
        K.setflags(write=False)
        object.__setattr__(self, "K", K)
        d = np.asarray(self.dist, dtype=np.float64).ravel()
        if not np.all(np.isfinite(d)):
            raise ValueError(f"dist must be finite, got {d.tolist()}")
        d.setflags(write=False)
        object.__setattr__(self, "dist", d)

    def _to_pixels(self, xd: np.ndarray, yd: np.ndarray) -> np.ndarray:
        K = self.K
        return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)

    def _from_pixels(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        K = self.K
        yd = (uv[:, 1] - K[1, 2]) / K[1, 1]
        xd = (uv[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
        return xd, yd

    def _chain_K(self, J_d: np.ndarray) -> np.ndarray:
        """d uv / d p from d (xd, yd) / d p, (N, 2, 3)."""
        K = self.K
        J = np.empty_like(J_d)
        J[:, 0] = K[0, 0] * J_d[:, 0] + K[0, 1] * J_d[:, 1]
        J[:, 1] = K[1, 1] * J_d[:, 1]
        return J

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        d["K"] = self.K.tolist()
        d["dist"] = self.dist.tolist()
        return d


# ------------------------------------------------------------------------------ pinhole
@dataclass(frozen=True, eq=False)
class Pinhole(_Intrinsic):
    """OpenCV's pinhole model, as ``cv2.projectPoints``; frame z forward, x right, y down.

    ``dist`` = (k1, k2, p1, p2[, k3[, k4, k5, k6]]) (0, 4, 5 or 8 numbers; 8 = rational model).
    With a = x/z, b = y/z, r2 = a^2 + b^2,
    ``rad = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)``,
    ``xd = a rad + 2 p1 a b + p2 (r2 + 2 a^2)``, ``yd = b rad + p1 (r2 + 2 b^2) + 2 p2 a b``,
    ``u = fx xd + skew yd + cx``, ``v = fy yd + cy`` (OpenCV ignores skew; keep it 0 to match).
    ``r_max``: the radius r = |(a, b)| where the radial map r -> r rad(r2) stops increasing
    (inf when it never does); points beyond it project to NaN.
    """

    kind: ClassVar[str] = "pinhole"
    r_max: float = field(init=False, repr=False, default=np.inf)
    _d8: np.ndarray = field(init=False, repr=False, default_factory=lambda: np.zeros(8))

    def __post_init__(self) -> None:
        self._check_common()
        if self.dist.size not in (0, 4, 5, 8):
            raise ValueError(
                f"pinhole dist must have 0, 4, 5 or 8 numbers (k1, k2, p1, p2[, k3[, k4, k5, k6]]), "
                f"got {self.dist.size}"
            )
        d8 = np.zeros(8)
        d8[: self.dist.size] = self.dist
        object.__setattr__(self, "_d8", d8)
        # the radial map g(r) = r rad(r^2) must increase; search r = tan(theta), theta < 90 deg
        theta_hi = np.pi / 2 - 1e-6

        def dg_dtheta_sign(th: np.ndarray) -> np.ndarray:
            r = np.tan(th)
            rad, drad, den = self._radial(r * r)
            return np.where(den > 0, rad + 2 * r * r * drad, -1.0)

        th = _first_fold(dg_dtheta_sign, theta_hi)
        object.__setattr__(self, "r_max", np.inf if th >= theta_hi else float(np.tan(th)))

    def _radial(self, r2: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """rad(r2), d rad / d r2 and the rational denominator."""
        k1, k2, _, _, k3, k4, k5, k6 = self._d8
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        dnum = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        dden = k4 + r2 * (2 * k5 + 3 * k6 * r2)
        with np.errstate(divide="ignore", invalid="ignore"):
            return num / den, (dnum * den - num * dden) / (den * den), den

    def _distort(self, a: np.ndarray, b: np.ndarray, jac: bool):
        """Normalised (a, b) -> distorted (xd, yd) and d(xd, yd)/d(a, b) (N, 2, 2) when ``jac``."""
        p1, p2 = self._d8[2], self._d8[3]
        r2 = a * a + b * b
        rad, drad, _ = self._radial(r2)
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

    def _project(self, p: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            iz = np.where(z > 0, 1.0 / z, np.nan)
        a, b = x * iz, y * iz
        ok = (z > 0) & (a * a + b * b < self.r_max**2)
        xd, yd, D = self._distort(a, b, jac)
        uv = self._to_pixels(xd, yd)
        uv[~ok] = np.nan
        if not jac:
            return uv, None
        dab = np.zeros((p.shape[0], 2, 3))
        dab[:, 0, 0] = dab[:, 1, 1] = iz
        dab[:, 0, 2] = -a * iz
        dab[:, 1, 2] = -b * iz
        J = self._chain_K(D @ dab)
        J[~ok] = np.nan
        return uv, J

    def _newton_undistort(
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
            fx, fy, D = self._distort(aa, bb, True)
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
            f1x, f1y, _ = self._distort(a1, b1, False)
            e1 = np.hypot(f1x - tx, f1y - ty)
            for _ in range(30):  # backtrack where the full step does not reduce the residual
                worse = good & ~(e1 < err)
                if not worse.any():
                    break
                step[worse] *= 0.5
                w = np.flatnonzero(worse)
                a1[w], b1[w] = aa[w] - step[w] * da[w], bb[w] - step[w] * db[w]
                f1x_w, f1y_w, _ = self._distort(a1[w], b1[w], False)
                e1[w] = np.hypot(f1x_w - tx[w], f1y_w - ty[w])
            accept = good & (e1 < err)
            a[act[accept]], b[act[accept]] = a1[accept], b1[accept]
            act = act[accept & (e1 > tol[act])]
        return a, b

    def _bearing(self, uv: np.ndarray) -> np.ndarray:
        xd, yd = self._from_pixels(uv)
        # radial-only inverse as the start, then Newton on the full model
        rho_d = np.hypot(xd, yd)
        r_hi = self.r_max if np.isfinite(self.r_max) else np.tan(np.pi / 2 - 1e-6)

        def g(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            rad, drad, _ = self._radial(r * r)
            return r * rad, rad + 2 * r * r * drad

        # tangential terms can push pixels a little beyond the radial map's maximum: start those at r_hi
        r_top = r_hi * (1 - 1e-9)
        g_top = g(np.array([r_top]))[0][0]
        r = _solve_increasing(g, np.minimum(rho_d, g_top), r_top)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(rho_d > 0, r / rho_d, 1.0)
        a, b = xd * s, yd * s
        a, b = self._newton_undistort(a, b, xd, yd)
        fx, fy, _ = self._distort(a, b, False)
        err = np.hypot(fx - xd, fy - yd)
        ok = (err <= 1e-10 * (1 + rho_d)) & (a * a + b * b < self.r_max**2)
        n = np.sqrt(a * a + b * b + 1)
        out = np.stack([a / n, b / n, 1 / n], axis=1)
        out[~ok] = np.nan
        return out


# ------------------------------------------------------------------------------ fisheye
@dataclass(frozen=True, eq=False)
class Fisheye(_Intrinsic):
    """OpenCV's fisheye (Kannala–Brandt) model, as ``cv2.fisheye.projectPoints``; frame z forward.

    ``dist`` = (k1, k2, k3, k4). With theta the angle off the optical axis (any value up to
    ``theta_max``, beyond 90 degrees too), ``theta_d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)``
    and ``(xd, yd) = theta_d (x, y) / hypot(x, y)``; ``u = fx xd + skew yd + cx``, ``v = fy yd + cy``
    (OpenCV's ``alpha`` is skew / fx). ``theta_max``: where theta_d stops increasing (< pi); points
    beyond it project to NaN.
    """

    kind: ClassVar[str] = "fisheye"
    theta_max: float = field(init=False, repr=False, default=np.pi)

    def __post_init__(self) -> None:
        self._check_common()
        if self.dist.size not in (0, 4):
            raise ValueError(f"fisheye dist must have 4 numbers (k1, k2, k3, k4), got {self.dist.size}")
        if self.dist.size == 0:
            object.__setattr__(self, "dist", np.zeros(4))
            self.dist.setflags(write=False)
        th = _first_fold(lambda t: self._theta_d(t)[1], np.pi)
        object.__setattr__(self, "theta_max", min(th, np.pi))

    def _theta_d(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """theta_d(theta) and its derivative."""
        k1, k2, k3, k4 = self.dist
        t2 = t * t
        poly = 1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
        dpoly = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        return t * poly, dpoly

    def _project(self, p: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        rho2 = x * x + y * y
        rho = np.sqrt(rho2)
        R2 = rho2 + z * z
        R = np.sqrt(R2)
        theta = np.arctan2(rho, z)
        ok = (R > 0) & (theta < self.theta_max)
        td, dtd = self._theta_d(theta)
        st, ct = np.sin(theta), np.cos(theta)
        with np.errstate(divide="ignore", invalid="ignore"):
            h = np.where(theta > 0, td / st, 1.0)  # theta_d / sin(theta), smooth at the axis
            xr, yr = x / R, y / R
        xd, yd = h * xr, h * yr
        uv = self._to_pixels(xd, yd)
        uv[~ok] = np.nan
        if not jac:
            return uv, None
        k1 = self.dist[0]
        small = theta < 1e-3
        with np.errstate(divide="ignore", invalid="ignore"):
            # q = h'(theta) / sin(theta); its limit at the axis is 2 (k1 + 1/6)
            q = np.where(small, 2 * (k1 + 1 / 6), (dtd * st - td * ct) / st**3)
            iR = 1 / R
            c = q * iR**3
        grad_h = np.stack([c * z * x, c * z * y, -c * rho2], axis=1)  # d h / d p
        # d (x/R, y/R) / d p = (E - [x, y]^T p^T / R^2) / R
        unit = np.stack([xr, yr], axis=1)
        Jd = -(unit[:, :, None] * p[:, None, :]) * iR[:, None, None]
        Jd[:, 0, 0] += 1
        Jd[:, 1, 1] += 1
        Jd *= (h * iR)[:, None, None]
        Jd += unit[:, :, None] * grad_h[:, None, :]
        J = self._chain_K(Jd)
        J[~ok] = np.nan
        return uv, J

    def _bearing(self, uv: np.ndarray) -> np.ndarray:
        xd, yd = self._from_pixels(uv)
        td = np.hypot(xd, yd)
        t_hi = self.theta_max
        reachable = td < self._theta_d(np.array([t_hi]))[0][0]
        theta = _solve_increasing(self._theta_d, np.where(reachable, td, 0.0), t_hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(td > 0, np.sin(theta) / td, 0.0)
        out = np.stack([xd * s, yd * s, np.cos(theta)], axis=1)
        out[~(reachable & (theta < t_hi))] = np.nan
        return out


# ----------------------------------------------------------------------------- dispatch
_MODELS: dict[str, type[CameraModel]] = {m.kind: m for m in (Equirectangular, Pinhole, Fisheye)}


def make_camera(d: dict[str, Any]) -> CameraModel:
    """Build a camera from our config's ``camera`` section (keys model, width, height[, K, dist]).

    The only dispatch on camera type. Raises ValueError on an unknown model or bad values.
    """
    model = str(d.get("model", "")).lower()
    if model not in _MODELS:
        raise ValueError(f"camera model must be one of {sorted(_MODELS)}, got {d.get('model')!r}")
    if model == Equirectangular.kind:
        return Equirectangular(width=d["width"], height=d["height"])
    return _MODELS[model](width=d["width"], height=d["height"], K=d["K"], dist=d.get("dist", []))
