"""Equirectangular (full-sphere panorama) camera, ``camera.model: equirectangular``.

Camera frame x forward (the image's centre column), y left, z up. ``az = atan2(y, x)`` in
(-pi, pi], ``el = atan2(z, hypot(x, y))``; ``u = W (0.5 - az / 2pi) - 0.5``,
``v = H (0.5 - el / pi) - 0.5`` (``shared/interface.md``). u wraps modulo W across the seam at
az = pi (u = -0.5 == W - 0.5). Config keys: ``model, width, height`` with width = 2 * height.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..checks import Checker
from .camera_model import CameraModel
from .common import check_size
from .registry import register

_TWO_PI = 2.0 * np.pi


@register("equirectangular")
@dataclass(frozen=True, eq=False)
class Equirectangular(CameraModel):
    """Full-sphere panorama, W x H (normally W = 2H); frame x forward, y left, z up.

    ``az = atan2(y, x)`` in (-pi, pi], ``el = atan2(z, hypot(x, y))``,
    ``u = W (0.5 - az / 2pi) - 0.5``, ``v = H (0.5 - el / pi) - 0.5``.
    u wraps modulo W across the seam at az = pi (u = -0.5 == W - 0.5).
    """

    R_flu_cam: ClassVar[np.ndarray] = np.eye(3)
    periodic_u: ClassVar[bool] = True
    aliases: ClassVar[tuple[str, ...]] = ("panorama", "panoramic", "spherical", "equirect", "360")

    def __post_init__(self) -> None:
        w, h = check_size(self.width, self.height)
        object.__setattr__(self, "width", w)
        object.__setattr__(self, "height", h)
        self._check_intrinsics_sigma()

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

    # -- config, export, simulation
    @classmethod
    def from_config(cls, c: Checker, d: dict, width: int, height: int) -> Equirectangular:
        if width != 2 * height:
            expected = f"2 * height = {2 * height} for an equirectangular image"
            raise c.fail("camera.width", d.get("width"), expected)
        return cls(width, height)

    def kalibr(self) -> tuple[dict[str, Any], list[str]]:
        raise ValueError(
            "Kalibr has no equirectangular (panoramic) camera model (its models: pinhole, omni, ds, "
            "eucm), so a Kalibr camchain of this camera would not load"
        )

    @classmethod
    def default(cls, width: int | None = None) -> Equirectangular:
        """W x W/2, default 8000 x 4000."""
        w = 8000 if width is None else int(width)
        return cls(w, w // 2)
