"""Pairing a data set's scans and images by file stem (interface.md, "A data set on disk")."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError
from .images import IMAGE_SUFFIXES
from .scans import supported_scan_suffixes

__all__ = ["FramePaths", "list_frames", "natural_key"]


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


def _by_stem(
    folder: Path,
    suffixes: tuple[str, ...] | list[str],
    kind: str,
    skipped: list[tuple[str, str]],
    notes: dict[str, str],
) -> dict[str, Path]:
    """stem -> the file of that stem (the preferred one when there are several, noted in ``notes``)."""
    out: dict[str, list[Path]] = {}
    for f in folder.iterdir():
        if f.name.startswith(".") or not (f.is_file() or (f.is_symlink() and not f.exists())):
            continue  # a broken link is kept: reading it says so, for its frame
        if f.suffix.lower() not in suffixes:
            skipped.append((f.stem, f"{kind}/{f.name}: unsupported file type {f.suffix!r}"))
            continue
        out.setdefault(f.stem, []).append(f)
    single: dict[str, Path] = {}
    what = "scans" if kind == "pcd" else "images"
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


def list_frames(
    data_dir: str | Path, require_image: bool = True, require_scan: bool = True
) -> tuple[list[FramePaths], list[tuple[str, str]]]:
    """Pair ``data_dir/pcd/<stem>.*`` with ``data_dir/img/<stem>.*``.

    Returns (frames in natural stem order, skipped [(stem, reason)]). A stem with several scans (or
    images) uses the preferred file (``PREFERENCE``) and says so in the frame's ``note``. A missing ``pcd`` or
    ``img`` folder, or no frame at all, raises ``InputError``.
    require_image=False (LiDAR-only runs): every scan is a frame, ``image`` is None when it has
    no partner and ``img/`` may be absent. require_scan=False likewise for image-only runs.
    """
    d = Path(data_dir)
    if not d.is_dir():
        raise InputError(f"{d}: data folder not found")
    for sub, required in (("pcd", require_scan), ("img", require_image)):
        if required and not (d / sub).is_dir():
            raise InputError(f"{d}: no '{sub}' folder (expected {d / 'pcd'} and {d / 'img'})")
    skipped: list[tuple[str, str]] = []
    notes: dict[str, str] = {}
    scans = (
        _by_stem(d / "pcd", supported_scan_suffixes(), "pcd", skipped, notes) if (d / "pcd").is_dir() else {}
    )
    img_notes: dict[str, str] = {}
    images = _by_stem(d / "img", IMAGE_SUFFIXES, "img", skipped, img_notes) if (d / "img").is_dir() else {}
    stems = scans.keys() & images.keys()
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
    skipped += [
        (s, f"scan {scans[s].name} has no image in img/") for s in scans.keys() - images.keys() - stems
    ]
    skipped += [
        (s, f"image {images[s].name} has no scan in pcd/") for s in images.keys() - scans.keys() - stems
    ]
    frames.sort(key=lambda f: natural_key(f.name))
    skipped.sort(key=lambda t: natural_key(t[0]))
    if not frames:
        detail = "; ".join(f"{s}: {r}" for s, r in skipped[:5]) or "the folders hold no scans or images"
        what = (
            "has both a scan in pcd/ and an image in img/" if require_image and require_scan else "was found"
        )
        raise InputError(f"{d}: no frame {what} ({detail})")
    return frames, skipped
