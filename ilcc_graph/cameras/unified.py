"""Unified omnidirectional camera with radial-tangential distortion (Mei and Rives, ICRA 2007),
``camera.model: unified``.

Kalibr's ``omni`` camera with ``radtan`` distortion (and OpenCV's ``omnidir`` model). Camera frame
OpenCV's (z forward, x right, y down). Config keys: ``model, width, height, K`` (3x3 or 9
numbers row-major; Mei's gamma1, gamma2 = fx, fy), ``xi`` >= 0 (the mirror parameter; 0 is a
pinhole) and ``dist`` = (k1, k2, p1, p2) (missing or [] = none). Kalibr's intrinsics are
[xi, fx, fy, cx, cy] with distortion_coeffs [k1, k2, p1, p2].

Projection of p: onto the unit sphere, then a pinhole ``xi`` behind its centre,
``(a, b) = (x, y) / (z + xi |p|)``, then OpenCV's radial-tangential distortion (:class:`RadTan`)
and K. Valid where ``z > -w |p|`` with ``w = xi`` for xi <= 1 and ``1 / xi`` beyond (where the
map from the sphere folds; Kalibr's bound) and where the distortion's radial map still increases
(``r_max``; as for the pinhole, tangential terms can fold the map a little before it, and a pixel
there has two rays). Unprojection: undistort (Newton), then the closed-form lift onto the sphere,
``b = (xi + sqrt(1 + (1 - xi^2) r^2)) / (1 + r^2) (a, b, 1) - (0, 0, xi)``, r^2 = a^2 + b^2.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from ..checks import MISSING, Checker
from ..errors import quote
from .camera_model import R_FLU_OPENCV, LensModel, Normalised
from .common import config_dist, config_K, finite_vector
from .pinhole import DIST_NAMES, RadTan
from .registry import register


@register("unified")
@dataclass(frozen=True, eq=False)
class Unified(LensModel):
    """Mei's unified model: sphere, pinhole shifted by ``xi``, radial-tangential ``dist``, K.

    ``xi`` >= 0; ``dist`` = (k1, k2, p1, p2). ``r_max``: the normalised radius where the
    distortion's radial map stops increasing (inf when it never does). Points outside the valid
    region project to NaN, pixels with no ray there give NaN bearings.
    """

    R_flu_cam: ClassVar[np.ndarray] = R_FLU_OPENCV
    config_keys: ClassVar[tuple[str, ...]] = (*LensModel.config_keys, "xi", "dist", "intrinsics_sigma")
    kalibr_models: ClassVar[tuple[tuple[str, str], ...]] = (("omni", "radtan"), ("omni", "none"))
    aliases: ClassVar[tuple[str, ...]] = ("omni", "mei", "ucm", "unified_camera_model")
    xi: float = 0.0
    dist: np.ndarray = field(default_factory=lambda: np.zeros(4))
    r_max: float = field(init=False, repr=False, default=np.inf)
    _rt: RadTan = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._check_lens()
        xi = self.xi
        if isinstance(xi, bool) or not isinstance(xi, (int, float, np.integer, np.floating)):
            raise ValueError(f"unified xi must be a number, got {quote(xi)}")
        if not (np.isfinite(xi) and xi >= 0):
            raise ValueError(f"unified xi must be finite and >= 0, got {quote(xi)}")
        object.__setattr__(self, "xi", float(xi))
        dist = finite_vector(self.dist, "dist")
        if dist.size not in (0, 4):
            raise ValueError(f"unified dist must have 4 numbers (k1, k2, p1, p2), got {dist.size}")
        object.__setattr__(self, "dist", finite_vector(np.zeros(4), "dist") if dist.size == 0 else dist)
        object.__setattr__(self, "_rt", RadTan.of(self.dist))
        object.__setattr__(self, "r_max", self._rt.r_max)
        self._check_intrinsics_sigma()

    @property
    def w(self) -> float:
        """The valid region is z > -w |p|."""
        return self.xi if self.xi <= 1 else 1 / self.xi

    # -- intrinsics after fx, fy, cx, cy: xi, then k1, k2, p1, p2
    @property
    def param_names(self) -> tuple[str, ...]:
        return ("xi", *DIST_NAMES[:4])

    def params(self) -> np.ndarray:
        return np.concatenate([[self.xi], self.dist])

    def _with_params(self, K: np.ndarray, q: np.ndarray) -> Unified:
        return replace(self, K=K, xi=float(q[0]), dist=q[1:])

    def _normalised(self, p: np.ndarray, jac: bool, jac_params: bool) -> Normalised:
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        xi = self.xi
        d = np.sqrt(x * x + y * y + z * z)
        den = z + xi * d
        ok = (d > 0) & (z > -self.w * d) & (den > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            a, b = x / den, y / den
        ok &= a * a + b * b < self.r_max**2
        with np.errstate(over="ignore", invalid="ignore"):
            xd, yd, D = self._rt.distort(a, b, jac or jac_params)
        if D is None:  # no Jacobian asked for
            return xd, yd, ok, None, None
        D_q = None
        if jac_params:  # d (a, b) / d xi = -(a, b) |p| / den, then through the distortion
            D_q = np.empty((len(p), 2, 5))
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                dab_xi = -np.stack([a, b], axis=1) * (d / den)[:, None]
                D_q[:, :, 0] = np.einsum("nij,nj->ni", D, dab_xi)
                D_q[:, :, 1:] = self._rt.d_coefficients(a, b)[:, :, :4]
        if not jac:
            return xd, yd, ok, None, D_q
        with np.errstate(divide="ignore", invalid="ignore"):
            dden = xi * p / d[:, None]  # d den / d p
            dden[:, 2] += 1.0
            dab = -np.stack([a, b], axis=1)[:, :, None] * dden[:, None, :]
            dab[:, 0, 0] += 1.0
            dab[:, 1, 1] += 1.0
            dab /= den[:, None, None]
        return xd, yd, ok, D @ dab, D_q

    def _bearing(self, uv: np.ndarray) -> np.ndarray:
        xi = self.xi
        a, b, ok = self._rt.undistort(*self._from_pixels(uv))
        r2 = a * a + b * b
        with np.errstate(invalid="ignore"):
            f = (xi + np.sqrt(1 + (1 - xi * xi) * r2)) / (1 + r2)  # NaN beyond xi > 1's reach
        out = np.stack([f * a, f * b, f - xi], axis=1)
        out /= np.linalg.norm(out, axis=1, keepdims=True)
        with np.errstate(invalid="ignore"):
            ok &= np.all(np.isfinite(out), axis=1) & (out[:, 2] > -self.w)
        out[~ok] = np.nan
        return out

    # -- config, export, simulation
    @classmethod
    def from_config(cls, c: Checker, d: dict, width: int, height: int) -> Unified:
        K = config_K(c, d.get("K", MISSING), "camera.K")
        xi = c.number(d.get("xi", MISSING), "camera.xi", lo=0.0)
        return cls(width, height, K, xi, config_dist(c, d, (4,), []))

    @classmethod
    def kalibr_section(cls, intrinsics: list[float], coeffs: list[float]) -> dict[str, Any]:
        K = cls._kalibr_K(1, intrinsics, coeffs, (0, 4))
        return {"K": K, "xi": float(intrinsics[0]), "dist": [float(v) for v in coeffs] or [0.0] * 4}

    def kalibr(self) -> tuple[dict[str, Any], list[str]]:
        return {
            "camera_model": "omni",
            "intrinsics": [self.xi, *self._kalibr_fxfycxcy()],
            "distortion_model": "radtan",
            "distortion_coeffs": self.dist.tolist(),
        }, []

    @classmethod
    def default(cls, width: int | None = None) -> Unified:
        """W x 4W/5 (default 1280 x 1024), xi = 0.9, f = 0.57 W (0.3 W px/rad at the centre, as the
        fisheye's; about 185 deg across the diagonal), mild radial-tangential distortion."""
        w = 1280 if width is None else int(width)
        h = (w * 4) // 5
        f = 0.57 * w
        K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
        return cls(w, h, K, 0.9, np.array([-0.05, 0.01, 4e-4, -3e-4]))
