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
    """One frame: its name (the shared file stem), scan file and image file."""

    name: str
    scan: Path
    image: Path


def natural_key(s: str) -> tuple:
    """Sort key that orders ``pose2`` before ``pose10``."""
    return tuple((0, int(t), "") if t.isdigit() else (1, 0, t.lower()) for t in re.split(r"(\d+)", s) if t)


def _by_stem(
    folder: Path, suffixes: tuple[str, ...] | list[str], kind: str, skipped: list[tuple[str, str]]
) -> dict[str, Path]:
    out: dict[str, list[Path]] = {}
    for f in folder.iterdir():
        if f.name.startswith(".") or not f.is_file():
            continue
        if f.suffix.lower() not in suffixes:
            skipped.append((f.stem, f"{kind}/{f.name}: unsupported file type {f.suffix!r}"))
            continue
        out.setdefault(f.stem, []).append(f)
    single: dict[str, Path] = {}
    for stem, files in out.items():
        if len(files) > 1:
            skipped.append((stem, f"several {kind} files for one frame: {sorted(p.name for p in files)}"))
        else:
            single[stem] = files[0]
    return single


def list_frames(data_dir: str | Path) -> tuple[list[FramePaths], list[tuple[str, str]]]:
    """Pair ``data_dir/pcd/<stem>.*`` with ``data_dir/img/<stem>.*``.

    Returns (frames in natural stem order, skipped [(stem, reason)]). A missing ``pcd`` or
    ``img`` folder, or no pair at all, raises ``InputError``.
    """
    d = Path(data_dir)
    if not d.is_dir():
        raise InputError(f"{d}: data folder not found")
    for sub in ("pcd", "img"):
        if not (d / sub).is_dir():
            raise InputError(f"{d}: no '{sub}' folder (expected {d / 'pcd'} and {d / 'img'})")
    skipped: list[tuple[str, str]] = []
    scans = _by_stem(d / "pcd", supported_scan_suffixes(), "pcd", skipped)
    images = _by_stem(d / "img", IMAGE_SUFFIXES, "img", skipped)
    frames = [FramePaths(s, scans[s], images[s]) for s in scans.keys() & images.keys()]
    skipped += [(s, f"scan {scans[s].name} has no image in img/") for s in scans.keys() - images.keys()]
    skipped += [(s, f"image {images[s].name} has no scan in pcd/") for s in images.keys() - scans.keys()]
    frames.sort(key=lambda f: natural_key(f.name))
    skipped.sort(key=lambda t: natural_key(t[0]))
    if not frames:
        detail = "; ".join(f"{s}: {r}" for s, r in skipped[:5]) or "both folders are empty"
        raise InputError(f"{d}: no frame has both a scan in pcd/ and an image in img/ ({detail})")
    return frames, skipped
