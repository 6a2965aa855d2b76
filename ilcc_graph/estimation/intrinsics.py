"""Camera intrinsics in the graph: refined as variables, or their stated uncertainty propagated.

With ``refine``, each lens camera's intrinsics (``camera.intrinsic_names``: fx, fy, cx, cy and its
own parameters) become a variable ``I(c)`` shared by every view of that camera, with the config's
values as a prior: their stated sigmas (``camera.intrinsics_sigma``) or, when none are stated, the
weak defaults of ``default_sigmas`` (a sigma of 0 holds a term fixed). Views then enter through
``factors.FramePixelFactor`` (pixel residuals) instead of bearings. A panorama has no intrinsics.

Without ``refine`` but with stated sigmas (and ``propagate``), the intrinsics stay at the config's
values and their uncertainty is added to the extrinsic's covariance to first order ("consider"
covariance): ``C = C_fixed + J Sigma_theta J^T`` with ``J`` the estimate's sensitivity to them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ilcc_graph.cameras import CameraModel

__all__ = ["IntrinsicsOptions", "default_sigmas", "prior_sigmas", "projection", "refinable"]

#: the smallest prior sigma used for a term stated as exact (GTSAM needs a finite information)
EXACT_SIGMA = 1e-9


@dataclass(frozen=True)
class IntrinsicsOptions:
    """refine: the cameras' intrinsics become variables (``--refine-intrinsics``); cameras: with
    ``refine``, which of them (the graph's camera indices, ``Assembly.cameras``; None: all);
    propagate: a stated intrinsics uncertainty enters the extrinsic's covariance when they are not
    refined; subsets: what the camera's choice tries when the boards do not determine all intrinsics
    (``camera_choice``: e.g. ``camera_choice.LIDAR_SUBSETS``; none by default)."""

    refine: bool = False
    propagate: bool = True
    subsets: tuple[tuple[str, ...], ...] = ()
    cameras: tuple[int, ...] | None = None


def refinable(camera: CameraModel) -> bool:
    """True when the camera has intrinsics to refine (a lens model)."""
    return len(camera.intrinsic_names) > 0


def default_sigmas(camera: CameraModel) -> np.ndarray:
    """Weak default prior sigmas when none are stated: 2 % of the focal lengths, 3 % of the image
    size for the principal point, 0.1 for radial-like coefficients and xi/alpha, 0.01 for tangential."""
    theta = camera.intrinsics()
    out = []
    for name, v in zip(camera.intrinsic_names, theta, strict=True):
        if name in ("fx", "fy"):
            out.append(0.02 * abs(v))
        elif name == "cx":
            out.append(0.03 * camera.width)
        elif name == "cy":
            out.append(0.03 * camera.height)
        elif name in ("p1", "p2"):
            out.append(0.01)
        else:
            out.append(0.1)
    return np.asarray(out, dtype=np.float64)


def prior_sigmas(camera: CameraModel) -> np.ndarray:
    """The prior sigmas of the camera's intrinsics: stated, else ``default_sigmas``; exact terms get
    ``EXACT_SIGMA`` times their size."""
    s = camera.intrinsics_sigma
    s = default_sigmas(camera) if s is None else np.asarray(s, dtype=np.float64)
    scale = np.maximum(np.abs(camera.intrinsics()), 1.0)
    return np.where(s > 0, s, EXACT_SIGMA * scale)


def projection(camera: CameraModel) -> Callable[[np.ndarray, np.ndarray], tuple]:
    """The projection ``factors.FramePixelFactor`` takes: ``(p_cam, theta) -> (uv, J_p, J_theta)``.

    The camera of the last ``theta`` is kept: every frame's factor is evaluated at the same intrinsics
    within a linearisation, and building a camera is costly (a fisheye's or pinhole's validity limit
    is searched on construction: 14,468 builds took 5.3 s of a 37 s calibrate of 80 frames)."""
    last: dict[bytes, CameraModel] = {}

    def project(p_cam: np.ndarray, theta: np.ndarray) -> tuple:
        key = np.asarray(theta, dtype=np.float64).tobytes()
        cam = last.get(key)
        if cam is None:
            last.clear()
            cam = last[key] = camera.with_intrinsics(theta)
        return cam.project_with_intrinsics_jacobian(p_cam)

    return project
