"""A camera's intrinsics from the file its calibration tool wrote, named in config.yaml.

``camera: {file: ost.yaml}`` (or ``camera: ost.yaml``; the path relative to config.yaml's folder)
reads, recognised by their keys:

- ROS ``camera_calibration``'s ``ost.yaml`` (and any CameraInfo as YAML): ``image_width``,
  ``image_height``, ``camera_matrix.data``, ``distortion_model``, ``distortion_coefficients.data``;
  the model by its ``distortion_model``, as a bag's CameraInfo (``cameras.camera_section_from_ros``);
- Kalibr's camchain (``cam0: {camera_model, intrinsics, distortion_model, distortion_coeffs,
  resolution}``; ``name: cam1`` picks another camera): pinhole + radtan / equidistant / none, omni +
  radtan / none (``unified``), ds (``double_sphere``); the inverse of ``CameraModel.kalibr``;
- OpenCV's ``cv::FileStorage`` YAML or XML (``camera_matrix`` or ``cameraMatrix`` or ``K``,
  ``distortion_coefficients`` or ``dist_coeffs`` or ``D``, ``image_width`` and ``image_height``
  or ``image_size``), as OpenCV's calibration samples write it: ``pinhole``, or ``fisheye`` when the
  file says ``fisheye_model: 1`` or the section says ``model: fisheye``.

Besides ``file``, the section may hold ``name`` (Kalibr), ``model`` (an OpenCV file's model) and
``intrinsics_sigma`` (as in an inline section). The result is our inline camera section
(docs/config.md), checked as one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..cameras import camera_section_from_ros
from ..checks import MISSING, Checker
from ..errors import InputError
from ..io import read_yaml

__all__ = ["FILE_KEYS", "camera_section"]

#: the keys a section naming a file may hold
FILE_KEYS = ("file", "name", "model", "intrinsics_sigma")

#: Kalibr's (camera_model, distortion_model) -> our model, and how its intrinsics list reads:
#: the leading parameters' names before [fu, fv, pu, pv]
_KALIBR = {
    ("pinhole", "radtan"): ("pinhole", ()),
    ("pinhole", "none"): ("pinhole", ()),
    ("pinhole", "equidistant"): ("fisheye", ()),
    ("omni", "radtan"): ("unified", ("xi",)),
    ("omni", "none"): ("unified", ("xi",)),
    ("ds", "none"): ("double_sphere", ("xi", "alpha")),
}
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
    if not path.is_file():
        raise c.fail("camera.file", d["file"], f"an existing file ({path} not found)")
    section = _read(path, d.get("name"), d.get("model"))
    if d.get("intrinsics_sigma") is not None:
        section["intrinsics_sigma"] = d["intrinsics_sigma"]
    return section


def _read(path: Path, name: Any, model: Any) -> dict[str, Any]:
    """Our inline section from the file at ``path`` (its kind by its keys)."""
    raw = path.read_bytes()
    if raw.lstrip().startswith((b"%YAML:1.", b"<?xml", b"<opencv_storage")) or b"!!opencv-matrix" in raw:
        return _opencv(path, model)  # OpenCV 3 writes %YAML:1.0, OpenCV 4 %YAML 1.2 with its own tags
    doc = read_yaml(path, "camera file")
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
        raise InputError(f"{path}: {key} = {data!r}: expected {' or '.join(map(str, n))} finite numbers")
    return out


def _ros(path: Path, doc: dict) -> dict[str, Any]:
    K = _matrix(path, doc["camera_matrix"], "camera_matrix", (9,))
    D = _matrix(path, doc.get("distortion_coefficients", []), "distortion_coefficients", _N_DIST)
    try:
        return camera_section_from_ros(
            str(doc.get("distortion_model", "plumb_bob")), doc["image_width"], doc.get("image_height"), K, D
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
        raise InputError(f"{path}: no camera {key!r} in this camchain (it has {', '.join(cams)})")
    cam = cams[key]
    kind = (str(cam.get("camera_model")), str(cam.get("distortion_model", "none")))
    if kind not in _KALIBR:
        raise InputError(
            f"{path}: {key}: Kalibr camera_model {kind[0]!r} with distortion_model {kind[1]!r} is not one we "
            f"read ({', '.join(f'{a} + {b}' for a, b in _KALIBR)})"
        )
    model, lead = _KALIBR[kind]
    intr = _matrix(path, cam.get("intrinsics"), f"{key}.intrinsics", (len(lead) + 4,))
    res = _matrix(path, cam.get("resolution"), f"{key}.resolution", (2,))
    fu, fv, pu, pv = intr[len(lead) :]
    out: dict[str, Any] = {"model": model, "width": int(res[0]), "height": int(res[1]),
                           "K": [[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]]}  # fmt: skip
    out.update(zip(lead, intr[: len(lead)], strict=True))
    if model != "double_sphere":
        n = (0,) if kind[1] == "none" else (4,)
        coeffs = _matrix(path, cam.get("distortion_coeffs", []), f"{key}.distortion_coeffs", n)
        if model == "pinhole" and coeffs:
            coeffs = coeffs + [0.0]  # radtan's k1, k2, p1, p2 and OpenCV's k3 = 0 (as a CameraInfo's five)
        out["dist"] = coeffs or ([0.0] * 4 if model == "unified" else [])
    return out


def _opencv(path: Path, model: Any) -> dict[str, Any]:
    import cv2

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
        flag = fs.getNode("fisheye_model")
        is_fisheye = model == "fisheye" if isinstance(model, str) else (not flag.empty() and flag.real() != 0)
    finally:
        fs.release()
    if not (w >= 1 and h >= 1):
        raise InputError(f"{path}: no image size (looked for image_width and image_height, or image_size)")
    if model not in (None, MISSING, "pinhole", "fisheye"):
        raise InputError(f"{path}: an OpenCV file holds a pinhole or fisheye camera, not {model!r}")
    return {"model": "fisheye" if is_fisheye else "pinhole", "width": int(w), "height": int(h),
            "K": np.asarray(K).reshape(3, 3).tolist(), "dist": D[:4] if is_fisheye else D}  # fmt: skip
