"""Pairing a data set's scans and images by file stem (interface.md, "A data set on disk")."""

from __future__ import annotations

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
    scan: Path | None
    image: Path | None
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
_TIME_NAME = re.compile(r"^(\d{9,10})(?:([._])(\d{1,9}))?$|^(\d{13}|\d{16}|\d{19})$")

#: ``by_time(scan seconds, image seconds) -> ({scan index: image index}, each scan's gap to its
#: nearest image in s, the index of that image)`` (``datasets.folder``, by ``datasets.timeline``)
TimePairing = Callable[[np.ndarray, np.ndarray], tuple[dict[int, int], np.ndarray, np.ndarray]]

#: the two readings of a nanosecond field after ``_`` with fewer than 9 digits (``1510868224_17000000``):
#: a decimal fraction (0.17 s), or nanoseconds a recorder did not pad to 9 digits (0.017 s; ROS
#: writes ``secs_nsecs`` padded, where both readings agree)
READINGS = ("a decimal fraction", "unpadded nanoseconds")
_NON_DIGITS = "".join(chr(c) for c in range(32, 127) if not chr(c).isdigit())


def name_seconds(stem: str, unpadded: bool = False) -> float | None:
    """The time a file's name gives, in seconds (``_TIME_NAME``), or None when the name is no time;
    ``unpadded``: a field after ``_`` read as a whole number of nanoseconds (``READINGS``)."""
    m = _TIME_NAME.match(stem)
    if m is None:
        return None
    if m.group(4) is not None:
        digits = m.group(4)
        return int(digits) / {13: 1e3, 16: 1e6, 19: 1e9}[len(digits)]
    secs, sep, frac = m.group(1), m.group(2), m.group(3)
    if frac is not None and unpadded and sep == "_":
        return int(secs) + int(frac) * 1e-9
    return float(f"{secs}.{frac or 0}")


def _seconds_text(rest: str, unpadded: bool) -> str:
    """The time of a name's time part as written, in seconds, every digit kept (no float rounding)."""
    m = _TIME_NAME.match(rest)
    if m is None or m.group(4) is not None or m.group(3) is None:
        return f"{name_seconds(rest, unpadded):.9f}".rstrip("0").rstrip(".")
    secs, sep, frac = m.groups()[:3]
    return f"{secs}.{int(frac):09d}" if unpadded and sep == "_" else f"{secs}.{frac}"


def _ambiguous(rest: str) -> bool:
    """Whether the two ``READINGS`` of this time differ (``_`` and fewer than 9 digits after it)."""
    m = _TIME_NAME.match(rest)
    return m is not None and m.group(2) == "_" and len(m.group(3)) < 9


def _time_names(files: dict[str, Path]) -> tuple[dict[str, str], list[str]]:
    """({name: its time part}, names set aside): the run of non-digits before the time (a recorder's
    ``cloud_``) must be the one most names have; a name that is no time or has another is a stray."""
    parts = {n: (n[: len(n) - len(n.lstrip(_NON_DIGITS))], n.lstrip(_NON_DIGITS)) for n in files}
    prefixes = [pre for pre, rest in parts.values() if name_seconds(rest) is not None]
    if not prefixes:
        return {}, sorted(files)
    common = max(set(prefixes), key=prefixes.count)
    timed = {n: rest for n, (pre, rest) in parts.items() if pre == common and name_seconds(rest) is not None}
    return timed, sorted(files.keys() - timed.keys())


def _conflicts(timed: dict[str, str], unpadded: bool, files: dict[str, Path], what: str) -> dict[str, str]:
    """{name: reason} of the names whose times equal another's: both set aside, each naming the other."""
    by_t: dict[float, list[str]] = {}
    for n in sorted(timed):
        by_t.setdefault(name_seconds(timed[n], unpadded), []).append(n)  # type: ignore[arg-type]
    out = {}
    for names in by_t.values():
        for n in names if len(names) > 1 else ():
            others = ", ".join(files[o].name for o in names if o != n)
            out[n] = (
                f"{what} {files[n].name}: its name gives the same time as {others} "
                f"({_seconds_text(timed[n], unpadded)} s): a conflict (a copy, or files of two "
                "recordings?); both set aside"
            )
    return out


