"""A camera's intrinsics from the file its calibration tool wrote, named in config.yaml.

``camera: {file: ost.yaml}`` (or ``camera: ost.yaml``; the path relative to config.yaml's folder)
reads, recognised by their keys:

- ROS ``camera_calibration``'s ``ost.yaml`` (and any CameraInfo as YAML): ``image_width``,
  ``image_height``, ``camera_matrix.data``, ``distortion_model``, ``distortion_coefficients.data``;
  the model by its ``distortion_model``, as a bag's CameraInfo (``cameras.camera_section_from_ros``);
- Kalibr's camchain (``cam0: {camera_model, intrinsics, distortion_model, distortion_coeffs,
  resolution}``; ``name: cam1`` picks another camera): the model whose ``kalibr_models`` name the
  pair (``cameras.camera_section_from_kalibr``, the inverse of ``CameraModel.kalibr``);
- OpenCV's ``cv::FileStorage`` YAML or XML (``camera_matrix`` or ``cameraMatrix`` or ``K``,
  ``distortion_coefficients`` or ``dist_coeffs`` or ``D``, ``image_width`` and ``image_height``
  or ``image_size``), as OpenCV's calibration samples write it: read as a CameraInfo of
  ``distortion_model`` ``plumb_bob``, or ``equidistant`` when the file says ``fisheye_model: 1``.

Besides ``file``, the section may hold ``name`` (Kalibr), ``distortion_model`` (an OpenCV file's
model in ROS's names, e.g. ``equidistant`` for a ``cv::fisheye`` result without the flag) and
``intrinsics_sigma`` (as in an inline section). The result is our inline camera section
(docs/config.md), checked as one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..cameras import camera_section_from_kalibr, camera_section_from_ros
from ..checks import Checker
from ..errors import InputError, quote
from ..io.files import SMALL_FILE, check_yaml_keys, not_a_file, read_bounded, read_yaml

__all__ = ["FILE_KEYS", "camera_section"]

#: the keys a section naming a file may hold
FILE_KEYS = ("file", "name", "distortion_model", "intrinsics_sigma")

_CV_K = ("camera_matrix", "cameraMatrix", "K", "intrinsic", "intrinsics", "M")
_CV_D = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "distortion", "D")
_N_DIST = (0, 4, 5, 8, 12, 14)  # OpenCV's distortion vectors


def camera_section(c: Checker, d: Any, base: Path | None) -> Any:
    """The camera section ``d`` with a named file read into an inline section (``d`` itself when it
    names none). base: config.yaml's folder (relative paths). InputError naming config.yaml or the
    camera file, the key and what was expected."""
    if isinstance(d, str):
        d = {"file": d}
    if not isinstance(d, dict) or "file" not in d:
        return d
    c.unknown(d, FILE_KEYS, "camera")
    if not isinstance(d["file"], str) or not d["file"].strip():
        raise c.fail("camera.file", d["file"], "the path of a camera calibration file (config.yaml's folder)")
    path = Path(d["file"]).expanduser()
    path = path if path.is_absolute() or base is None else base / path
    problem = not_a_file(path)
    if problem is not None:
        raise c.fail("camera.file", d["file"], f"an existing file ({path} {problem})")
    section = _read(path, d.get("name"), d.get("distortion_model"))
    if d.get("intrinsics_sigma") is not None:
        section["intrinsics_sigma"] = d["intrinsics_sigma"]
    return section


def _read(path: Path, name: Any, distortion_model: Any) -> dict[str, Any]:
    """Our inline section from the file at ``path`` (its kind by its keys)."""
    raw = read_bounded(path, "camera file", SMALL_FILE)
    if raw.lstrip().startswith((b"%YAML:1.", b"<?xml", b"<opencv_storage")) or b"!!opencv-matrix" in raw:
        if raw.lstrip().startswith(b"%YAML"):  # OpenCV 3 writes %YAML:1.0 (not YAML to PyYAML), 4 %YAML 1.2
            body = "\n" + raw.decode("utf-8", errors="replace").lstrip().partition("\n")[2]  # lines kept
            check_yaml_keys(body, str(path))  # a key twice in it: refused as in every YAML file
        return _opencv(path, distortion_model)  # OpenCV 3 writes %YAML:1.0, 4 %YAML 1.2 with its tags
    doc = read_yaml(path, "camera file", SMALL_FILE)
    if not isinstance(doc, dict):
        raise InputError(f"{path}: a camera file is a mapping (ost.yaml, a Kalibr camchain or OpenCV's YAML)")
    if "camera_matrix" in doc and "image_width" in doc:
        return _ros(path, doc)
    cams = {k: v for k, v in doc.items() if isinstance(v, dict) and "camera_model" in v}
    if cams:
        return _kalibr(path, cams, name)
    raise InputError(
        f"{path}: not a camera file we read (keys {sorted(map(str, doc))[:8]}): expected ROS's ost.yaml "
        "(image_width, camera_matrix, distortion_model, ...), a Kalibr camchain (cam0: camera_model, "
        "intrinsics, ...) or OpenCV's FileStorage YAML (%YAML:1.0, camera_matrix, ...)"
    )


def _matrix(path: Path, v: Any, key: str, n: tuple[int, ...]) -> list[float]:
    """The numbers of a ``{rows, cols, data}`` mapping or a plain list; InputError unless n of them."""
    data = v.get("data") if isinstance(v, dict) else v
    try:
        out = [float(x) for x in np.asarray(data, dtype=np.float64).ravel()]
    except (TypeError, ValueError):
        out = []
    if len(out) not in n or not np.all(np.isfinite(out)):
        raise InputError(f"{path}: {key} = {quote(data)}: expected {' or '.join(map(str, n))} finite numbers")
    return out


def _ros(path: Path, doc: dict) -> dict[str, Any]:
    K = _matrix(path, doc["camera_matrix"], "camera_matrix", (9,))
    D = _matrix(path, doc.get("distortion_coefficients", []), "distortion_coefficients", _N_DIST)
    if doc.get("image_height") is None:
        raise InputError(f"{path}: a ROS camera file without image_height")
    try:
        return camera_section_from_ros(
            str(doc.get("distortion_model", "plumb_bob")), doc["image_width"], doc["image_height"], K, D
        )
    except (ValueError, TypeError) as e:
        raise InputError(f"{path}: {e}") from None


def _kalibr(path: Path, cams: dict[str, dict], name: Any) -> dict[str, Any]:
    if name is None and len(cams) > 1:
        raise InputError(
            f"{path}: a camchain of {len(cams)} cameras ({', '.join(cams)}): say which in config.yaml "
            "(camera: {file: ..., name: cam0})"
        )
    key = next(iter(cams)) if name is None else str(name)
    if key not in cams:
        raise InputError(f"{path}: no camera {quote(key)} in this camchain (it has {', '.join(cams)})")
    try:
        return camera_section_from_kalibr(cams[key])
    except (ValueError, TypeError) as e:
        raise InputError(f"{path}: {key}: {e}") from None


def _opencv(path: Path, distortion_model: Any) -> dict[str, Any]:
    import cv2

    try:
        return _opencv_read(cv2, path, distortion_model)
    except (cv2.error, SystemError) as e:  # OpenCV's parser on a damaged file (SystemError wraps it)
        raise InputError(
            f"{path}: OpenCV cannot read this FileStorage file ({' '.join(str(e).split())})"
        ) from None


def _opencv_read(cv2: Any, path: Path, distortion_model: Any) -> dict[str, Any]:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        if not fs.isOpened():
            raise InputError(f"{path}: OpenCV cannot read this FileStorage file")

        def first(keys: tuple[str, ...]) -> Any:
            return next((fs.getNode(k) for k in keys if not fs.getNode(k).empty()), None)

        K_node, D_node = first(_CV_K), first(_CV_D)
        if K_node is None:
            raise InputError(f"{path}: no camera matrix (looked for {', '.join(_CV_K)})")
        K = _matrix(path, K_node.mat(), "camera_matrix", (9,))
        D = [] if D_node is None else _matrix(path, D_node.mat(), "distortion_coefficients", _N_DIST)
        size = fs.getNode("image_size")
        if size.isSeq() and size.size() == 2:  # [w, h]
            w, h = size.at(0).real(), size.at(1).real()
        elif not size.empty() and size.mat() is not None and size.mat().size == 2:  # a Mat of two
            w, h = (float(v) for v in size.mat().ravel())
        else:
            w, h = fs.getNode("image_width").real(), fs.getNode("image_height").real()
        flag = fs.getNode("fisheye_model")  # OpenCV's calibration sample marks its cv::fisheye results
        fisheye = not flag.empty() and flag.real() != 0
    finally:
        fs.release()
    if not (w >= 1 and h >= 1):
        raise InputError(f"{path}: no image size (looked for image_width and image_height, or image_size)")
    model = "equidistant" if fisheye else "plumb_bob"
    model = model if distortion_model is None else str(distortion_model)
    try:
        return camera_section_from_ros(model, int(w), int(h), K, D)
    except ValueError as e:
        raise InputError(f"{path}: {e}") from None
