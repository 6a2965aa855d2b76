"""Write a simulated data set (the simulator's only file I/O, through ``ilcc_graph.io`` writers).

Layout (interface.md): ``config.yaml`` (our schema), ``pcd/<stem>.pcd`` (binary, x y z intensity
ring; organised HEIGHT x WIDTH for ``sensor_format="ouster"``; header and fields as another tool
writes them with ``pcd_style``, e.g. MATLAB's) or ``pcd/<stem>.csv`` (ILCC's CSV with the hardware
``laser_id`` for ``"velodyne-csv"``), ``img/<stem>.png`` (or ``.jpg``), ``ground_truth.yaml``. The
data set is assembled in a staging folder beside ``out_dir`` that becomes ``out_dir`` at the end
(``assemble``: ``io.output_folders.staged``), so ``out_dir`` either holds a complete data set or is
left as it was; it must be new, empty or an earlier simulated set (docs/faults.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import PCD_STYLES, write_image, write_pcd, write_yaml
from ..io.output_folders import DATA_SET, staged
from ..io.scans import write_csv
from ..types import Scan
from .frames import ground_truth, simulate_frames
from .intrinsics_error import IntrinsicsError, stated_camera
from .spec import SimulationSpec, standard_spec

__all__ = [
    "IMAGE_FORMATS",
    "assemble",
    "config_dict",
    "simulate_dataset",
    "standard_set_spec",
    "write_scan",
    "write_standard_set",
]

#: how the images are stored: PNG (lossless) or JPEG (OpenCV's quality 95: a sixth of the bytes)
IMAGE_FORMATS = ("png", "jpg")


def config_dict(spec: SimulationSpec) -> dict:
    """config.yaml content (our schema) for the spec's board, LiDAR and camera (the stated camera:
    the truth perturbed by ``spec.intrinsics_error``)."""
    return {
        "board": spec.board.to_dict(),
        "lidar": spec.lidar_model.to_dict(),
        "camera": stated_camera(spec.camera, spec.intrinsics_error, spec.units_seed).to_dict(),
    }


def simulate_dataset(
    out_dir: Path | str,
    spec: SimulationSpec,
    progress: Callable[[int, int], None] | None = None,
    pcd_style: str = "plain",
    image_format: str = "png",
    command: str = "",
) -> Path:
    """Simulate ``spec`` and write the data set to ``out_dir`` (new, empty, or an earlier simulated
    set, replaced whole; ``OutputError`` naming the folder otherwise), the images as ``image_format``
    (``IMAGE_FORMATS``).

    progress: called as ``progress(done, total)`` after each frame. pcd_style: how the PCD files
    look (``io.write_pcd``'s ``style``: ``plain``, ``pcl``, ``open3d``, ``matlab``). command: the
    command line that asked (recorded in the folder's marker). Returns ``out_dir`` (a link's target).
    """
    if image_format not in IMAGE_FORMATS:
        raise ValueError(f"image_format must be one of {IMAGE_FORMATS}, not {image_format!r}")
    if pcd_style not in PCD_STYLES:
        raise ValueError(f"pcd_style must be one of {PCD_STYLES}, got {pcd_style!r}")
    if pcd_style != "plain" and spec.sensor_format == "velodyne-csv":
        raise ValueError(f"pcd_style {pcd_style!r} needs PCD output; sensor_format 'velodyne-csv' writes CSV")
    fill = partial(_write, spec=spec, progress=progress, pcd_style=pcd_style, image_format=image_format)
    return assemble(Path(out_dir), fill, command)


def assemble(out: Path, fill: Callable[[Path], None], command: str = "") -> Path:
    """Run ``fill(tmp)`` on a staging folder that becomes ``out`` (``io.output_folders.staged``, a
    data set: new, empty or an earlier simulated set; ``OutputError`` naming the folder otherwise), so
    ``out`` holds the whole data set or is left as it was. Returns the folder written (a link's target)."""
    with staged(out, DATA_SET, "simulate", command) as tmp:
        fill(tmp)
    return Path(out).resolve() if Path(out).is_symlink() else Path(out)


def _write(
    tmp: Path, spec: SimulationSpec, progress: Callable[[int, int], None] | None, pcd_style: str,
    image_format: str = "png",
) -> None:  # fmt: skip
    write_yaml(tmp / "config.yaml", config_dict(spec))
    names, poses = [], []
    total = int(spec.n_frames)
    for k, frame in enumerate(simulate_frames(spec)):
        write_scan(tmp / "pcd", frame.name, frame.scan, spec.sensor_format, pcd_style)
        write_image(tmp / "img" / f"{frame.name}.{image_format}", frame.image)
        names.append(frame.name)
        poses.append(frame.T_lidar_board)
        if progress is not None:
            progress(k + 1, total)
    gt = ground_truth(spec, [_Pose(n, T) for n, T in zip(names, poses, strict=True)])
    write_yaml(tmp / "ground_truth.yaml", gt)


def write_scan(folder: Path, stem: str, scan: Scan, sensor_format: str, pcd_style: str = "plain") -> Path:
    """Write a simulated scan as ``folder/<stem>.pcd`` (binary; organised for ``"ouster"``; header and
    fields in ``pcd_style``) or ``.csv`` (``"velodyne-csv"``), as ``spec.sensor_format`` says a driver
    would; returns the path."""
    if sensor_format == "velodyne-csv":
        return write_csv(folder / f"{stem}.csv", scan)
    path = folder / f"{stem}.pcd"
    if sensor_format == "ouster":
        rows = len(scan) // int(scan.columns)  # type: ignore[arg-type]
        return write_pcd(path, scan, data="binary", organised=(rows, int(scan.columns)), style=pcd_style)  # type: ignore[arg-type]
    return write_pcd(path, scan, data="binary", style=pcd_style)


class _Pose:
    """Name and pose of a written frame (what :func:`ground_truth` reads from a frame)."""

    def __init__(self, name: str, T: np.ndarray) -> None:
        self.name, self.T_lidar_board = name, T


def standard_set_spec(
    intrinsics_error: float = 0.0, range_offset_mm: float = 0.0, pcd_style: str = "plain", **spec: object
) -> SimulationSpec:
    """The standard set's spec (``standard_spec(**spec)``, stated intrinsics off by ``intrinsics_error``
    x a typical error, every range ``range_offset_mm`` long on top of the default systematics);
    InputError naming the option that cannot be (``pcd_style``: how its PCD files are to look)."""
    try:
        s = standard_spec(intrinsics_error=IntrinsicsError.typical(intrinsics_error), **spec)  # type: ignore[arg-type]
        if range_offset_mm:
            s = s.with_(systematics=replace(s.systematics, range_offset_m=1e-3 * float(range_offset_mm)))
        if pcd_style != "plain" and s.sensor_format == "velodyne-csv":
            raise ValueError(f"--pcd-style {pcd_style} needs PCD files; --format velodyne-csv writes CSV")
    except ValueError as err:
        raise InputError(f"simulate: {err}") from None
    return s


def write_standard_set(
    out: Path | str,
    progress: Callable[[int, int], None] | None = None,
    intrinsics_error: float = 0.0,
    pcd_style: str = "plain",
    range_offset_mm: float = 0.0,
    image_format: str = "png",
    command: str = "",
    **spec: object,
) -> SimulationSpec:
    """The standard set (``standard_set_spec``) written to ``out`` with ``image_format`` images and
    PCD files in ``pcd_style``; InputError naming the option, OutputError the folder when it cannot be."""
    s = standard_set_spec(intrinsics_error, range_offset_mm, pcd_style, **spec)
    kw = {"pcd_style": pcd_style, "image_format": image_format, "command": command}
    simulate_dataset(Path(out), s, progress=progress, **kw)
    return s
