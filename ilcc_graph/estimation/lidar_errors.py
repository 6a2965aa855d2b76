"""The LiDAR's own errors as variables shared by every board: which terms, and their layout.

A LiDAR's parameter vector ``L(l)`` holds, in this order (each part optional):

- ``offset[b]``: the range offset of beam b (measured minus true range, metres);
- ``offset``: one range offset for all beams (what ``--range-offset`` estimated), when the
  per-beam offsets are off;
- ``dark``: the extra range of returns from black print (a weak return reads long), metres;
- ``scale``: a range scale error (measured = true * (1 + scale));
- ``elevation[b]``: the elevation error of beam b (measured minus true, rad).

A scanline-free LiDAR's returns all carry the pseudo-beam 0 (``lidar/ringless.py``): ``offset[0]`` is
its one laser's range offset and it gets no elevation term (a constant elevation error of every
return is a rotation of the sensor: the extrinsic's).

A return j of beam b on print of darkness w at range rho has the range error
``offset[b] + w dark + rho scale`` and the elevation error ``elevation[b]`` (``factors.BoardPointsFactor``).
Every term has a weak zero-mean prior (the plausible size of such an error). A beam enters only
when the boards hold enough of its returns; a term the boards cannot determine (its variance
barely shrinks below its prior's) is left out and said so (``noise.solve_problem``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ilcc_graph.types import BoardReturns

__all__ = ["LidarErrorOptions", "LidarLayout", "errors_entry", "layout_for", "merge_layouts"]


@dataclass(frozen=True)
class LidarErrorOptions:
    """Which of the LiDAR's own errors the graph estimates, with their priors (one sigma).

    beam_offsets, global_offset, dark_offset, range_scale, beam_elevations: the terms (see the
    module docstring); ``global_offset`` is used only when ``beam_offsets`` is off.
    min_points_per_beam, min_boards_per_beam: a beam's terms enter only with at least this many
    returns over at least this many boards.
    max_points_per_board: returns per board given to the graph (an even subsample beyond).
    board_plane: (offset m, tilt rad) one sigma of each board's own deviation from the ideal plane
        of its returns (print and backing bend; LiDAR errors no term models), or None for none
        (``factors.BoardPointsFactor``, plane_sigma).
    observable_ratio: a term is left out when the boards shrink its prior variance to no less than
        this fraction of it (the data hardly tell it).
    board_plane_estimate: estimate the board plane's offset and tilt sigmas from the boards (two
        variance components of the random plane, ``estimation/plane.py``), starting from
        ``board_plane``, kept within [``board_plane_floor``, ``board_plane_max``]; with fewer than
        ``board_plane_min_boards`` boards the configured sigmas stay (and the solution says so).
        False: ``board_plane`` fixed (docs/bench_lidar_errors.md compares the two).
    board_beam: one sigma (m) of a random range offset of each beam on each board (a beam's error
        that changes from board to board), or None for none; estimated with the plane's (a third
        variance component, within [``board_beam_floor``, ``board_beam_max``]) or fixed likewise.
    """

    beam_offsets: bool = True
    global_offset: bool = False
    dark_offset: bool = True
    range_scale: bool = False
    beam_elevations: bool = False
    prior_offset_m: float = 0.05
    prior_dark_m: float = 0.05
    prior_scale: float = 0.01
    prior_elevation_rad: float = 0.005
    min_points_per_beam: int = 40
    min_boards_per_beam: int = 2
    max_points_per_board: int = 1200
    board_plane: tuple[float, float] | None = (0.005, 0.007)
    observable_ratio: float = 0.5
    board_plane_estimate: bool = True
    board_plane_floor: tuple[float, float] = (0.0005, 0.0007)
    board_plane_max: tuple[float, float] = (0.04, 0.028)
    board_plane_min_boards: int = 5
    board_beam: float | None = 0.002
    board_beam_floor: float = 0.0002
    board_beam_max: float = 0.02

    def __post_init__(self) -> None:
        for name in ("prior_offset_m", "prior_dark_m", "prior_scale", "prior_elevation_rad"):
            if not getattr(self, name) > 0:
                raise ValueError(f"LidarErrorOptions.{name} must be > 0, got {getattr(self, name)!r}")
        given: Sequence[float] | None = self.board_plane  # as the caller gave it: any length
        if given is not None and not (len(given) == 2 and min(given) > 0):
            raise ValueError(
                f"LidarErrorOptions.board_plane must be two sigmas > 0 or None, got {self.board_plane!r}"
            )
        if self.board_plane_estimate and self.board_plane is not None:  # (no plane: nothing to estimate)
            lo, hi = self.board_plane_floor, self.board_plane_max
            if not all(0 < a <= b <= c for a, b, c in zip(lo, self.board_plane, hi, strict=True)):
                raise ValueError(
                    "LidarErrorOptions: need 0 < board_plane_floor <= board_plane <= board_plane_max, got "
                    f"{lo!r}, {self.board_plane!r}, {hi!r}"
                )
        if self.board_beam is not None and not (
            0 < self.board_beam_floor <= self.board_beam <= self.board_beam_max
        ):
            raise ValueError(
                "LidarErrorOptions: need 0 < board_beam_floor <= board_beam <= board_beam_max, got "
                f"{self.board_beam_floor!r}, {self.board_beam!r}, {self.board_beam_max!r}"
            )
        if not 0.0 < self.observable_ratio < 1.0:
            raise ValueError(
                f"LidarErrorOptions.observable_ratio must be in (0, 1), got {self.observable_ratio!r}"
            )

    @property
    def any(self) -> bool:
        return (
            self.beam_offsets
            or self.global_offset
            or self.dark_offset
            or self.range_scale
            or self.beam_elevations
        )


@dataclass(frozen=True)
class LidarLayout:
    """Which entry of one LiDAR's parameter vector is which.

    beams: beams with an offset (ascending); global_offset, dark, scale: whether those entries are
    there; elevations: beams with an elevation error. excluded: (term, reason) left out.
    """

    beams: tuple[int, ...] = ()
    global_offset: bool = False
    dark: bool = False
    scale: bool = False
    elevations: tuple[int, ...] = ()
    priors: tuple[float, float, float, float] = (0.05, 0.05, 0.01, 0.005)
    excluded: tuple[tuple[str, str], ...] = field(default=())

    @property
    def names(self) -> list[str]:
        out = [f"offset[{b}]" for b in self.beams]
        out += ["offset"] * self.global_offset + ["dark"] * self.dark + ["scale"] * self.scale
        return out + [f"elevation[{b}]" for b in self.elevations]

    @property
    def units(self) -> list[str]:
        """Each term's unit, in ``names`` order: ``m`` (range offsets), ``1`` (scale), ``rad``
        (elevations)."""
        n_m = len(self.beams) + self.global_offset + self.dark
        return ["m"] * n_m + ["1"] * self.scale + ["rad"] * len(self.elevations)

    @property
    def dim(self) -> int:
        return len(self.names)

    def prior_sigmas(self) -> np.ndarray:
        """(dim,) the priors' sigmas (metres, -, rad as each term's unit)."""
        off, dark, scale, elev = self.priors
        s = [off] * len(self.beams) + [off] * self.global_offset + [dark] * self.dark + [scale] * self.scale
        return np.array(s + [elev] * len(self.elevations), dtype=np.float64)

    def without(self, names: Sequence[str], reason: str) -> LidarLayout:
        """The layout with the terms ``names`` left out, each with ``reason``."""
        drop = set(names)
        beams = tuple(b for b in self.beams if f"offset[{b}]" not in drop)
        elev = tuple(b for b in self.elevations if f"elevation[{b}]" not in drop)
        return replace(
            self, beams=beams, elevations=elev, global_offset=self.global_offset and "offset" not in drop,
            dark=self.dark and "dark" not in drop, scale=self.scale and "scale" not in drop,
            excluded=self.excluded + tuple((n, reason) for n in names),
        )  # fmt: skip

    def terms(
        self, r: BoardReturns, rho: np.ndarray, keep: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """For the returns ``r`` (rows ``keep``): range_index, range_coef (M, k) and
        elevation_index, elevation_coef (M, 1), or None for the latter without elevation terms."""
        ring, dark = np.asarray(r.ring)[keep], np.asarray(r.dark, dtype=np.float64)[keep]
        M = len(ring)
        idx, coef = [], []
        pos = {b: i for i, b in enumerate(self.beams)}
        k = len(self.beams)
        if self.beams:
            has = np.isin(ring, self.beams)
            idx.append(np.where(has, [pos.get(int(b), 0) for b in ring], 0))
            coef.append(has.astype(np.float64))
        if self.global_offset:
            idx.append(np.full(M, k))
            coef.append(np.ones(M))
            k += 1
        if self.dark:
            idx.append(np.full(M, k))
            coef.append(dark)
            k += 1
        if self.scale:
            idx.append(np.full(M, k))
            coef.append(rho)
            k += 1
        if not idx:
            idx, coef = [np.zeros(M, np.int64)], [np.zeros(M)]
        range_index, range_coef = np.column_stack(idx).astype(np.int64), np.column_stack(coef)
        if not self.elevations:
            return range_index, range_coef, None, None
        epos = {b: k + i for i, b in enumerate(self.elevations)}
        has = np.isin(ring, self.elevations)
        e_idx = np.where(has, [epos.get(int(b), k) for b in ring], k)[:, None].astype(np.int64)
        return range_index, range_coef, e_idx, has.astype(np.float64)[:, None]


def layout_for(returns: Sequence[BoardReturns], options: LidarErrorOptions) -> LidarLayout:
    """The layout of one LiDAR from the returns of its boards: beams with enough returns on enough
    boards get their terms; the others are excluded with the reason."""
    excluded: list[tuple[str, str]] = []
    counts: dict[int, int] = {}
    boards: dict[int, int] = {}
    for r in returns:
        ring = np.asarray(r.ring)
        for b, n in zip(*np.unique(ring, return_counts=True), strict=True):
            counts[int(b)] = counts.get(int(b), 0) + int(n)
            boards[int(b)] = boards.get(int(b), 0) + 1
    good = tuple(
        sorted(
            b
            for b in counts
            if counts[b] >= options.min_points_per_beam and boards[b] >= options.min_boards_per_beam
        )
    )
    for b in sorted(set(counts) - set(good)):
        excluded.append(
            (f"beam {b}", f"{counts[b]} returns on {boards[b]} board(s): too few to estimate its terms")
        )
    # a scanline-free LiDAR (Livox) gives every return one pseudo-beam 0: its offset is the one laser's
    # range offset; an elevation term would turn every return alike, which the extrinsic already does
    one_beam = set(counts) <= {0}
    if options.beam_elevations and one_beam and good:
        excluded.append(("elevation[0]", "one pseudo-beam (a LiDAR without scanlines): no beam elevation"))
    any_dark = any(0.1 < float(np.mean(r.dark)) < 0.9 for r in returns)
    if options.dark_offset and not any_dark:
        excluded.append(("dark", "no board shows both black and white returns"))
    return LidarLayout(
        beams=good if options.beam_offsets else (),
        global_offset=options.global_offset and not options.beam_offsets,
        dark=options.dark_offset and any_dark,
        scale=options.range_scale,
        elevations=good if options.beam_elevations and not one_beam else (),
        priors=(
            options.prior_offset_m,
            options.prior_dark_m,
            options.prior_scale,
            options.prior_elevation_rad,
        ),
        excluded=tuple(excluded),
    )


def merge_layouts(layouts: Sequence[LidarLayout]) -> LidarLayout:
    """One LiDAR's layout in a joint problem from its layouts in the sessions solved alone: a term
    enters when it entered some session's (the same data twice determine no term that once did
    not); left out, with a session's reason, when it entered none. Each session brings the terms'
    prior: the joint's is that prior once per session (sigmas over sqrt(sessions)), so that the joint
    objective is the sum of the sessions' own and a session given twice is that session."""
    first = layouts[0]
    if len(layouts) == 1:
        return first
    entered = {n for lay in layouts for n in lay.names} | {f"beam {b}" for lay in layouts for b in lay.beams}
    out = {n: why for lay in reversed(layouts) for n, why in lay.excluded if n not in entered}
    k = math.sqrt(len(layouts))
    return replace(
        first,
        beams=tuple(sorted({b for lay in layouts for b in lay.beams})),
        global_offset=any(lay.global_offset for lay in layouts),
        dark=any(lay.dark for lay in layouts),
        scale=any(lay.scale for lay in layouts),
        elevations=tuple(sorted({b for lay in layouts for b in lay.elevations})),
        priors=tuple(p / k for p in first.priors),  # type: ignore[arg-type]
        excluded=tuple(out.items()),
    )


