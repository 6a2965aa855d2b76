"""Write a simulated data set (the simulator's only file I/O, through ``ilcc_graph.io`` writers).

Layout (interface.md): ``config.yaml`` (our schema), ``pcd/<stem>.pcd`` (binary, x y z intensity
ring; organised HEIGHT x WIDTH for ``sensor_format="ouster"``; header and fields as another tool
writes them with ``pcd_style``, e.g. MATLAB's) or ``pcd/<stem>.csv`` (ILCC's CSV with the hardware
``laser_id`` for ``"velodyne-csv"``), ``img/<stem>.png``, ``ground_truth.yaml``.
Every file is written atomically; the data set
is assembled in a sibling temporary folder and renamed into place at the end, so ``out_dir``
either holds a complete data set or is left as it was.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from .. import signals
from ..errors import InputError
from ..io import PCD_STYLES, write_image, write_pcd, write_yaml
from ..io.scans import write_csv
from ..types import Scan
from .frames import ground_truth, simulate_frames
from .intrinsics import IntrinsicsError, stated_camera
from .spec import SimulationSpec, standard_spec

__all__ = ["assemble", "simulate_dataset", "config_dict", "write_scan", "write_standard_set"]


def config_dict(spec: SimulationSpec) -> dict:
    """config.yaml content (our schema) for the spec's board, LiDAR and camera (the stated camera:
    the truth perturbed by ``spec.intrinsics_error``)."""
    return {
        "board": spec.board.to_dict(),
        "lidar": spec.lidar_model.to_dict(),
        "camera": stated_camera(spec.camera, spec.intrinsics_error, spec.seed).to_dict(),
    }


def simulate_dataset(
    out_dir: Path | str,
    spec: SimulationSpec,
    progress: Callable[[int, int], None] | None = None,
    pcd_style: str = "plain",
) -> Path:
    """Simulate ``spec`` and write the data set to ``out_dir`` (created; must be empty or absent).

    progress: called as ``progress(done, total)`` after each frame. pcd_style: how the PCD files
    look (``io.write_pcd``'s ``style``: ``plain``, ``pcl``, ``open3d``, ``matlab``). Returns ``out_dir``.
    Raises ``FileExistsError`` when ``out_dir`` exists and is not empty.
    """
    if pcd_style not in PCD_STYLES:
        raise ValueError(f"pcd_style must be one of {PCD_STYLES}, got {pcd_style!r}")
    if pcd_style != "plain" and spec.sensor_format == "velodyne-csv":
        raise ValueError(f"pcd_style {pcd_style!r} needs PCD output; sensor_format 'velodyne-csv' writes CSV")
    return assemble(Path(out_dir), lambda tmp: _write(tmp, spec, progress, pcd_style))


def assemble(out: Path, fill: Callable[[Path], None]) -> Path:
    """Run ``fill(tmp)`` on a sibling temporary folder and rename it to ``out`` (absent or empty), so
    ``out`` holds the whole data set or is left as it was. FileExistsError when ``out`` is not empty."""
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise FileExistsError(f"{out}: exists and is not an empty folder")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    with signals.on_stop(lambda: shutil.rmtree(tmp, ignore_errors=True)):
        try:
            fill(tmp)
            if out.exists():
                out.rmdir()
            tmp.rename(out)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return out


def _write(
    tmp: Path, spec: SimulationSpec, progress: Callable[[int, int], None] | None, pcd_style: str
) -> None:
    write_yaml(tmp / "config.yaml", config_dict(spec))
    names, poses = [], []
    total = int(spec.n_frames)
    for k, frame in enumerate(simulate_frames(spec)):
        write_scan(tmp / "pcd", frame.name, frame.scan, spec.sensor_format, pcd_style)
        write_image(tmp / "img" / f"{frame.name}.png", frame.image)
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

    def __init__(self, name: str, T) -> None:
        self.name, self.T_lidar_board = name, T


def write_standard_set(
    out: Path | str,
    progress: Callable[[int, int], None] | None = None,
    intrinsics_error: float = 0.0,
    pcd_style: str = "plain",
    range_offset_mm: float = 0.0,
    **spec: object,
) -> SimulationSpec:
    """The standard set (``standard_spec(**spec)``, stated intrinsics off by ``intrinsics_error`` x a
    typical error, every range ``range_offset_mm`` long on top of the default systematics) written
    to ``out`` with PCD files in ``pcd_style``; InputError naming the option or the folder when it
    cannot be."""
    try:
        s = standard_spec(intrinsics_error=IntrinsicsError.typical(intrinsics_error), **spec)  # type: ignore[arg-type]
        if range_offset_mm:
            s = s.with_(systematics=replace(s.systematics, range_offset_m=1e-3 * float(range_offset_mm)))
        if pcd_style != "plain" and s.sensor_format == "velodyne-csv":
            raise ValueError(f"--pcd-style {pcd_style} needs PCD files; --format velodyne-csv writes CSV")
    except ValueError as err:
        raise InputError(f"simulate: {err}") from None
    parent = Path(out).parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(f"{out}: {parent} is a file, so the data set's folder cannot be made under it")
    try:
        simulate_dataset(Path(out), s, progress=progress, pcd_style=pcd_style)
    except FileExistsError as err:
        raise InputError(f"{err}; choose a new folder") from None
    except OSError as err:
        raise InputError(f"{out}: cannot write the data set ({err.strerror or err})") from None
    return s
