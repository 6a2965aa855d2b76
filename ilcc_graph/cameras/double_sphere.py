"""Double sphere camera (Usenko, Demmel, Cremers, 3DV 2018), ``camera.model: double_sphere``.

Kalibr's ``ds`` model. Camera frame OpenCV's (z forward, x right, y down). Config keys:
``model, width, height, K`` (3x3 or 9 numbers row-major; Kalibr's fx, fy, cx, cy), ``xi`` in
(-1, 1] and ``alpha`` in [0, 1] (the paper's ranges without xi = -1, where the optical axis
degenerates; Kalibr's intrinsics are [xi, alpha, fx, fy, cx, cy]).

Projection of p = (x, y, z), as in the paper::

    d1 = |p|,  k = xi d1 + z,  d2 = sqrt(x^2 + y^2 + k^2)
    (mx, my) = (x, y) / (alpha d2 + (1 - alpha) k),  u = fx mx + s my + cx,  v = fy my + cy

Valid region: the point on the second sphere, (x, y, k) / d2, must lie where the last step (a
pinhole ``w = alpha / (1 - alpha)`` behind that sphere's centre) images it once:
``k > -w1 d2`` with ``w1 = w`` for alpha <= 0.5 (the denominator stays positive) and ``1 / w``
beyond (where the image folds). The paper's bound ``z > -w2 d1``,
``w2 = (w1 + xi) / sqrt(2 w1 xi + xi^2 + 1)``, equals it for xi = 0, lies inside it for xi > 0,
and for xi < 0 admits points behind the last pinhole or beyond the fold (e.g. xi = -0.5,
alpha = 0: the denominator is negative for 60 < theta < 63.4 deg), so it is not used.
Unprojection, the paper's closed form: with r^2 = mx^2 + my^2 (valid for alpha <= 0.5 or
r^2 <= 1 / (2 alpha - 1)), ``mz = (1 - alpha^2 r^2) / (alpha sqrt(1 - (2 alpha - 1) r^2) + 1 - alpha)``
and ``b = (mz xi + sqrt(mz^2 + (1 - xi^2) r^2)) / (mz^2 + r^2) (mx, my, mz) - (0, 0, xi)``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np

from ..checks import MISSING, Checker
from ..errors import quote
from .camera_model import R_FLU_OPENCV, LensModel, Normalised
from .common import config_K
from .registry import register


@register("double_sphere")
@dataclass(frozen=True, eq=False)
class DoubleSphere(LensModel):
    """The double sphere model: a unit sphere, a second one shifted by ``xi`` along z, then a
    pinhole shifted by ``alpha / (1 - alpha)``; no distortion polynomial. Frame z forward.

    Points outside the valid region (angle from +z beyond ``theta_max``) project to NaN; pixels
    whose ray would lie there or outside the unprojection's domain have NaN bearings.
    """

    R_flu_cam: ClassVar[np.ndarray] = R_FLU_OPENCV
    config_keys: ClassVar[tuple[str, ...]] = (*LensModel.config_keys, "xi", "alpha", "intrinsics_sigma")
    kalibr_models: ClassVar[tuple[tuple[str, str], ...]] = (("ds", "none"),)
    aliases: ClassVar[tuple[str, ...]] = ("ds",)
    xi: float = 0.0
    alpha: float = 0.0

    def __post_init__(self) -> None:
        self._check_lens()
        for name in ("xi", "alpha"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise ValueError(f"double_sphere {name} must be a number, got {quote(v)}")
            object.__setattr__(self, name, float(v))
        if not -1.0 < self.xi <= 1.0:
            raise ValueError(f"double_sphere xi must be in (-1, 1], got {quote(self.xi)}")
        if not 0.0 <= self.alpha <= 1.0:
            raise ValueError(f"double_sphere alpha must be in [0, 1], got {quote(self.alpha)}")
        self._check_intrinsics_sigma()

    @property
    def w1(self) -> float:
        """The valid region is xi |p| + z > -w1 d2 (module docstring)."""
        a = self.alpha
        return a / (1 - a) if a <= 0.5 else (1 - a) / a

    @property
    def theta_max(self) -> float:
        """Largest angle off the optical axis (rad) of an imaged point, the valid region's edge."""
        xi, w1 = self.xi, self.w1
        c = -xi * (1 - w1 * w1) - w1 * np.sqrt(1 - xi * xi * (1 - w1 * w1))
        return float(np.arccos(np.clip(c, -1.0, 1.0)))

    # -- intrinsics after fx, fy, cx, cy: xi, alpha
    @property
    def param_names(self) -> tuple[str, ...]:
        return ("xi", "alpha")

    def params(self) -> np.ndarray:
        return np.array([self.xi, self.alpha])

    def _with_params(self, K: np.ndarray, q: np.ndarray) -> DoubleSphere:
        return replace(self, K=K, xi=float(q[0]), alpha=float(q[1]))

    def _normalised(self, p: np.ndarray, jac: bool, jac_params: bool) -> Normalised:
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        a, xi = self.alpha, self.xi
        d1 = np.sqrt(x * x + y * y + z * z)
        k = xi * d1 + z
        d2 = np.sqrt(x * x + y * y + k * k)
        den = a * d2 + (1 - a) * k
        ok = (d1 > 0) & (k > -self.w1 * d2)
        with np.errstate(divide="ignore", invalid="ignore"):
            mx, my = x / den, y / den
            m = np.stack([mx, my], axis=1)
        D_q = None
        if jac_params:  # d den / d xi = (alpha k / d2 + 1 - alpha) d1, d den / d alpha = d2 - k
            with np.errstate(divide="ignore", invalid="ignore"):
                dden_q = np.stack([(a * k / d2 + (1 - a)) * d1, d2 - k], axis=1)
                D_q = -m[:, :, None] * (dden_q / den[:, None])[:, None, :]
        if not jac:
            return mx, my, ok, None, D_q
        with np.errstate(divide="ignore", invalid="ignore"):
            dd1 = p / d1[:, None]  # d d1 / d p
            dk = xi * dd1
            dk[:, 2] += 1.0
            dd2 = (k[:, None] * dk) / d2[:, None]
            dd2[:, 0] += x / d2
            dd2[:, 1] += y / d2
            dden = a * dd2 + (1 - a) * dk
            Jm = -m[:, :, None] * dden[:, None, :]
            Jm[:, 0, 0] += 1.0
            Jm[:, 1, 1] += 1.0
            Jm /= den[:, None, None]
        return mx, my, ok, Jm, D_q

    def _bearing(self, uv: np.ndarray) -> np.ndarray:
        a, xi = self.alpha, self.xi
        mx, my = self._from_pixels(uv)
        r2 = mx * mx + my * my
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.sqrt(1 - (2 * a - 1) * r2)  # NaN outside the domain when alpha > 0.5
            if a > 0.75:  # the same value, well conditioned where alpha s + 1 - alpha may reach 0
                mz = (a * s - (1 - a)) / (2 * a - 1)
            else:
                mz = (1 - a * a * r2) / (a * s + 1 - a)
            f = (mz * xi + np.sqrt(mz * mz + (1 - xi * xi) * r2)) / (mz * mz + r2)
        out = np.stack([f * mx, f * my, f * mz - xi], axis=1)
        out /= np.linalg.norm(out, axis=1, keepdims=True)
        k = xi + out[:, 2]
        with np.errstate(invalid="ignore"):
            ok = np.all(np.isfinite(out), axis=1) & (k > -self.w1 * np.sqrt(1 - out[:, 2] ** 2 + k * k))
        out[~ok] = np.nan
        return out

    # -- config, export, simulation
    @classmethod
    def from_config(cls, c: Checker, d: dict, width: int, height: int) -> DoubleSphere:
        K = config_K(c, d.get("K", MISSING), "camera.K")
        xi = c.number(d.get("xi", MISSING), "camera.xi", lo=-1.0, hi=1.0, lo_open=True)
        alpha = c.number(d.get("alpha", MISSING), "camera.alpha", lo=0.0, hi=1.0)
        return cls(width, height, K, xi, alpha)

    @classmethod
    def kalibr_section(cls, intrinsics: list[float], coeffs: list[float]) -> dict[str, Any]:
        K = cls._kalibr_K(2, intrinsics, coeffs, (0,))
        return {"K": K, "xi": float(intrinsics[0]), "alpha": float(intrinsics[1])}

    def kalibr(self) -> tuple[dict[str, Any], list[str]]:
        if self.alpha >= 1.0:
            raise ValueError(f"Kalibr's ds model needs alpha < 1; this camera's alpha = {self.alpha}")
        return {
            "camera_model": "ds",
            "intrinsics": [self.xi, self.alpha, *self._kalibr_fxfycxcy()],
            "distortion_model": "none",
            "distortion_coeffs": [],
        }, []

    @classmethod
    def default(cls, width: int | None = None) -> DoubleSphere:
        """W x 4W/5 (default 1280 x 1024), xi = -0.2, alpha = 0.59, f = 0.3 W: about 200 deg across the
        diagonal, close to published double-sphere fits of the TUM VI data set's fisheye lenses."""
        w = 1280 if width is None else int(width)
        h = (w * 4) // 5
        f = 0.3 * w
        K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
        return cls(w, h, K, -0.2, 0.59)