def errors_entry(
    estimate: tuple[Sequence[str], np.ndarray, np.ndarray] | None,
    layout: LidarLayout | None,
    covariance: np.ndarray | None = None,
    board_plane: dict[str, Any] | None = None,
    elevations_deg: Sequence[float] | np.ndarray | None = None,
) -> dict[str, Any]:
    """A LiDAR's own errors as ``Calibration.sensors['lidar_errors']`` and a rig's calibration.yaml
    hold them: ``names``, ``values``, ``sigmas`` (``estimate``; metres or none, as ``units`` from the
    layout say), the terms the layout left out (``left_out``: [term, reason]), the (n, n)
    ``covariance`` when given, each beam term's nominal elevation in deg (``elevation_deg``; beam
    index 0 = lowest) from ``elevations_deg``; {} when there is neither an estimate nor a term left
    out."""
    if estimate is None and (layout is None or not layout.excluded):
        return {}
    names, values, sigmas = estimate if estimate is not None else ([], np.zeros(0), np.zeros(0))
    left = [] if layout is None else [list(x) for x in layout.excluded]
    out: dict[str, Any] = {"names": list(names), "values": values, "sigmas": sigmas, "left_out": left}
    if layout is not None and estimate is not None:
        out["units"] = layout.units
    if covariance is not None:
        out["covariance"] = covariance
    if board_plane is not None:
        out["board_plane"] = board_plane
    if elevations_deg is not None:
        beams = {n: int(n[n.index("[") + 1 : -1]) for n in names if "[" in n}
        el = elevations_deg
        out["elevation_deg"] = {n: round(float(el[b]), 3) for n, b in beams.items() if b < len(el)}
    return out
