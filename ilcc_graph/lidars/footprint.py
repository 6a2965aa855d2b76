"""A beam's footprint as points evenly covering the unit disc, for ray casters that average what a
spot lights (the main simulator's ``simulate.edges`` and the LiDAR stage's test scenes)."""

from __future__ import annotations

import numpy as np

__all__ = ["FOOTPRINT", "disc_cover"]


def disc_cover(half: int) -> np.ndarray:
    """(2 half, 2) points evenly covering the unit disc: Vogel's spiral (point k at radius
    ``sqrt((k + 1/2) / half)``, turned by the golden angle each step) and its point reflection, so
    the cover's centre is the disc's and no two points line up in rows along any direction."""
    k = np.arange(half)
    r, t = np.sqrt((k + 0.5) / half), k * np.pi * (3.0 - np.sqrt(5.0))
    p = np.column_stack([r * np.cos(t), r * np.sin(t)])
    return np.vstack([p, -p])


#: a beam's footprint, unit disc (128 points): a real spot's light is spread evenly, so the share of
#: it on one side of a straight edge follows the disc's segment area (within 0.03 here, in steps of
#: 1/128, for an edge at any angle) as the edge crosses it. A cover of few points (7 were used before)
#: or of rows (a grid) blends an edge in a few large steps that no sensor shows, and a fit then
#: places the print's edges by the steps
FOOTPRINT = disc_cover(64)
