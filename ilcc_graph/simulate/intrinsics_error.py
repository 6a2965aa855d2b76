"""The simulator's intrinsics error: config.yaml states a camera perturbed from the one that rendered
the images (a published calibration that is a little off), ground_truth.yaml records the truth.

Off by default. The draw has its own random stream (``SeedSequence(seed, spawn_key=(PURPOSE_INTRINSICS,))``),
so switching it on or off changes no other draw: the scans and images stay byte for byte the same.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..cameras import CameraModel

__all__ = ["PURPOSE_INTRINSICS", "TYPICAL_COEFFICIENT_SIGMA", "IntrinsicsError", "stated_camera"]

#: Stream key of the intrinsics draw (placements.py uses 0-2 for the other purposes).
PURPOSE_INTRINSICS = 9

#: One-sigma errors of a typical published calibration's coefficients beyond fx, fy, cx, cy, by name
#: (absolute, in each coefficient's own unit). For the default fisheye (f = 384 px) k1..k4 together
#: move a point 60 deg off axis by about 1 px (one sigma); xi and alpha are the sphere models'.
TYPICAL_COEFFICIENT_SIGMA: dict[str, float] = {
    "k1": 2e-3,
    "k2": 1e-3,
    "k3": 5e-4,
    "k4": 2e-4,
    "k5": 1e-4,
    "k6": 1e-4,
    "p1": 2e-4,
    "p2": 2e-4,
    "xi": 5e-3,
    "alpha": 2e-3,
}


@dataclass(frozen=True)
class IntrinsicsError:
    """How far the stated camera is from the true one; every sigma 0 (off) by default.

    focal_rel_sigma: relative sigma of fx and fy (drawn independently).
    principal_sigma_px: sigma of cx and cy, pixels.
    coefficient_sigma: absolute sigma of the other intrinsics by name (``k1``, ``p1``, ``xi``,
        ``alpha``, ...); a name the camera lacks is ignored, a name missing here is not perturbed.
    state_sigma: config.yaml states these sigmas as ``camera.intrinsics_sigma`` (when on).
    """

    focal_rel_sigma: float = 0.0
    principal_sigma_px: float = 0.0
    coefficient_sigma: Mapping[str, float] = field(default_factory=dict)
    state_sigma: bool = True

    def __post_init__(self) -> None:
        values = {"focal_rel_sigma": self.focal_rel_sigma, "principal_sigma_px": self.principal_sigma_px}
        values.update({f"coefficient_sigma[{k!r}]": v for k, v in self.coefficient_sigma.items()})
        for name, v in values.items():
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"IntrinsicsError: {name} must be finite and >= 0, got {v!r}")
        object.__setattr__(
            self, "coefficient_sigma", {str(k): float(v) for k, v in self.coefficient_sigma.items()}
        )

    @classmethod
    def typical(cls, scale: float = 1.0) -> IntrinsicsError:
        """``scale`` times a typical published calibration's error: 0.5 % on f, 2 px on c,
        :data:`TYPICAL_COEFFICIENT_SIGMA` on the rest."""
        s = float(scale)
        return cls(0.005 * s, 2.0 * s, {k: v * s for k, v in TYPICAL_COEFFICIENT_SIGMA.items()})

    @property
    def is_off(self) -> bool:
        return (
            self.focal_rel_sigma == 0
            and self.principal_sigma_px == 0
            and not any(self.coefficient_sigma.values())
        )

    def sigmas(self, camera: CameraModel) -> np.ndarray:
        """(n,) one-sigma errors of ``camera``'s intrinsics, ``intrinsic_names`` order.

        ValueError when the error is on and the camera has no intrinsics (a panorama)."""
        names = camera.intrinsic_names
        if not names:
            if not self.is_off:
                raise ValueError(f"intrinsics error: camera model {camera.kind!r} has nothing to perturb")
            return np.zeros(0)
        theta = camera.intrinsics()
        s = np.array([self.coefficient_sigma.get(n, 0.0) for n in names])
        s[:2] = self.focal_rel_sigma * np.abs(theta[:2])
        s[2:4] = self.principal_sigma_px
        return s

    def summary(self) -> dict[str, Any]:
        return {
            "focal_rel_sigma": self.focal_rel_sigma,
            "principal_sigma_px": self.principal_sigma_px,
            "coefficient_sigma": dict(self.coefficient_sigma),
            "state_sigma": self.state_sigma,
        }


def stated_camera(camera: CameraModel, error: IntrinsicsError, seed: int) -> CameraModel:
    """The camera config.yaml states: ``camera`` itself when ``error`` is off, else its intrinsics
    plus ``N(0, error.sigmas(camera)^2)`` (with ``intrinsics_sigma`` when ``error.state_sigma``).

    Drawn from the stream ``(seed, PURPOSE_INTRINSICS)``; a draw the model refuses (e.g. a double
    sphere's alpha beyond 1) is redrawn from the same stream.
    """
    sigma = error.sigmas(camera)
    if error.is_off:
        return camera
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(PURPOSE_INTRINSICS,)))
    theta = camera.intrinsics()
    for _ in range(100):
        try:
            stated = camera.with_intrinsics(theta + sigma * rng.standard_normal(theta.size))
            break
        except ValueError:
            continue
    else:
        raise ValueError(f"intrinsics error: 100 draws around {theta.tolist()} were all invalid")
    return replace(stated, intrinsics_sigma=sigma if error.state_sigma else None)
