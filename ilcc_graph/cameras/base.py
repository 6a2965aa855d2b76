"""The camera interface, its shared helpers and the registry of camera kinds.

A camera model is one file in this package: a frozen dataclass subclassing :class:`CameraModel`
(or :class:`LensModel` when it has a K matrix), decorated with ``@register("<kind>")`` and
imported in ``cameras/__init__.py``. Everything that differs between models lives in that file:

- ``_project`` (pixels, and beside them the analytic Jacobian) and ``_bearing`` (its inverse),
  NaN wherever the model cannot image a point or no ray maps to a pixel;
- ``R_flu_cam``: the model's camera axes in a forward-left-up frame (x forward, y left, z up);
  lens models use OpenCV's axes, :data:`R_FLU_OPENCV`;
- ``periodic_u``, ``wrap_u``, ``wrap_du`` when its image columns wrap around (a panorama);
- ``config_keys`` and ``from_config`` (its ``camera:`` section, checked key by key) and
  ``to_dict`` (the same schema back);
- ``kalibr()``: its Kalibr camchain fields;
- ``default(width)``: plausible intrinsics, the simulator's camera of that kind.

Pixels follow OpenCV (pixel centres at integers, the image spans [-0.5, W-0.5] x [-0.5, H-0.5]).
Every function is vectorised over leading axes: points ``(..., 3)``, pixels ``(..., 2)``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from ..checks import MISSING, Checker
from ..errors import InputError

__all__ = [
    "R_FLU_OPENCV",
    "CameraModel",
    "LensModel",
    "register",
    "camera_kinds",
    "camera_class",
    "camera_from_config",
    "make_camera",
]

#: OpenCV's camera axes (x right, y down, z forward) in a forward-left-up frame: the columns are
#: the camera's x, y, z axes. ``R_FLU_OPENCV.T`` is the nominal ``R_cam_lidar`` of a lens camera
#: looking along the LiDAR's x axis.
R_FLU_OPENCV = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
R_FLU_OPENCV.setflags(write=False)

_FLU_AXIS_NAMES = (("backward", "forward"), ("right", "left"), ("down", "up"))


# ----------------------------------------------------------------------------- helpers
def as_points(p: np.ndarray, dim: int, what: str) -> tuple[np.ndarray, tuple[int, ...]]:
    """Coerce to float64 (N, dim); return it with the leading shape to restore."""
    a = np.asarray(p, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != dim:
        raise ValueError(f"{what} must have shape (..., {dim}), got {a.shape}")
    return a.reshape(-1, dim), a.shape[:-1]


def check_K(K: Any) -> np.ndarray:
    """K as a read-only float64 [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0; ValueError else."""
    K = np.array(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"K must be a finite 3x3 matrix, got {K.tolist() if K.size <= 16 else K.shape}")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise ValueError(
            f"K must be [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K.tolist()}"
        )
    K.setflags(write=False)
    return K


def check_size(width: Any, height: Any) -> tuple[int, int]:
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise ValueError(f"camera {name} must be a positive integer (pixels), got {v!r}")
    return int(width), int(height)


def finite_vector(v: Any, what: str) -> np.ndarray:
    """A read-only float64 1-D copy of ``v``; ValueError when not finite."""
    d = np.array(v, dtype=np.float64).ravel()
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{what} must be finite, got {d.tolist()}")
    d.setflags(write=False)
    return d


def solve_increasing(f, target: np.ndarray, hi: float, iters: int = 100) -> np.ndarray:
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


def first_fold(dfdx, hi: float, n: int = 20001) -> float:
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


def config_K(c: Checker, v: Any, key: str) -> list[list[float]]:
    """A config value for K: 3x3 nested or 9 numbers row-major, [[fx, s, cx], [0, fy, cy], [0, 0, 1]]."""
    if isinstance(v, (list, tuple)) and len(v) == 9 and not any(isinstance(x, (list, tuple)) for x in v):
        v = [list(v[0:3]), list(v[3:6]), list(v[6:9])]
    if not (
        isinstance(v, (list, tuple))
        and len(v) == 3
        and all(isinstance(r, (list, tuple)) and len(r) == 3 for r in v)
    ):
        raise c.fail(key, v, "a 3x3 matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
    K = [c.numbers(r, f"{key}[{i}]", 3) for i, r in enumerate(v)]
    if not (K[0][0] > 0 and K[1][1] > 0 and K[1][0] == 0 and K[2] == [0.0, 0.0, 1.0]):
        raise c.fail(key, v, "[[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    return K


def axes_text(R_flu_cam: np.ndarray) -> str:
    """The camera axes in words, e.g. ``x right, y down, z forward`` for OpenCV's."""
    words = []
    for j, name in enumerate("xyz"):
        col = R_flu_cam[:, j]
        i = int(np.argmax(np.abs(col)))
        words.append(f"{name} {_FLU_AXIS_NAMES[i][int(col[i] > 0)] if abs(col[i]) == 1.0 else 'tilted'}")
    return ", ".join(words)


# --------------------------------------------------------------------------- the base
@dataclass(frozen=True, eq=False)
class CameraModel(ABC):
    """A calibrated camera: pixel (u, v) <-> unit bearing in the camera frame.

    width, height: image size in pixels.
    """

    kind: ClassVar[str] = ""
    #: Rotation from this camera's frame to a forward-left-up frame (x forward, y left, z up).
    R_flu_cam: ClassVar[np.ndarray]
    #: Image columns wrap around (u and u + W are the same column): a 360-degree panorama.
    periodic_u: ClassVar[bool] = False
    #: Keys of this kind's ``camera:`` config section.
    config_keys: ClassVar[tuple[str, ...]] = ("model", "width", "height")
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
        p, lead = as_points(p_cam, 3, "p_cam")
        return self._project(p, False)[0].reshape(*lead, 2)

    def d_uv_d_point(self, p_cam: np.ndarray) -> np.ndarray:
        """Jacobian (..., 2, 3) of ``project`` at camera-frame points (..., 3).

        At a unit bearing it is the pixel's derivative w.r.t. the bearing (it annihilates ``p``:
        projection is scale invariant). NaN where ``project`` is NaN.
        """
        p, lead = as_points(p_cam, 3, "p_cam")
        return self._project(p, True)[1].reshape(*lead, 2, 3)

    def project_with_jacobian(self, p_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(uv (..., 2), d uv / d p (..., 2, 3)) in one pass."""
        p, lead = as_points(p_cam, 3, "p_cam")
        uv, J = self._project(p, True)
        return uv.reshape(*lead, 2), J.reshape(*lead, 2, 3)

    def bearing(self, uv: np.ndarray) -> np.ndarray:
        """Unit bearings (..., 3), camera frame, of pixels (..., 2); NaN where no ray maps there."""
        q, lead = as_points(uv, 2, "uv")
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

    # -- image membership and the seam
    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """(...,) bool: pixel inside [-0.5, W-0.5] x [-0.5, H-0.5] (and finite)."""
        q, lead = as_points(uv, 2, "uv")
        with np.errstate(invalid="ignore"):
            ok = (q[:, 0] >= -0.5) & (q[:, 0] <= self.width - 0.5)
            ok &= (q[:, 1] >= -0.5) & (q[:, 1] <= self.height - 0.5)
        return ok.reshape(lead)

    def fov_contains(self, p_cam: np.ndarray) -> np.ndarray:
        """(...,) bool: the camera-frame point (..., 3) is imaged inside the picture."""
        return self.in_image(self.project(p_cam))

    def wrap_u(self, u: np.ndarray) -> np.ndarray:
        """Column coordinate(s) brought into the image's period (unchanged unless ``periodic_u``)."""
        return np.asarray(u, dtype=np.float64)

    def wrap_du(self, du: np.ndarray) -> np.ndarray:
        """Column difference(s) taken the shortest way (unchanged unless ``periodic_u``)."""
        return np.asarray(du, dtype=np.float64)

    # -- axes
    @property
    def optical(self) -> bool:
        """The camera frame has OpenCV's (REP 103 optical) axes: x right, y down, z forward."""
        return bool(np.array_equal(self.R_flu_cam, R_FLU_OPENCV))

    @property
    def R_opencv_cam(self) -> np.ndarray:
        """(3, 3) rotation from this camera's frame to OpenCV axes at the same place."""
        return R_FLU_OPENCV.T @ self.R_flu_cam

    @property
    def axes(self) -> str:
        """The camera frame's axes in words (``x right, y down, z forward``)."""
        return axes_text(self.R_flu_cam)

    # -- config, export, simulation
    @classmethod
    @abstractmethod
    def from_config(cls, c: Checker, d: dict, width: int, height: int) -> CameraModel:
        """This kind from its ``camera:`` section ``d`` (keys already checked against
        ``config_keys``; width and height already parsed); ``InputError`` via ``c`` on bad values."""

    def to_dict(self) -> dict[str, Any]:
        """Our config schema's ``camera`` section."""
        return {"model": self.kind, "width": self.width, "height": self.height}

    @abstractmethod
    def kalibr(self) -> tuple[dict[str, Any], list[str]]:
        """Kalibr camchain fields (``camera_model``, ``intrinsics``, ``distortion_model``,
        ``distortion_coeffs``, in this order, as far as Kalibr has them) and notes for the reader."""

    @classmethod
    @abstractmethod
    def default(cls, width: int | None = None) -> CameraModel:
        """A camera of this kind with plausible intrinsics (the simulator's default), ``width`` px wide."""

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.to_dict() == other.to_dict()  # type: ignore[union-attr]

    def __hash__(self) -> int:
        return hash(repr(self.to_dict()))


# ---------------------------------------------------------------------- lenses with K
@dataclass(frozen=True, eq=False)
class LensModel(CameraModel):
    """A camera with K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] mapping its (distorted)
    normalised coordinates (xd, yd) to pixels: ``u = fx xd + skew yd + cx``, ``v = fy yd + cy``."""

    config_keys: ClassVar[tuple[str, ...]] = ("model", "width", "height", "K")
    K: np.ndarray = field(default_factory=lambda: np.eye(3))

    def _check_lens(self) -> None:
        w, h = check_size(self.width, self.height)
        object.__setattr__(self, "width", w)
        object.__setattr__(self, "height", h)
        object.__setattr__(self, "K", check_K(self.K))

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

    def _kalibr_fxfycxcy(self) -> list[float]:
        return [float(self.K[0, 0]), float(self.K[1, 1]), float(self.K[0, 2]), float(self.K[1, 2])]

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        d["K"] = self.K.tolist()
        return d


# ----------------------------------------------------------------------------- registry
_REGISTRY: dict[str, type[CameraModel]] = {}


def register(kind: str):
    """Class decorator: make a ``CameraModel`` subclass the model of ``camera.model: <kind>``."""

    def add(cls: type[CameraModel]) -> type[CameraModel]:
        if kind in _REGISTRY:
            raise ValueError(f"camera kind {kind!r} is already {_REGISTRY[kind].__name__}'s")
        R = np.array(getattr(cls, "R_flu_cam", None), dtype=np.float64)
        if R.shape != (3, 3) or np.abs(R.T @ R - np.eye(3)).max() > 1e-12 or np.linalg.det(R) < 0:
            raise ValueError(f"{cls.__name__}.R_flu_cam must be a (3, 3) rotation")
        R.setflags(write=False)
        cls.R_flu_cam = R
        cls.kind = kind
        _REGISTRY[kind] = cls
        return cls

    return add


def camera_kinds() -> tuple[str, ...]:
    """The registered camera kinds (``camera.model`` values), in registration order."""
    return tuple(_REGISTRY)


def camera_class(kind: str) -> type[CameraModel]:
    """The model class of a kind; ValueError naming the known kinds otherwise."""
    cls = _REGISTRY.get(str(kind).lower())
    if cls is None:
        raise ValueError(f"camera: unknown model {kind!r}; expected one of {'|'.join(_REGISTRY)}")
    return cls


def camera_from_config(d: Any, source: str = "<config>") -> CameraModel:
    """A camera from our config's ``camera:`` section ``d``.

    ``source`` names the file in messages. Raises ``InputError`` naming file, key, value found
    and what was expected (``<source>: camera.dist = [1, 2]: expected a list of 4 numbers``).
    """
    c = Checker(source)
    d = c.section(d, "camera")
    cls = _REGISTRY[c.choice(d.get("model", MISSING), "camera.model", camera_kinds())]
    c.unknown(d, cls.config_keys, "camera")
    w = c.number(d.get("width", MISSING), "camera.width", lo=1, hi=100000, integer=True)
    h = c.number(d.get("height", MISSING), "camera.height", lo=1, hi=100000, integer=True)
    try:
        return cls.from_config(c, d, int(w), int(h))
    except (ValueError, TypeError) as e:
        raise c.fail("camera", d, f"a valid camera ({e})") from None


def make_camera(d: dict[str, Any]) -> CameraModel:
    """A camera from a ``to_dict()``-style mapping; as :func:`camera_from_config` but raises ValueError."""
    try:
        return camera_from_config(d, "camera")
    except InputError as e:
        raise ValueError(str(e)) from None
