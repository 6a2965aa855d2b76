"""Pairing a data set's scans and images by file stem (interface.md, "A data set on disk")."""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .images import IMAGE_SUFFIXES
from .scans import supported_scan_suffixes

__all__ = [
    "IMAGE_FOLDERS",
    "SCAN_FOLDERS",
    "FramePaths",
    "TimePairing",
    "data_folders",
    "list_frames",
    "name_seconds",
    "natural_key",
]

#: where a data set's scans may be, first the layout's own (interface.md), then the names other
#: tools and labs use (KITTI odometry's ``velodyne``, KITTI raw's ``velodyne_points/data``)
SCAN_FOLDERS = ("pcd", "lidar", "velodyne", "velodyne_points", "pointclouds", "point_clouds", "points",
                "clouds", "scans")  # fmt: skip
#: where its images may be (KITTI's ``image_2``, KITTI raw's ``image_02/data``)
IMAGE_FOLDERS = ("img", "images", "image", "camera", "cam", "rgb", "image_0", "image_1", "image_2",
                 "image_3", "image_00", "image_01", "image_02", "image_03")  # fmt: skip


@dataclass(frozen=True)
class FramePaths:
    """One frame: its name (the shared file stem), scan file and image file.

    ``scan`` / ``image`` are None only in frames listed with ``require_scan`` / ``require_image``
    False. ``note``: what a person should know about how the files were paired (a stem with two
    scans, say), or None.
    """

    name: str
    scan: Path
    image: Path
    note: str | None = None


#: which file a frame uses when one stem has several (first wins): formats that name their fields
#: and store intensity explicitly before headerless ones; lossless images before JPEG
PREFERENCE = (".pcd", ".ply", ".csv", ".bin", ".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg")


def natural_key(s: str) -> tuple:
    """Sort key that orders ``pose2`` before ``pose10``."""
    return tuple((0, int(t), "") if t.isdigit() else (1, 0, t.lower()) for t in re.split(r"(\d+)", s) if t)


def _rank(p: Path) -> tuple[int, str]:
    s = p.suffix.lower()
    return (PREFERENCE.index(s) if s in PREFERENCE else len(PREFERENCE), p.name)


def _holds(folder: Path, suffixes: tuple[str, ...] | list[str]) -> bool:
    """``folder`` holds a file of one of ``suffixes`` (an unreadable folder holds none)."""
    try:
        return any(f.suffix.lower() in suffixes and not f.name.startswith(".") for f in folder.iterdir())
    except OSError:
        return False


def _one_folder(
    d: Path, names: tuple[str, ...], suffixes: tuple[str, ...] | list[str], what: str
) -> str | None:
    """The folder of ``d`` (relative name) holding its ``what``: ``names[0]`` when it exists, else the
    one of the other ``names`` that holds such files (or whose ``data/`` does, as in KITTI raw); None
    when none does. Two such folders: InputError naming them."""
    if (d / names[0]).is_dir():
        return names[0]
    found = []
    for n in names[1:]:
        for sub in (n, f"{n}/data"):
            if (d / sub).is_dir() and _holds(d / sub, suffixes):
                found.append(sub)
                break
    if len(found) > 1:
        listed = ", ".join(f"{n}/" for n in found)
        raise InputError(
            f"{d}: the {what} could be in any of {listed}: name the one to use {names[0]}/ "
            f"(e.g. ln -s {found[0]} {d / names[0]})"
        )
    return found[0] if found else None


def data_folders(data_dir: str | Path) -> tuple[str | None, str | None]:
    """(scan folder, image folder) of a data set, relative to it: ``pcd`` and ``img`` (interface.md),
    else the one folder of ``SCAN_FOLDERS`` / ``IMAGE_FOLDERS`` there is; None for a kind with none.
    Raises InputError when two folders could hold the same kind."""
    d = Path(data_dir)
    scans = _one_folder(d, SCAN_FOLDERS, supported_scan_suffixes(), "scans")
    images = _one_folder(d, IMAGE_FOLDERS, IMAGE_SUFFIXES, "images")
    return scans, images


