"""A recording's time line as plain arrays: motion between samples, still intervals, and the
pairing of scans with images by time (docs/datasets.md has the rules and thresholds)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "Stream",
    "common_still_runs",
    "image_change",
    "lidar_change",
    "motion_image",
    "nearest",
    "pair_by_time",
    "range_image",
    "still_runs",
    "unpaired",
]

MOTION_STEP_S = 0.09  # motion is measured between samples at least this far apart (<= ~10 Hz)
IMAGE_WIDTH = 320  # grey images are shrunk to about this width to measure motion
IMAGE_LEVEL, IMAGE_STILL = 10, 0.002  # a pixel changed by > 10 grey levels; still: <= 0.2 % changed
LIDAR_STEP_M, LIDAR_STILL = 0.10, 0.003  # a cell changed by > 10 cm and 3 %; still: <= 0.3 % changed
AZIMUTH_BINS = 360


def motion_image(img: np.ndarray) -> np.ndarray:
    """A BGR image (H, W, 3) as a small grey image (about IMAGE_WIDTH wide) to measure motion on."""
    import cv2

    f = max(1, round(img.shape[1] / IMAGE_WIDTH))  # area averaging: noise / f, board motion kept
    small = cv2.resize(img, (img.shape[1] // f, img.shape[0] // f), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_BGR2GRAY)


def image_change(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of pixels whose grey level changed by more than IMAGE_LEVEL."""
    return float(np.mean(np.abs(a.astype(np.int16) - b) > IMAGE_LEVEL)) if a.shape == b.shape else 1.0


def range_image(points: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(beams, AZIMUTH_BINS) nearest range per beam and 1-degree azimuth cell; inf where empty."""
    az = np.arctan2(points[:, 1], points[:, 0])
    col = np.minimum((az + np.pi) * (AZIMUTH_BINS / (2 * np.pi)), AZIMUTH_BINS - 1).astype(np.int64)
    key = rows.astype(np.int64) * AZIMUTH_BINS + col
    order = np.argsort(key, kind="stable")
    k = key[order]
    start = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
    img = np.full((int(rows.max()) + 1 if len(rows) else 1) * AZIMUTH_BINS, np.inf)
    img[k[start]] = np.minimum.reduceat(np.linalg.norm(points, axis=1)[order], start)
    return img.reshape(-1, AZIMUTH_BINS)


def lidar_change(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of cells seen in both scans whose range changed by more than LIDAR_STEP_M and 3 %."""
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    both = np.isfinite(a) & np.isfinite(b)
    if not both.any():
        return 1.0
    d = np.abs(a[both] - b[both])
    return float(np.mean(d > np.maximum(LIDAR_STEP_M, 0.03 * np.minimum(a[both], b[both]))))


def still_runs(times: np.ndarray, changes: np.ndarray, threshold: float) -> list[tuple[float, float]]:
    """Maximal intervals [t_a, t_b] (a < b) over which every step's change is <= threshold.

    changes[k] is the change from sample k to sample k + 1 (len(times) - 1 values).
    """
    runs, start = [], 0
    for k, c in enumerate(changes):
        if c > threshold:
            if k > start:
                runs.append((float(times[start]), float(times[k])))
            start = k + 1
    if len(times) - 1 > start:
        runs.append((float(times[start]), float(times[-1])))
    return runs


@dataclass
class Stream:
    """One topic's messages: bag (receive) times, header stamps (+ sweep offsets), the time base used
    (``header`` or ``bag``), and the motion between samples (``changes[k]``: sample k to k + 1)."""

    topic: str
    still: float
    bag_ns: list[int] = field(default_factory=list)
    stamp_ns: list[int] = field(default_factory=list)
    offset_s: list[float] = field(default_factory=list)
    samples: list[int] = field(default_factory=list)
    changes: list[float] = field(default_factory=list)
    time_base: str = "header"

    def times(self, base: str | None = None) -> np.ndarray:
        """Seconds of every message in ``base`` (default: the stream's time base)."""
        if (base or self.time_base) == "bag":
            return np.asarray(self.bag_ns, dtype=np.float64) * 1e-9
        return np.asarray(self.stamp_ns, dtype=np.float64) * 1e-9 + np.asarray(self.offset_s)

    def runs(self) -> list[tuple[float, float]]:
        """Still intervals of this stream (seconds, in its time base)."""
        return still_runs(self.times()[self.samples], np.asarray(self.changes), self.still)


def common_still_runs(streams: list[Stream]) -> tuple[list[tuple[float, float]], bool]:
    """Still intervals of several streams watched together (a rig's cameras): the span of their
    samples minus every step over which some stream moved; and whether any stream moved. A stream
    without samples over a while (a camera triggered only when it sees the board) says nothing there."""
    moving, times = [], []
    for s in streams:
        t = s.times()[s.samples]
        times.append(t)
        moving += [(float(t[k]), float(t[k + 1])) for k, c in enumerate(s.changes) if c > s.still]
    every = np.concatenate(times) if times else np.zeros(0)
    if not every.size:
        return [], False
    runs, start = [], float(every.min())
    for a, b in sorted(moving):
        if a > start:
            runs.append((start, a))
        start = max(start, b)
    if float(every.max()) > start:
        runs.append((start, float(every.max())))
    return runs, bool(moving)


def nearest(ref: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Index into ``ref`` (non-empty) of the value nearest to each ``q``."""
    order = np.argsort(ref, kind="stable")
    r = ref[order]
    hi = np.clip(np.searchsorted(r, q), 0, len(r) - 1)
    lo = np.maximum(hi - 1, 0)
    return order[np.where(np.abs(q - r[lo]) <= np.abs(r[hi] - q), lo, hi)]


def pair_by_time(ts: np.ndarray, ti: np.ndarray, tol: float) -> dict[int, int]:
    """Scan index -> image index: mutual nearest neighbours in time at most ``tol`` apart."""
    if not len(ts) or not len(ti):
        return {}
    near_i, near_s = nearest(ti, ts), nearest(ts, ti)
    return {i: int(j) for i, j in enumerate(near_i) if near_s[j] == i and abs(ti[j] - ts[i]) <= tol}


def unpaired(ts: np.ndarray, ti: np.ndarray, pairs: dict[int, int], tol: float, names: list[str]) -> list:
    """(name, reason) of scans whose nearest image is beyond ``tol`` and in no pair: a frame missed."""
    if not len(ti):
        return []
    near, taken = nearest(ti, ts), set(pairs.values())
    return [
        (
            names[i],
            f"no image within {tol} s of the scan (the nearest is {abs(ti[near[i]] - ts[i]):.3f} s away)",
        )
        for i in range(len(ts))
        if i not in pairs and int(near[i]) not in taken
    ]
