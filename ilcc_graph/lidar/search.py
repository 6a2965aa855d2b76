"""The board search shared by scanline scans (detection.py) and scanline-free ones (ringless.py).

:func:`search_board` tests each object as found with the paper's tests (detection.py's list),
trims a piece that fails, offers what passes to the caller's ``accept`` and, only when that says
no, splits the over-merged objects smallest first (peel a plane, cut inliers and rest into
connected pieces, test those, queue the big ones). What differs between the two kinds of scan
comes in as :class:`SearchInput`: how an object is cut into pieces, the theoretical point count,
the tests' beam model, the trimming, the plane fit and the message's hint.
Frames: the LiDAR frame, metres.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..board import Board
from ..errors import BoardNotFound
from .board_tests import intensity_contrast, print_visible
from .options import LidarOptions, breach

__all__ = ["Candidate", "SearchInput", "inside_mask", "inlier_threshold", "piece_range", "ransac_plane",
           "roi_mask", "search_board"]  # fmt: skip

PlaneFn = Callable[[np.ndarray, float, np.random.Generator], tuple[np.ndarray, float, np.ndarray]]
#: failed tests after which a piece of a split object is trimmed and tested again
TRIMMABLE = ("size", "uniformity", "count", "plane", "contrast")
#: fewest returns of a piece worth a look
MIN_PIECE = 12
#: the share of a plane's inliers its largest connected piece holds when the plane is one surface
ONE_SURFACE = 0.8


@dataclass(frozen=True)
class Candidate:
    """The chessboard's points found in a scan.

    indices: (M,) indices into the scan's points. normal: (3,) unit plane normal towards the sensor.
    offset: plane offset d with ``normal @ p = d`` (metres, negative: the sensor is on the normal's side).
    uniformity: the paper's quadrant uniformity. noise_sigma: range noise of the scan (m).
    tested: number of candidates tested (so far). contrast: the black/white separation d'.
    """

    indices: np.ndarray
    normal: np.ndarray
    offset: float
    uniformity: float
    noise_sigma: float
    tested: int
    contrast: float = 0.0


def roi_mask(points: np.ndarray, roi: Any | None) -> np.ndarray:
    """(N,) bool: points inside the region of interest (config.Roi or None = everything).

    Azimuth ``atan2(y, x)`` and elevation ``atan2(z, hypot(x, y))`` in degrees, range in metres;
    an azimuth interval with lo > hi wraps through +-180 deg.
    """
    p = np.asarray(points, dtype=np.float64)
    if roi is None:
        return np.ones(p.shape[0], bool)
    if hasattr(roi, "contains"):
        return np.asarray(roi.contains(p), bool)
    keep = np.ones(p.shape[0], bool)
    if getattr(roi, "azimuth_deg", None) is not None:
        lo, hi = roi.azimuth_deg
        az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
        keep &= ((az >= lo) & (az <= hi)) if lo <= hi else ((az >= lo) | (az <= hi))
    if getattr(roi, "elevation_deg", None) is not None:
        lo, hi = roi.elevation_deg
        el = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
        keep &= (el >= lo) & (el <= hi)
    if getattr(roi, "range_m", None) is not None:
        lo, hi = roi.range_m
        r = np.linalg.norm(p, axis=1)
        keep &= (r >= lo) & (r <= hi)
    return keep


def piece_range(points: np.ndarray) -> float:
    """The range (m) at which a board among ``points`` (N, 3, LiDAR frame) would stand: the median
    return's. Not the mean point's: an object around the sensor (a room the board merged with) has
    its mean near the origin, and a board's count at that range would bar it from being split."""
    return float(np.median(np.linalg.norm(points, axis=1)))


def inside_mask(
    points: np.ndarray, roi: Any | None, mask: np.ndarray | None, valid: np.ndarray | None = None
) -> np.ndarray:
    """(N,) bool: the points (N, 3) the search may use: ``valid`` (None: all), inside ``roi`` and
    ``mask`` (the expected board's box, None: everywhere); BoardNotFound when there is none."""
    inside = roi_mask(points, roi) if valid is None else valid & roi_mask(points, roi)
    if mask is not None:
        inside &= np.asarray(mask, bool)
    if not inside.any():
        where = "the region of interest (board.roi)" if mask is None else "the expected board's box"
        raise BoardNotFound(f"no point of the scan lies inside {where}")
    return inside


def ransac_plane(
    p: np.ndarray, threshold: float, rng: np.random.Generator, n_hyp: int = 96, max_score: int = 1500
) -> tuple[np.ndarray, float, np.ndarray]:
    """Vectorised RANSAC plane, refined by least squares on the inliers.

    p: (M, 3). Returns (normal (3,), offset d with normal @ x = d, inlier mask (M,)).
    """
    m = p.shape[0]
    sub = p if m <= max_score else p[rng.choice(m, max_score, replace=False)]
    tri = rng.integers(0, m, size=(n_hyp, 3))
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    nrm = np.cross(b - a, c - a)
    ln = np.linalg.norm(nrm, axis=1)
    good = ln > 1e-9
    nrm = nrm[good] / ln[good, None]
    d = np.einsum("ij,ij->i", nrm, a[good])
    if nrm.shape[0] == 0:
        return np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(m, bool)
    score = (np.abs(sub @ nrm.T - d) < threshold).sum(axis=0)
    best = int(np.argmax(score))
    n, dd = nrm[best], d[best]
    for _ in range(2):
        inl = np.abs(p @ n - dd) < threshold
        if inl.sum() < 3:
            break
        q = p[inl]
        mu = q.mean(axis=0)
        _, _, vt = np.linalg.svd(q - mu, full_matrices=False)
        n, dd = vt[2], float(vt[2] @ mu)
    inl = np.abs(p @ n - dd) < threshold
    return n, float(dd), inl


def inlier_threshold(options: LidarOptions, sigma: float) -> float:
    """RANSAC inlier distance (m) for a scan with range noise ``sigma`` (m)."""
    return max(options.ransac_threshold_m, 2.5 * sigma)


@dataclass(frozen=True)
class SearchInput:
    """One scan as the search sees it, and what its kind of scan does its own way.

    points: (M, 3) the returns searched, LiDAR frame, metres; intensity: (M,). Indices below are
    into these. to_scan: (M,) each one's index in the scan (None: the same).
    sigma: range noise (m); threshold: RANSAC inlier distance (m).
    objects: the segments as found (ascending index arrays).
    n_theory(idx): returns a frontal board would give at the piece's range.
    admit(idx): any further condition for testing a piece (the scanline search: enough rings).
    at_edge(idx): whether the piece reaches the top or the lowest beam of the LiDAR's field (a board
        there may be cut by it; default never).
    tests(idx): ``board_tests`` on the piece: (passed, uniformity, failed test, detail).
    trims(idx, depth): trimmed pieces of a piece that failed, lazily (depth 1: a piece of a split
        object, 2: a trimmed piece; only those of depth-1 pieces are tested).
    pieces(sub, links): the connected pieces of ``sub`` within ``links``, each with its own links.
    links(idx): what ``pieces`` needs to cut the object ``idx`` (scanline: its links; default None).
    plane_fn(p, threshold, rng) -> (normal, offset, inliers). note, hint: the failure message's
    extra words after the count of tested candidates and after the advice.
    """

    points: np.ndarray
    intensity: np.ndarray
    sigma: float
    threshold: float
    objects: list[np.ndarray]
    n_theory: Callable[[np.ndarray], float]
    tests: Callable[[np.ndarray], tuple[bool, float, str, str]]
    trims: Callable[[np.ndarray, int], Iterator[np.ndarray]]
    pieces: Callable[[np.ndarray, Any], list[tuple[np.ndarray, Any]]]
    links: Callable[[np.ndarray], Any] = lambda idx: None
    plane_fn: PlaneFn = ransac_plane
    admit: Callable[[np.ndarray], bool] = lambda idx: True
    at_edge: Callable[[np.ndarray], bool] = lambda idx: False
    to_scan: np.ndarray | None = None
    note: str = ""
    hint: str = ""


def search_board(
    scan: SearchInput,
    board: Board,
    options: LidarOptions,
    rng: np.random.Generator,
    accept: Callable[[list[Candidate]], bool] | None = None,
    in_roi: bool = False,
) -> list[Candidate]:
    """Every piece that passes the chessboard tests; raise BoardNotFound with the reason if none.

    The objects are tested as they are; only when ``accept`` (given the new candidates) says no, the
    over-merged ones are split, smallest first, and ``accept`` is asked again after each. Without
    ``accept`` the first candidates found are taken. in_roi: the search was limited to board.roi.
    """
    search = _Search(scan, board, options, rng, accept)
    for obj in scan.objects:
        search.test(obj, 0)
    # only when no object passed as it is (or none of them was accepted): split the over-merged
    # ones, smallest first: a board merged with a hand or its stand is cheap to split; the room last
    done = search.offer()
    for obj in sorted(search.to_split, key=len):
        if done:
            break
        search.split(obj)
        done = search.offer()
    if not search.out:
        raise search.not_found(in_roi)
    return search.out


class _Search:
    """One scan's search (``search_board``): the pieces tested so far, what passed (uniformity,
    members, contrast), what failed ((size, test, detail)), the objects to split, the plane fits
    left for the whole scan and the candidates offered."""

    def __init__(
        self,
        scan: SearchInput,
        board: Board,
        options: LidarOptions,
        rng: np.random.Generator,
        accept: Callable[[list[Candidate]], bool] | None,
    ) -> None:
        self.scan, self.options, self.rng, self.accept = scan, options, rng, accept
        x0, x1, y0, y1 = board.extent()
        self.long_side, self.short_side = x1 - x0, y1 - y0
        self.diag = float(np.hypot(x1 - x0, y1 - y0))
        self.passed: list[tuple[float, np.ndarray, float]] = []
        self.misses: list[tuple[int, str, str, bool]] = []  # (size, test, detail, larger than a board)
        self.to_split: list[np.ndarray] = []
        self.tested = 0
        self.cut = 0  # board-sized objects at the field's top or lowest beam with too few returns
        self.budget = options.max_planes * 6  # plane fits for the whole scan
        self.out: list[Candidate] = []

    def min_count(self, idx: np.ndarray) -> float:
        return self.options.count_ratio[0] * self.scan.n_theory(idx)

    def test(self, idx: np.ndarray, depth: int) -> None:
        """Test the piece ``idx`` (depth 0: an object as found, 1: a piece of a split one, 2: a
        trimmed piece); a failed depth-1 piece is trimmed and tested again."""
        scan, options, p = self.scan, self.options, self.scan.points
        span = float(np.linalg.norm(np.ptp(p[idx], axis=0)))
        if span < options.size_ratio[0] * self.short_side or idx.size < max(MIN_PIECE, options.min_points):
            return
        short = idx.size < self.min_count(idx)
        if short or not scan.admit(idx):
            self._cut_by_field(idx, depth, span, short and scan.admit(idx))
            return
        self.tested += 1
        ok, uni, name, detail = scan.tests(idx)
        if not ok and name in ("count", "size"):
            self._cut_by_field(idx, depth, span, idx.size < self.scan.n_theory(idx))
        if ok:
            _, _, inl = scan.plane_fn(p[idx], scan.threshold, self.rng)
            if inl.mean() >= 0.9:
                self.passed.append((uni, idx[inl], intensity_contrast(scan.intensity[idx[inl]])[0]))
                return
            name = "plane"
            detail = f"not one plane, {detail} " + breach(
                f"returns within {1e3 * scan.threshold:.0f} mm of a RANSAC plane", inl.mean(), "<", 0.9
            )
        if depth >= 1 and name in TRIMMABLE:
            for kept in scan.trims(idx, depth):
                if depth == 1 and MIN_PIECE <= kept.size < idx.size:
                    n_pass = len(self.passed)
                    self.test(kept, 2)
                    if len(self.passed) > n_pass:
                        return
        self.misses.append((idx.size, name, detail, span > options.size_ratio[1] * self.diag))
        if depth == 0 and span >= options.size_ratio[0] * self.diag:
            self.to_split.append(idx)

    def _cut_by_field(self, idx: np.ndarray, depth: int, span: float, short: bool) -> None:
        """Count an object as found (depth 0) that reaches the top or lowest beam of the field, no
        larger than the board and ``short`` of a whole board's returns: the field may cut it."""
        if depth == 0 and short and span <= self.diag and self.scan.at_edge(idx):
            self.cut += 1

    def split(self, idx: np.ndarray) -> None:
        """Peel planes off an over-merged object: each plane's inliers are cut into connected pieces
        and tested; what is left is cut into connected pieces again (the ground gone, a board on a
        pole comes apart from it) and those are tested or split in turn."""
        scan, options, p = self.scan, self.options, self.scan.points
        idx = np.sort(idx)
        queue = [(idx, scan.links(idx))]
        own = options.max_planes * 3
        n_before = len(self.passed)
        while queue and self.budget > 0 and own > 0 and len(self.passed) == n_before:
            own -= 1
            # smallest first: the floor and walls are big, a board with a pole or an arm is not
            queue.sort(key=lambda t: -len(t[0]))
            cur, links = queue.pop()
            if cur.size < MIN_PIECE:
                continue
            self.budget -= 1
            _, _, inl = scan.plane_fn(p[cur], scan.threshold, self.rng)
            if inl.sum() < MIN_PIECE:
                continue
            pieces = scan.pieces(cur[inl], links)
            if (again := self._one_surface(cur, inl, pieces)) is not None:
                inl, pieces = again, scan.pieces(cur[again], links)
                # the plane's other pieces may be bands of a surface near the largest (a board a few
                # degrees off the plane of the body before it): what is left with them is tested too
                big = max(pieces, key=lambda t: t[0].size)[0]
                for piece, _ in scan.pieces(cur[~np.isin(cur, big, assume_unique=True)], links):
                    span = float(np.linalg.norm(np.ptp(p[piece], axis=0)))
                    if piece.size >= MIN_PIECE and span < 2.0 * self.diag:
                        self.test(piece, 1)
            for piece, _ in pieces:
                self.test(piece, 1)
            rest = cur[~inl]
            rest_pieces = [t for t in scan.pieces(rest, links) if t[0].size >= MIN_PIECE] if rest.size else []
            for piece, piece_links in rest_pieces:
                size = float(np.linalg.norm(np.ptp(p[piece], axis=0)))
                if size < 2.0 * self.diag:
                    self.test(piece, 1)  # small enough to be judged (and trimmed) directly
                if size >= options.size_ratio[0] * self.diag and piece.size >= max(
                    self.min_count(piece), options.min_points
                ):
                    queue.append((piece, piece_links))  # big enough, with returns enough, for a board
            if len(self.passed) == n_before:
                self._regrow(cur, links, [t[0] for t in pieces + rest_pieces])

    def _regrow(self, cur: np.ndarray, links: Any, pieces: list[np.ndarray]) -> None:
        """Test the whole surface of each piece too short for a board (indices into the scan's points,
        of the object ``cur``): another surface's plane (the body of the person holding the board,
        at a few degrees to it) takes a band across the board, leaving pieces either side that are
        short of a board's returns. Only a piece that shows a print (``print_visible`` at
        ``print_contrast_min``) is grown: its own plane (least squares) gathers the returns of ``cur``
        on it, and their connected piece holding most of the seed is tested, once per surface. (Grown
        from any piece, the faces of a person's body or a box pass the tests of a board whose print
        the LiDAR does not show.)"""
        p, options = self.scan.points, self.options
        seen: set[tuple[int, int]] = set()
        for seed in pieces:
            span = float(np.linalg.norm(np.ptp(p[seed], axis=0)))
            if seed.size >= self.min_count(seed) or span < options.size_ratio[0] * self.short_side:
                continue
            if not print_visible(self.scan.intensity[seed], p[seed], options.print_contrast_min)[0]:
                continue
            on = cur[self._on_plane_of(seed, cur)]
            if on.size <= seed.size:
                continue
            on_pieces = self.scan.pieces(on, links)
            if not on_pieces:
                continue
            grown = max(on_pieces, key=lambda t: np.isin(t[0], seed).sum())[0]
            key = (int(grown[0]), int(grown.size))
            if grown.size <= seed.size or key in seen:
                continue
            seen.add(key)
            n_pass = len(self.passed)
            self.test(grown, 1)
            if len(self.passed) > n_pass:
                return

    def _one_surface(
        self, cur: np.ndarray, inl: np.ndarray, pieces: list[tuple[np.ndarray, Any]]
    ) -> np.ndarray | None:
        """The inliers of ``cur`` (indices) to the plane of the largest piece of a plane's inliers
        ``inl`` (mask) when those fell apart (the largest less than ``ONE_SURFACE`` of them): a plane
        that cuts through two nearby surfaces (a board and the body of the person holding it, a few
        cm before it) can hold more returns than either; None when the plane was one surface."""
        if not pieces:
            return None
        big = max(pieces, key=lambda t: t[0].size)[0]
        if big.size >= ONE_SURFACE * inl.sum() or big.size < MIN_PIECE:
            return None
        again = self._on_plane_of(big, cur)
        return again if again.sum() >= MIN_PIECE else None

    def _on_plane_of(self, piece: np.ndarray, cur: np.ndarray) -> np.ndarray:
        """(len(cur),) bool: the returns ``cur`` (indices) within the inlier distance of the
        least-squares plane of ``piece`` (indices; a piece of one surface, so no RANSAC)."""
        p = self.scan.points
        mu = p[piece].mean(axis=0)
        n = np.linalg.svd(p[piece] - mu, full_matrices=False)[2][2]
        return np.abs((p[cur] - mu) @ n) < self.scan.threshold

    def offer(self) -> bool:
        """Turn the new passes into Candidates; True when the caller accepts them (stop searching)."""
        scan, p = self.scan, self.scan.points
        new: list[Candidate] = []
        for uni, members, sep in self.passed[len(self.out) :]:
            loc = np.unique(members)
            q = p[loc]
            n, d, _ = scan.plane_fn(q, scan.threshold, self.rng)
            if n @ q.mean(axis=0) > 0:  # normal towards the sensor
                n, d = -n, -d
            idx = loc if scan.to_scan is None else scan.to_scan[loc]
            new.append(Candidate(idx, n, float(d), float(uni), scan.sigma, self.tested, float(sep)))
        self.out.extend(new)
        if not new:
            return False
        return True if self.accept is None else bool(self.accept(new))

    def not_found(self, in_roi: bool) -> BoardNotFound:
        """Why no candidate was found: no object of board size, or the largest board-sized ones that
        failed (then larger ones) and why; and how many board-sized objects at the field's top or
        lowest beam had too few returns."""
        n = self.cut
        cut = (
            f" {n} board-sized object{'s' if n > 1 else ''} at the top or lowest beam of the LiDAR's field "
            f"{'have' if n > 1 else 'has'} too few returns for a whole board: if the board is one, the field "
            "cuts it (a cut board is not used); hold it whole within the beams (farther away, or nearer "
            "the LiDAR's height)."
            if n else ""
        )  # fmt: skip
        if not self.misses:
            return BoardNotFound(
                f"no object of board size ({self.long_side:.2f} x {self.short_side:.2f} m) in the scan"
                + (" inside the region of interest" if in_roi else "") + ("." + cut if cut else "")
            )
        # the board-sized first (a room the board merged with is tested too, and says little), largest first
        misses = sorted(self.misses, key=lambda t: (t[3], -t[0]))
        near = "; ".join(f"{name}: {detail}" for _, name, detail, _ in misses[:3])
        return BoardNotFound(
            f"no segment passed the chessboard tests ({self.tested} board-sized candidates{self.scan.note}); "
            f"largest: {near}.{cut} If the board is in view, narrow the search with board.roi "
            f"(azimuth_deg, elevation_deg, range_m){self.scan.hint}."
        )
