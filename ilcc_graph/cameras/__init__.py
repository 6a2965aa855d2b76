"""Camera models, one file each, registered by kind (``camera.model`` in config.yaml).

The model imports below fill the registry (``registry.py``): a model file joins it by being
imported here. See ``camera_model.py`` for what a model file holds; nothing outside this package branches
on the kind.
"""

from .camera_model import R_FLU_OPENCV, CameraModel, LensModel, RefinedIntrinsics
from .double_sphere import DoubleSphere as DoubleSphere
from .equirectangular import Equirectangular as Equirectangular
from .fisheye import Fisheye as Fisheye
from .pinhole import Pinhole as Pinhole
from .registry import (
    camera_class,
    camera_from_config,
    camera_kinds,
    camera_section_from_kalibr,
    camera_section_from_ros,
    make_camera,
    register,
)
from .unified import Unified as Unified

__all__ = [
    "R_FLU_OPENCV",
    "CameraModel",
    "LensModel",
    "RefinedIntrinsics",
    "camera_class",
    "camera_from_config",
    "camera_section_from_kalibr",
    "camera_section_from_ros",
    "camera_kinds",
    "make_camera",
    "register",
]