def _by_stem(
    folder: Path,
    suffixes: tuple[str, ...] | list[str],
    kind: str,
    what: str,
    skipped: list[tuple[str, str]],
    notes: dict[str, str],
) -> dict[str, Path]:
    """stem -> the file of that stem (the preferred one when there are several, noted in ``notes``);
    ``kind``: the folder's name in messages, ``what``: "scans" or "images"."""
    out: dict[str, list[Path]] = {}
    for f in folder.iterdir():
        if f.name.startswith(".") or not (f.is_file() or (f.is_symlink() and not f.exists())):
            continue  # a broken link is kept: reading it says so, for its frame
        if f.suffix.lower() not in suffixes:
            skipped.append((f.stem, f"{kind}/{f.name}: unsupported file type {f.suffix!r}"))
            continue
        out.setdefault(f.stem, []).append(f)
    single: dict[str, Path] = {}
    for stem, files in out.items():
        files.sort(key=_rank)
        single[stem] = files[0]
        if len(files) > 1:
            names = ", ".join(f"{kind}/{p.name}" for p in sorted(files))
            notes[stem] = (
                f"frame {stem} has {len(files)} {what} ({names}); using {files[0].name}; "
                "remove the other(s) if they are not the same recording"
            )
    return single


#: a name that is a time: seconds with a fraction (``1510868224.123456``, ``1510868224_123456789``),
#: or whole seconds, milli-, micro- or nanoseconds (10, 13, 16, 19 digits: ``1510868224123456``)
_TIME_NAME = re.compile(r"^(\d{9,10})(?:[._](\d{1,9}))?$|^(\d{13}|\d{16}|\d{19})$")

#: ``by_time(scan seconds, image seconds) -> ({scan index: image index}, each scan's gap to its
#: nearest image in s)`` (``datasets.folder``, by ``datasets.timeline.pair_by_time``)
TimePairing = Callable[[np.ndarray, np.ndarray], tuple[dict[int, int], np.ndarray]]


def name_seconds(stem: str) -> float | None:
    """The time a file's name gives, in seconds (``_TIME_NAME``), or None when the name is no time."""
    m = _TIME_NAME.match(stem)
    if m is None:
        return None
    if m.group(3) is not None:
        digits = m.group(3)
        return int(digits) / {13: 1e3, 16: 1e6, 19: 1e9}[len(digits)]
    return float(f"{m.group(1)}.{m.group(2) or 0}")


def _prefix_length(names: list[str]) -> int:
    """Length of the run of non-digits all ``names`` begin with alike (``frame_``, ``cloud-``): what
    a recorder put before the time."""
    common = os.path.commonprefix(names)
    return next((i for i, c in enumerate(common) if c.isdigit()), len(common))


def _paired_by_time(
    scans: dict[str, Path], images: dict[str, Path], by_time: TimePairing
) -> tuple[dict[str, Path], list[tuple[str, str]], str] | None:
    """Images renamed to the stems of the scans they pair with by the times in their names (after a
    prefix every scan's, or every image's, name shares; equal names pair at distance 0), the scans
    and images left alone (stem, reason), and the note saying how many pairs differ in name (empty
    when none); None when some name is no time."""
    s_names, i_names = sorted(scans), sorted(images)
    ks, ki = _prefix_length(s_names), _prefix_length(i_names)
    ts = [name_seconds(n[ks:]) for n in s_names]
    ti = [name_seconds(n[ki:]) for n in i_names]
    if any(t is None for t in ts + ti):
        return None
    t_s, t_i = np.array(ts, dtype=np.float64), np.array(ti, dtype=np.float64)
    pairs, gap = by_time(t_s, t_i)
    renamed = {s_names[a]: images[i_names[b]] for a, b in pairs.items()}
    left = [
        (n, f"scan {scans[n].name}: no image near its time (the nearest {gap[a]:.3f} s away)")
        for a, n in enumerate(s_names)
        if a not in pairs
    ]
    taken = set(pairs.values())
    left += [
        (n, f"image {images[n].name}: no scan near its time") for b, n in enumerate(i_names) if b not in taken
    ]
    other = sum(1 for a, b in pairs.items() if s_names[a] != i_names[b])
    note = (
        f"{other} of {len(s_names)} scans paired with an image of another name, the one nearest in "
        "time by the times the names give (a frame is named by its scan)"
        if other
        else ""
    )
    return renamed, left, note


