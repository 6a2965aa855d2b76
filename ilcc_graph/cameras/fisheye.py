"""OpenCV's fisheye (Kannala-Brandt) camera, ``camera.model: fisheye``.

Camera frame OpenCV's (z forward, x right, y down). Config keys: ``model, width, height, K``
(3x3 or 9 numbers row-major) and ``dist`` = (k1, k2, k3, k4) (missing or [] = none).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from ..checks import MISSING, Checker
from .camera_model import R_FLU_OPENCV, LensModel, Normalised
from .common import config_dist, config_K, finite_vector, first_fold, solve_increasing
from .registry import register


def _theta_d(dist: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """theta_d(theta) of the coefficients ``dist`` (k1..k4) and its derivative."""
    k1, k2, k3, k4 = dist
    t2 = t * t
    poly = 1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
    dpoly = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
    return t * poly, dpoly


@functools.lru_cache(maxsize=1024)
def _theta_max(dist: tuple[float, ...]) -> float:
    """``Fisheye.theta_max`` of the coefficients: where theta_d stops increasing (< pi). Kept per
    coefficients: a solve that refines the intrinsics builds the same camera for every view."""
    k = np.array(dist)
    return min(first_fold(lambda t: _theta_d(k, t)[1], np.pi), np.pi)


@register("fisheye")
@dataclass(frozen=True, eq=False)
class Fisheye(LensModel):
    """OpenCV's fisheye (Kannala–Brandt) model, as ``cv2.fisheye.projectPoints``; frame z forward.

    ``dist`` = (k1, k2, k3, k4). With theta the angle off the optical axis (any value up to
    ``theta_max``, beyond 90 degrees too), ``theta_d = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)``
    and ``(xd, yd) = theta_d (x, y) / hypot(x, y)``; ``u = fx xd + skew yd + cx``, ``v = fy yd + cy``
    (OpenCV's ``alpha`` is skew / fx). ``theta_max``: where theta_d stops increasing (< pi); points
    beyond it project to NaN.
    """

    R_flu_cam: ClassVar[np.ndarray] = R_FLU_OPENCV
    ros_models: ClassVar[tuple[str, ...]] = ("equidistant", "fisheye")
    aliases: ClassVar[tuple[str, ...]] = ("kannala_brandt", "kb4", "equidistant", "opencv_fisheye")
    kalibr_models: ClassVar[tuple[tuple[str, str], ...]] = (("pinhole", "equidistant"),)
    config_keys: ClassVar[tuple[str, ...]] = (*LensModel.config_keys, "dist", "intrinsics_sigma")
    dist: np.ndarray = field(default_factory=lambda: np.zeros(0))
    theta_max: float = field(init=False, repr=False, default=np.pi)

    def __post_init__(self) -> None:
        self._check_lens()
        object.__setattr__(self, "dist", finite_vector(self.dist, "dist"))
        if self.dist.size not in (0, 4):
            raise ValueError(f"fisheye dist must have 4 numbers (k1, k2, k3, k4), got {self.dist.size}")
        if self.dist.size == 0:
            object.__setattr__(self, "dist", finite_vector(np.zeros(4), "dist"))
        object.__setattr__(self, "theta_max", _theta_max(tuple(float(k) for k in self.dist)))
        self._check_intrinsics_sigma()

    def _theta_d(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """theta_d(theta) and its derivative."""
        return _theta_d(self.dist, t)

    # -- intrinsics after fx, fy, cx, cy: k1..k4
    @property
    def param_names(self) -> tuple[str, ...]:
        return ("k1", "k2", "k3", "k4")

    def params(self) -> np.ndarray:
        return np.array(self.dist)

    def _with_params(self, K: np.ndarray, q: np.ndarray) -> Fisheye:
        return replace(self, K=K, dist=q)

    def _normalised(self, p: np.ndarray, jac: bool, jac_params: bool) -> Normalised:
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
        D_q = None
        if jac_params:
            # d (xd, yd) / d k_i = theta^(2i+1) / sin(theta) (x, y) / R = theta^(2i) (theta / rho) (x, y)
            with np.errstate(divide="ignore", invalid="ignore"):
                t_rho = np.where(rho > 0, theta / rho, 1.0 / R)
            t2 = theta * theta
            pw = np.stack([t2, t2**2, t2**3, t2**4], axis=1) * t_rho[:, None]
            D_q = np.stack([pw * x[:, None], pw * y[:, None]], axis=1)
        if not jac:
            return xd, yd, ok, None, D_q
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
        return xd, yd, ok, Jd, D_q

    def _bearing(self, uv: np.ndarray) -> np.ndarray:
        xd, yd = self._from_pixels(uv)
        td = np.hypot(xd, yd)
        t_hi = self.theta_max
        reachable = td < self._theta_d(np.array([t_hi]))[0][0]
        theta = solve_increasing(self._theta_d, np.where(reachable, td, 0.0), t_hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(td > 0, np.sin(theta) / td, 0.0)
        out = np.stack([xd * s, yd * s, np.cos(theta)], axis=1)
        out[~(reachable & (theta < t_hi))] = np.nan
        return out

    # -- config, export, simulation
    @classmethod
    def from_config(cls, c: Checker, d: dict, width: int, height: int) -> Fisheye:
        K = config_K(c, d.get("K", MISSING), "camera.K")
        return cls(width, height, K, config_dist(c, d, (4,), [0.0] * 4))

    def ros_camera_info(self) -> tuple[str, list[float]] | None:
        return "equidistant", [float(v) for v in self.dist]

    @classmethod
    def ros_dist(cls, D: list[float]) -> list[float]:
        return ([float(v) for v in D] + [0.0] * 4)[:4]

    @classmethod
    def kalibr_section(cls, intrinsics: list[float], coeffs: list[float]) -> dict[str, Any]:
        return {"K": cls._kalibr_K(0, intrinsics, coeffs, (4,)), "dist": [float(v) for v in coeffs]}

    def kalibr(self) -> tuple[dict[str, Any], list[str]]:
        return {
            "camera_model": "pinhole",
            "intrinsics": self._kalibr_fxfycxcy(),
            "distortion_model": "equidistant",
            "distortion_coeffs": self.dist.tolist(),
        }, []

    @classmethod
    def default(cls, width: int | None = None) -> Fisheye:
        """W x 4W/5 (default 1280 x 1024), equidistant f = 0.3 W (about 190 deg across the
        diagonal) with small k1..k4."""
        w = 1280 if width is None else int(width)
        h = (w * 4) // 5
        f = 0.3 * w
        K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
        return cls(w, h, K, np.array([0.02, -0.005, 0.001, 0.0]))
