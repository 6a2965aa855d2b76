"""The camera interface (the registry of kinds: ``registry.py``; shared numerics: ``common.py``).

A camera model is one file in this package: a frozen dataclass subclassing :class:`CameraModel`
(or :class:`LensModel` when it has a K matrix), decorated with ``@register("<kind>")`` and
imported in ``cameras/__init__.py``. Everything that differs between models lives in that file:

- ``_project`` (pixels, and beside them the analytic Jacobian) and ``_bearing`` (its inverse),
  NaN wherever the model cannot image a point or no ray maps to a pixel; a :class:`LensModel`
  gives ``_normalised`` (its coordinates before K, with their Jacobians w.r.t. the point and its
  own parameters) instead of ``_project``;
- its refinable intrinsics: ``intrinsic_names``, ``intrinsics()``, ``with_intrinsics(theta)``
  and the Jacobian w.r.t. them beside the projection (``project_with_intrinsics_jacobian``);
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

from ..checks import Checker
from .common import as_points, axes_text, check_intrinsics_sigma, check_K, check_size

__all__ = ["R_FLU_OPENCV", "CameraModel", "LensModel", "Normalised"]

#: What a lens model's ``_normalised`` gives: xd, yd, ok (N,), then d (xd, yd) / d p (N, 2, 3) and
#: d (xd, yd) / d params (N, 2, m), each None unless asked for.
Normalised = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]

#: OpenCV's camera axes (x right, y down, z forward) in a forward-left-up frame: the columns are
#: the camera's x, y, z axes. ``R_FLU_OPENCV.T`` is the nominal ``R_cam_lidar`` of a lens camera
#: looking along the LiDAR's x axis.
R_FLU_OPENCV = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
R_FLU_OPENCV.setflags(write=False)


# --------------------------------------------------------------------------- the base
@dataclass(frozen=True, eq=False)
class CameraModel(ABC):
    """A calibrated camera: pixel (u, v) <-> unit bearing in the camera frame.

    width, height: image size in pixels.
    intrinsics_sigma: optional stated one-sigma uncertainty of the intrinsics, (n,) in
        ``intrinsic_names`` order (pixels for fx, fy, cx, cy; the coefficients' own units else;
        0 = known exactly), or a mapping by name; keyword only. Config key ``intrinsics_sigma``.
    """

    kind: ClassVar[str] = ""
    #: Rotation from this camera's frame to a forward-left-up frame (x forward, y left, z up).
    R_flu_cam: ClassVar[np.ndarray]
    #: Image columns wrap around (u and u + W are the same column): a 360-degree panorama.
    periodic_u: ClassVar[bool] = False
    #: Keys of this kind's ``camera:`` config section.
    config_keys: ClassVar[tuple[str, ...]] = ("model", "width", "height")
    #: other names users and tools give this model (``camera.model``; case, ``-``, ``_``, spaces ignored)
    aliases: ClassVar[tuple[str, ...]] = ()
    #: ROS CameraInfo ``distortion_model`` names this model reads (bags); () for none
    ros_models: ClassVar[tuple[str, ...]] = ()
    #: Kalibr (``camera_model``, ``distortion_model``) pairs this model reads (camchains); () for none
    kalibr_models: ClassVar[tuple[tuple[str, str], ...]] = ()
    width: int
    height: int
    intrinsics_sigma: np.ndarray | None = field(default=None, kw_only=True)

    # -- projection and its Jacobian
    @abstractmethod
    def _project(self, p: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """p (N, 3) -> uv (N, 2) and, when ``jac``, d uv / d p (N, 2, 3); NaN where not imaged."""

    @abstractmethod
    def _bearing(self, uv: np.ndarray) -> np.ndarray:
        """uv (N, 2) -> unit bearings (N, 3); NaN where no ray maps to the pixel."""

    def _project_jac(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``_project`` with its Jacobian: uv (N, 2) and d uv / d p (N, 2, 3)."""
        uv, J = self._project(p, True)
        if J is None:
            raise TypeError(f"{type(self).__name__}._project gave no Jacobian with jac=True")
        return uv, J

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
        return self._project_jac(p)[1].reshape(*lead, 2, 3)

    def project_with_jacobian(self, p_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(uv (..., 2), d uv / d p (..., 2, 3)) in one pass."""
        p, lead = as_points(p_cam, 3, "p_cam")
        uv, J = self._project_jac(p)
        return uv.reshape(*lead, 2), J.reshape(*lead, 2, 3)

    def bearing(self, uv: np.ndarray) -> np.ndarray:
        """Unit bearings (..., 3), camera frame, of pixels (..., 2); NaN where no ray maps there."""
        q, lead = as_points(uv, 2, "uv")
        return self._bearing(q).reshape(*lead, 3)

    # -- intrinsics: what a calibration may refine (skew and the image size stay fixed)
    @property
    def intrinsic_names(self) -> tuple[str, ...]:
        """Names of the refinable intrinsics, the order of ``intrinsics()``; () when there are none."""
        return ()

    def intrinsics(self) -> np.ndarray:
        """(n,) float64 copy of the refinable intrinsics, in ``intrinsic_names`` order."""
        return np.zeros(0)

    def with_intrinsics(self, theta: np.ndarray) -> CameraModel:
        """This camera (same kind, size, skew and ``intrinsics_sigma``) with intrinsics ``theta`` (n,).

        Validated as the constructor validates (``ValueError``, e.g. fx <= 0 or a double sphere's
        alpha outside [0, 1]). ``with_intrinsics(intrinsics()) == self``.
        """
        t = np.array(theta, dtype=np.float64)
        names = self.intrinsic_names
        if t.shape != (len(names),) or not np.all(np.isfinite(t)):
            raise ValueError(
                f"{self.kind} intrinsics must be {len(names)} finite numbers ({', '.join(names)}), got "
                f"{t.tolist() if t.size <= 16 else t.shape}"
            )
        return self._with_intrinsics(t)

    def _with_intrinsics(self, theta: np.ndarray) -> CameraModel:
        return self

    def project_with_intrinsics_jacobian(
        self, p_cam: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(uv (..., 2), d uv / d p (..., 2, 3), d uv / d intrinsics (..., 2, n)) in one pass.

        Analytic; ``d uv / d p`` equals ``d_uv_d_point``; columns of the last follow
        ``intrinsic_names``. NaN where ``project`` is NaN.
        """
        p, lead = as_points(p_cam, 3, "p_cam")
        uv, J, J_t = self._project_intrinsics(p)
        return uv.reshape(*lead, 2), J.reshape(*lead, 2, 3), J_t.reshape(*lead, 2, J_t.shape[-1])

    def _project_intrinsics(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        uv, J = self._project_jac(p)
        return uv, J, np.zeros((len(p), 2, 0))

    def _check_intrinsics_sigma(self) -> None:
        """Coerce ``intrinsics_sigma`` (call at the end of ``__post_init__``, once the names are known)."""
        s = check_intrinsics_sigma(self.intrinsics_sigma, self.intrinsic_names, self.kind)
        object.__setattr__(self, "intrinsics_sigma", s)

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
        Jt = self._project_jac(b)[1] @ basis
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
        """Our config schema's ``camera`` section (``intrinsics_sigma`` last, by name, when stated)."""
        d = self._section()
        if self.intrinsics_sigma is not None:
            d["intrinsics_sigma"] = dict(
                zip(self.intrinsic_names, self.intrinsics_sigma.tolist(), strict=True)
            )
        return d

    def _section(self) -> dict[str, Any]:
        """The model's own keys of its ``camera`` section."""
        return {"model": self.kind, "width": self.width, "height": self.height}

    def ros_camera_info(self) -> tuple[str, list[float]] | None:
        """(ROS CameraInfo ``distortion_model``, ``D``) of this camera; None when ROS has no such model."""
        return None

    @classmethod
    def ros_dist(cls, D: list[float]) -> list[float]:
        """Our ``dist`` from a CameraInfo's ``D`` of one of ``ros_models``."""
        return list(D)

    @classmethod
    def kalibr_section(cls, intrinsics: list[float], coeffs: list[float]) -> dict[str, Any]:
        """Our config section's own keys (all but model, width, height) from a Kalibr camchain's
        ``intrinsics`` and ``distortion_coeffs`` of one of ``kalibr_models`` (the inverse of
        ``kalibr``); ValueError when their counts do not fit."""
        raise ValueError(f"Kalibr has no model of a {cls.kind} camera")

    @abstractmethod
    def kalibr(self) -> tuple[dict[str, Any], list[str]]:
        """Kalibr camchain fields (``camera_model``, ``intrinsics``, ``distortion_model``,
        ``distortion_coeffs``, in this order, named as Kalibr names them) and notes for the reader.

        Raises ValueError, saying why, when Kalibr has no model that holds this camera exactly (a
        file Kalibr cannot load, or one that would change the camera, is worse than none)."""

    @classmethod
    @abstractmethod
    def default(cls, width: int | None = None) -> CameraModel:
        """A camera of this kind with plausible intrinsics (the simulator's default), ``width`` px wide."""

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.to_dict() == other.to_dict()

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
        """d uv / d x from d (xd, yd) / d x, (N, 2, m)."""
        K = self.K
        J = np.empty_like(J_d)
        J[:, 0] = K[0, 0] * J_d[:, 0] + K[0, 1] * J_d[:, 1]
        J[:, 1] = K[1, 1] * J_d[:, 1]
        return J

    @staticmethod
    def _kalibr_K(lead: int, intrinsics: list[float], coeffs: list[float], n_coeffs: tuple[int, ...]) -> list:
        """K from Kalibr's [..., fu, fv, pu, pv] after ``lead`` parameters of the model's own;
        ValueError unless there are ``lead`` + 4 intrinsics and n_coeffs coefficients."""
        if len(intrinsics) != lead + 4 or len(coeffs) not in n_coeffs:
            raise ValueError(
                f"expected {lead + 4} intrinsics and {' or '.join(map(str, n_coeffs))} distortion_coeffs, "
                f"got {len(intrinsics)} and {len(coeffs)}"
            )
        fu, fv, pu, pv = (float(v) for v in intrinsics[lead:])
        return [[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]]

    def _kalibr_fxfycxcy(self) -> list[float]:
        """Kalibr's [fu, fv, pu, pv]; ValueError for a K with skew (Kalibr has none)."""
        if self.K[0, 1] != 0.0:
            raise ValueError(f"Kalibr's camera models have no skew; this camera's K[0][1] = {self.K[0, 1]}")
        return [float(self.K[0, 0]), float(self.K[1, 1]), float(self.K[0, 2]), float(self.K[1, 2])]

    def _section(self) -> dict[str, Any]:
        """model, width, height, K, then the model's own ``config_keys`` from its fields of those names."""
        d = super()._section()
        d["K"] = self.K.tolist()
        for key in self.config_keys:
            if key not in d and key != "intrinsics_sigma":
                v = getattr(self, key)
                d[key] = v.tolist() if isinstance(v, np.ndarray) else v
        return d

    # -- what each lens file gives: its coordinates before K and its own parameters
    @abstractmethod
    def _normalised(self, p: np.ndarray, jac: bool, jac_params: bool) -> Normalised:
        """p (N, 3) -> (xd, yd, ok, d (xd, yd) / d p (N, 2, 3) when ``jac``, d (xd, yd) / d params
        (N, 2, m) when ``jac_params``); ``ok`` (N,) False where the model cannot image the point."""

    @property
    @abstractmethod
    def param_names(self) -> tuple[str, ...]:
        """Names of the model's own intrinsics after fx, fy, cx, cy (distortion, xi, alpha, ...)."""

    @abstractmethod
    def params(self) -> np.ndarray:
        """(m,) the model's own intrinsics, ``param_names`` order."""

    @abstractmethod
    def _with_params(self, K: np.ndarray, q: np.ndarray) -> LensModel:
        """This camera with another K and own parameters (through the constructor)."""

    def _project(self, p: np.ndarray, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        xd, yd, ok, D_p, _ = self._normalised(p, jac, False)
        with np.errstate(over="ignore", invalid="ignore"):
            uv = self._to_pixels(xd, yd)
        uv[~ok] = np.nan
        if not jac:
            return uv, None
        if D_p is None:
            raise TypeError(f"{type(self).__name__}._normalised gave no Jacobian with jac=True")
        J = self._chain_K(D_p)
        J[~ok] = np.nan
        return uv, J

    def _project_intrinsics(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        xd, yd, ok, D_p, D_q = self._normalised(p, True, True)
        if D_p is None or D_q is None:
            raise TypeError(f"{type(self).__name__}._normalised gave no Jacobians with jac, jac_params")
        with np.errstate(over="ignore", invalid="ignore"):
            uv = self._to_pixels(xd, yd)
        J = self._chain_K(D_p)
        J_t = np.zeros((len(p), 2, 4 + D_q.shape[2]))
        J_t[:, 0, 0], J_t[:, 1, 1] = xd, yd  # u = fx xd + s yd + cx, v = fy yd + cy
        J_t[:, 0, 2] = J_t[:, 1, 3] = 1.0
        J_t[:, :, 4:] = self._chain_K(D_q)
        for a in (uv, J, J_t):
            a[~ok] = np.nan
        return uv, J, J_t

    @property
    def intrinsic_names(self) -> tuple[str, ...]:
        return ("fx", "fy", "cx", "cy", *self.param_names)

    def intrinsics(self) -> np.ndarray:
        K = self.K
        return np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], self.params()])

    def _with_intrinsics(self, theta: np.ndarray) -> LensModel:
        K = np.array(self.K)
        K[0, 0], K[1, 1], K[0, 2], K[1, 2] = theta[:4]
        return self._with_params(K, theta[4:])


@dataclass(frozen=True)
class RefinedIntrinsics:
    """A camera's intrinsics a calibration refined. names: the model's ``intrinsic_names``; stated:
    (n,) the config's values; values: (n,) the refined ones; sigmas: (n,) their 1-sigma (each in its
    own unit: px, or none). ``Calibration.sensors["camera_intrinsics"]`` holds it as ``entry()``."""

    names: tuple[str, ...]
    stated: np.ndarray
    values: np.ndarray
    sigmas: np.ndarray

    @classmethod
    def from_entry(cls, d: Any) -> RefinedIntrinsics:
        """From ``{names, stated, values, sigmas}``; KeyError, TypeError or ValueError when malformed."""
        arrays = [np.asarray(d[k], dtype=np.float64).reshape(-1) for k in ("stated", "values", "sigmas")]
        names = tuple(str(n) for n in d["names"])
        if any(len(a) != len(names) for a in arrays):
            raise ValueError(f"refined intrinsics: {len(names)} names but values of other lengths")
        return cls(names, *arrays)

    def entry(self) -> dict[str, Any]:
        """``{names, stated, values, sigmas}``, as ``Calibration.sensors["camera_intrinsics"]``."""
        return {"names": list(self.names), "stated": self.stated, "values": self.values,
                "sigmas": self.sigmas}  # fmt: skip