def list_frames(
    data_dir: str | Path,
    require_image: bool = True,
    require_scan: bool = True,
    by_time: TimePairing | None = None,
) -> tuple[list[FramePaths], list[tuple[str, str]]]:
    """Pair ``data_dir/pcd/<stem>.*`` with ``data_dir/img/<stem>.*`` (or the folders of another
    common name, ``data_folders``).

    Returns (frames in natural stem order, skipped [(stem, reason)]). A stem with several scans (or
    images) uses the preferred file (``PREFERENCE``) and says so in the frame's ``note``. A missing
    folder of scans or images, two candidates for one, or no frame at all, raises ``InputError``.
    require_image=False (LiDAR-only runs): every scan is a frame, ``image`` is None when it has
    no partner and the images' folder may be absent. require_scan=False likewise for image-only runs.
    ``by_time``: when some scan has no image of its name and every name is a time (``name_seconds``),
    scans and images pair as it says (the frame named by the scan; said in every frame's note when
    some pair's names differ).
    """
    d = Path(data_dir)
    if not d.is_dir():
        raise InputError(f"{d}: data folder not found")
    scan_dir, image_dir = data_folders(d)
    for sub, required, names in (
        (scan_dir, require_scan, SCAN_FOLDERS),
        (image_dir, require_image, IMAGE_FOLDERS),
    ):
        if required and sub is None:
            raise InputError(
                f"{d}: no '{names[0]}' folder (expected {d / 'pcd'} and {d / 'img'}; also taken: "
                f"{', '.join(n + '/' for n in names[1:])})"
            )
    skipped: list[tuple[str, str]] = []
    notes: dict[str, str] = {}
    scans = (
        _by_stem(d / scan_dir, supported_scan_suffixes(), scan_dir, "scans", skipped, notes)
        if scan_dir
        else {}
    )
    img_notes: dict[str, str] = {}
    images = (
        _by_stem(d / image_dir, IMAGE_SUFFIXES, image_dir, "images", skipped, img_notes) if image_dir else {}
    )
    stems = scans.keys() & images.keys()
    timed = None
    if by_time is not None and require_image and require_scan and images and len(stems) < len(scans):
        timed = _paired_by_time(scans, images, by_time)
    if timed is not None:
        images, left, note = timed
        skipped += left
        stems = set(images)
        img_notes = {n: img_notes[p.stem] for n, p in images.items() if p.stem in img_notes}
        if note:
            notes = {n: "; ".join(x for x in (notes.get(n), note) if x) for n in stems}
    if not require_image:
        stems |= scans.keys()
    if not require_scan:
        stems |= images.keys()
    frames = [
        FramePaths(
            s, scans.get(s), images.get(s), "; ".join(n[s] for n in (notes, img_notes) if s in n) or None
        )
        for s in stems
    ]  # type: ignore[arg-type]
    if timed is None:  # by time, the ones left alone are listed already
        skipped += [
            (s, f"scan {scans[s].name} has no image in {image_dir or 'img'}/")
            for s in scans.keys() - images.keys() - stems
        ]
        skipped += [
            (s, f"image {images[s].name} has no scan in {scan_dir or 'pcd'}/")
            for s in images.keys() - scans.keys() - stems
        ]
    frames.sort(key=lambda f: natural_key(f.name))
    skipped.sort(key=lambda t: natural_key(t[0]))
    if not frames:
        detail = "; ".join(f"{s}: {r}" for s, r in skipped[:5]) or "the folders hold no scans or images"
        what = (
            f"has both a scan in {scan_dir}/ and an image in {image_dir}/"
            if require_image and require_scan
            else "was found"
        )
        raise InputError(f"{d}: no frame {what} ({detail})")
    return frames, skipped
