"""The registry of camera kinds: ``@register("<kind>")`` and the look-ups ``config/`` and others use."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import replace
from typing import Any, TypeVar

import numpy as np

from ..checks import MISSING, Checker
from ..errors import InputError, quote
from .camera_model import CameraModel
from .common import config_intrinsics_sigma

__all__ = [
    "register",
    "camera_kinds",
    "camera_class",
    "camera_from_config",
    "camera_section_from_ros",
    "make_camera",
]


_REGISTRY: dict[str, type[CameraModel]] = {}
_Model = TypeVar("_Model", bound=type[CameraModel])


def register(kind: str) -> Callable[[_Model], _Model]:
    """Class decorator: make a ``CameraModel`` subclass the model of ``camera.model: <kind>``."""

    def add(cls: _Model) -> _Model:
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
        raise ValueError(f"camera: unknown model {quote(kind)}; expected one of {'|'.join(_REGISTRY)}")
    return cls


def _plain(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower())


def _named(written: Any) -> type[CameraModel] | None:
    """The model a ``camera.model`` value names: its kind or one of its ``aliases`` (case, ``-``,
    ``_`` and spaces do not matter: ``Pinhole``, ``kannala-brandt``, ``Double Sphere``); None if none."""
    if not isinstance(written, str):
        return None
    key = _plain(written)
    for cls in _REGISTRY.values():
        if key in {_plain(n) for n in (cls.kind, *cls.aliases)}:
            return cls
    return None


def camera_from_config(d: Any, source: str = "<config>") -> CameraModel:
    """A camera from our config's ``camera:`` section ``d``.

    ``source`` names the file in messages. Raises ``InputError`` naming file, key, value found
    and what was expected (``<source>: camera.dist = [1, 2]: expected a list of 4 numbers``).
    """
    c = Checker(source)
    d = c.section(d, "camera")
    cls = _named(d.get("model", MISSING))
    if cls is None:
        names = ", ".join(f"{k} ({', '.join(m.aliases)})" if m.aliases else k for k, m in _REGISTRY.items())
        raise c.fail(
            "camera.model", d.get("model", MISSING), f"one of {list(_REGISTRY)}, or a name of one: {names}"
        )
    c.unknown(d, {*cls.config_keys, "intrinsics_sigma"}, "camera")
    w = c.number(d.get("width", MISSING), "camera.width", lo=1, hi=100000, integer=True)
    h = c.number(d.get("height", MISSING), "camera.height", lo=1, hi=100000, integer=True)
    sigma = d.get("intrinsics_sigma")
    try:
        cam = cls.from_config(c, {k: v for k, v in d.items() if k != "intrinsics_sigma"}, int(w), int(h))
    except (ValueError, TypeError) as e:
        raise c.fail("camera", d, f"a valid camera ({e})") from None
    if sigma is None:
        return cam
    s = config_intrinsics_sigma(c, sigma, "camera.intrinsics_sigma", cam.intrinsic_names)
    return replace(cam, intrinsics_sigma=s)


def camera_section_from_ros(distortion_model: str, width: int, height: int, K: Any, D: Any) -> dict[str, Any]:
    """Our config's camera section from a ROS CameraInfo (the model whose ``ros_models`` name its
    ``distortion_model``); ValueError naming the ROS models we read otherwise."""
    name = str(distortion_model).lower()
    for cls in _REGISTRY.values():
        if name in cls.ros_models:
            K = np.asarray(K, dtype=np.float64).reshape(3, 3).tolist()
            return {
                "model": cls.kind,
                "width": int(width),
                "height": int(height),
                "K": K,
                "dist": cls.ros_dist(list(D)),
            }
    known = sorted(m for cls in _REGISTRY.values() for m in cls.ros_models)
    raise ValueError(
        f"CameraInfo distortion_model {quote(distortion_model)} is not supported (we read {known})"
    )


def camera_section_from_kalibr(cam: dict[str, Any]) -> dict[str, Any]:
    """Our config's camera section from one camera of a Kalibr camchain (``camera_model``,
    ``intrinsics``, ``distortion_model``, ``distortion_coeffs``, ``resolution``): the model whose
    ``kalibr_models`` name its pair; ValueError naming the pairs we read otherwise, or what is wrong."""
    pair = (str(cam.get("camera_model")), str(cam.get("distortion_model", "none")))
    for cls in _REGISTRY.values():
        if pair in cls.kalibr_models:
            w, h = (int(v) for v in cam.get("resolution", ()))
            own = cls.kalibr_section(
                list(cam.get("intrinsics") or ()), list(cam.get("distortion_coeffs") or ())
            )
            return {"model": cls.kind, "width": w, "height": h, **own}
    known = sorted(f"{a} + {b}" for cls in _REGISTRY.values() for a, b in cls.kalibr_models)
    raise ValueError(
        f"Kalibr camera_model {quote(pair[0])} with distortion_model {quote(pair[1])} is not one we read "
        f"({', '.join(known)})"
    )


def make_camera(d: dict[str, Any]) -> CameraModel:
    """A camera from a ``to_dict()``-style mapping; as :func:`camera_from_config` but raises ValueError."""
    try:
        return camera_from_config(d, "camera")
    except InputError as e:
        raise ValueError(str(e)) from None
