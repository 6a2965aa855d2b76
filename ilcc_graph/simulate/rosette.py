"""Scanline-free scan patterns: the rosette of two counter-rotating Risley prisms (Livox Mid-40/70).

First-order (thin wedge) model: each prism deflects the beam by a fixed angle in the direction it
is turned to, and the deflections add. With both wedges deflecting by half of the field's
half-angle ``a`` and turning at ``f1`` and ``f2`` revolutions per second (opposite signs), the
beam's offset from the optical axis (LiDAR x) at time t is the 2-D vector

    v(t) = a/2 (exp(i 2 pi f1 t) + exp(i 2 pi f2 t)),

a rose curve: ``|v| = a |cos(pi (f1 - f2) t)|`` passes through the centre ``f1 - f2`` times a second
while the figure turns at ``(f1 + f2) / 2`` revolutions per second. An irrational-looking ratio
``f1 / f2`` makes the pattern non-repetitive: the petals of successive frames fall between those
before, and the covered part of the field grows with the integration time. Returns are densest at
the centre and at the rim of the field (the beam is slowest in ``|v|`` there), as on the real units.

The direction of offset ``v`` is at angle ``|v|`` from x, towards ``(0, cos arg v, sin arg v)``
(y left, z up). One return per ``1 / point_rate_hz`` s, in time order, as the Livox driver sends them.

Prism rates: about -4664 and 7294 rpm (Liu et al. 2021, "Low-cost retina-like robotic lidars based
on incommensurable scanning", IEEE/ASME T-Mech, for the Mid-40). Only their ratio shapes the
pattern; we use them for both units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..lidars import LidarModel

__all__ = ["Rosette", "ROSETTES", "rosette_for", "rosette_directions"]


@dataclass(frozen=True)
class Rosette:
    """A two-prism rosette.

    half_fov_deg: half-angle of the circular field about LiDAR x (deg).
    point_rate_hz: returns per second. prism_hz: the two prisms' signed rotation rates (rev/s).
    """

    half_fov_deg: float
    point_rate_hz: float
    prism_hz: tuple[float, float] = (-4664.0 / 60.0, 7294.0 / 60.0)

    def __post_init__(self) -> None:
        if not (0 < self.half_fov_deg < 90 and self.point_rate_hz > 0):
            raise ValueError(f"Rosette: half_fov_deg in (0, 90) and point_rate_hz > 0, got {self!r}")
        if self.prism_hz[0] * self.prism_hz[1] >= 0:
            raise ValueError(f"Rosette: the prisms must turn opposite ways, got {self.prism_hz!r}")


#: data sheets: Mid-40 38.4 deg and Mid-70 70.4 deg circular field, both 100,000 points/s
ROSETTES: dict[str, Rosette] = {
    "livox-mid40": Rosette(19.2, 100_000.0),
    "livox-mid70": Rosette(35.2, 100_000.0),
}


def rosette_for(model: LidarModel) -> Rosette:
    """The rosette that renders a scanline-free ``model`` (by name); ValueError when none does."""
    r = ROSETTES.get(model.name)
    if r is None:
        raise ValueError(
            f"no scan pattern to simulate for the scanline-free lidar {model.name!r}; "
            f"simulated ones: {sorted(ROSETTES)}"
        )
    return r


def rosette_directions(rosette: Rosette, t0: float, duration_s: float) -> np.ndarray:
    """Unit beam directions (N, 3), LiDAR frame, of the returns fired in ``[t0, t0 + duration_s)``.

    N = round(duration_s * point_rate_hz), in firing order.
    """
    n = max(1, int(round(duration_s * rosette.point_rate_hz)))
    t = t0 + np.arange(n) / rosette.point_rate_hz
    a = np.deg2rad(rosette.half_fov_deg)
    f1, f2 = rosette.prism_hz
    v = 0.5 * a * (np.exp(2j * np.pi * f1 * t) + np.exp(2j * np.pi * f2 * t))
    theta, phi = np.abs(v), np.angle(v)
    s = np.sin(theta)
    return np.column_stack([np.cos(theta), s * np.cos(phi), s * np.sin(phi)])