def _paired_by_time(
    scans: dict[str, Path], images: dict[str, Path], by_time: TimePairing
) -> tuple[dict[str, Path], list[tuple[str, str]], str] | None:
    """Images renamed to the stems of the scans they pair with by the times in their names (after the
    run of non-digits most names begin with; equal names pair at distance 0), the scans and images
    left alone (stem, reason: strays whose name is no time, equal times, no partner near), and the
    note saying how many pairs differ in name and which reading of the names was used when both are
    possible (``READINGS``; the one that pairs more scans, then the nearer); None when most names
    are no times."""
    (s_time, s_stray), (i_time, i_stray) = _time_names(scans), _time_names(images)
    if 2 * len(s_time) <= len(scans) or 2 * len(i_time) <= len(images):
        return None
    times = [*s_time.values(), *i_time.values()]
    readings, why = _readings(times)
    tries = [_try_reading(scans, images, s_time, i_time, u, by_time) for u in readings]
    best = max(tries, key=lambda t: len(t[0]))  # the first (the conventional reading) on a tie
    renamed, left, other, _ = best
    stray = "its name is no time like the others' ({}); set aside, the others pair by time"
    left += [(n, f"scan {scans[n].name}: " + stray.format(next(iter(s_time)))) for n in s_stray]
    left += [(n, f"image {images[n].name}: " + stray.format(next(iter(i_time)))) for n in i_stray]
    notes = []
    if other:
        notes.append(
            f"{other} of {len(scans)} scans paired with an image of another name, the one nearest in "
            "time by the times the names give (a frame is named by its scan)"
        )
    if why:
        k = int(readings[tries.index(best)])
        example = min(r for r in times if _ambiguous(r))
        counts = (
            ""
            if len(tries) == 1
            else f": it pairs {len(best[0])} scans, {READINGS[1 - k]} {len(tries[1 - k][0])}"
        )
        notes.append(
            f"names like {example} read as {READINGS[k]} ({_seconds_text(example, bool(k))} s; {why}){counts}"
        )
    return renamed, left, "; ".join(notes)


def _readings(times: list[str]) -> tuple[tuple[bool, ...], str]:
    """The readings of the names' ``_`` fields to try (``READINGS``: False the decimal fraction, True
    unpadded nanoseconds) and why ("" when no name is ambiguous), by their digits: a field with a
    leading zero was padded; fields of several lengths below 9 were not (a padded writer writes one
    length); neither or both: the reading that pairs more scans, the decimal fraction on a tie."""
    fields = [m.group(3) for r in times if (m := _TIME_NAME.match(r)) and m.group(2) == "_" and m.group(3)]
    if not any(len(f) < 9 for f in fields):
        return (False,), ""
    padded = any(f.startswith("0") and len(f) > 1 for f in fields)
    unpadded = len({len(f) for f in fields}) > 1
    if padded != unpadded:
        return (unpadded,), (
            "their digits vary in number, as a recorder that does not pad writes them"
            if unpadded
            else "some begin with 0: padded"
        )
    return (False, True), "both readings possible"


def _try_reading(
    scans: dict[str, Path],
    images: dict[str, Path],
    s_time: dict[str, str],
    i_time: dict[str, str],
    unpadded: bool,
    by_time: TimePairing,
) -> tuple[dict[str, Path], list[tuple[str, str]], int, float]:
    """One reading of the names: (images renamed to their scans' stems, those left alone, how many
    pairs differ in name, the pairs' summed gap in s)."""
    s_bad, i_bad = _conflicts(s_time, unpadded, scans, "scan"), _conflicts(i_time, unpadded, images, "image")
    s_names = sorted(s_time.keys() - s_bad.keys())
    i_names = sorted(i_time.keys() - i_bad.keys())
    t_s = np.array([name_seconds(s_time[n], unpadded) for n in s_names], dtype=np.float64)
    t_i = np.array([name_seconds(i_time[n], unpadded) for n in i_names], dtype=np.float64)
    pairs, gap, near = by_time(t_s, t_i) if len(t_s) and len(t_i) else ({}, np.zeros(0), np.zeros(0, int))
    taken = {b: a for a, b in pairs.items()}
    left = [(n, why) for n, why in [*s_bad.items(), *i_bad.items()]]
    for a, n in enumerate(s_names):
        if a in pairs:
            continue
        why = f"scan {scans[n].name}: no image near its time (the nearest {gap[a]:.3f} s away)"
        if int(near[a]) in taken:
            b = int(near[a])
            why = (
                f"scan {scans[n].name}: its nearest image {images[i_names[b]].name} ({gap[a]:.3f} s away) "
                f"pairs with scan {scans[s_names[taken[b]]].name}, nearer to it"
            )
        left.append((n, why))
    left += [
        (n, f"image {images[n].name}: no scan near its time") for b, n in enumerate(i_names) if b not in taken
    ]
    renamed = {s_names[a]: images[i_names[b]] for a, b in pairs.items()}
    other = sum(1 for a, b in pairs.items() if s_names[a] != i_names[b])
    return renamed, left, other, float(sum(gap[a] for a in pairs))


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
    ]
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
