"""Variance components of the boards' random planes and beam offsets (``board_plane_estimate``).

Each board's returns carry a random plane (offset, two tilts; sigmas ``board_plane``) marginalised in
their whitening (``factors.BoardPointsFactor``). Made explicit, the plane is three parameters per
board with a zero-mean prior as pseudo-observations. Foerstner's variance components of those
pseudo-observations, one for the offsets and one for the tilts per noise group, estimate the plane's
sigmas from how far each board's returns lie from the plane the whole graph gives the board (its
image corners through the extrinsic, the other boards through the LiDAR's shared terms). In the
marginalised form the same numbers come from the virtual rows ``Z^T`` of
``BoardPointsFactor.plane_rows`` (``linear.redundancies``, ``extra``): the offsets' chi-square is
``sum |Z_o^T r|^2`` over the boards, their redundancy ``sum trace(Z_o^T Z_o) - trace(N^-1 A^T Z_o
Z_o^T A)``; the returns' own component then takes the remainder of the rows' chi-square and
redundancy. Each update (a Fisher-scoring step, ``components``) runs with the other components; the
scale stays between the floor (a plane never taken as ideal: near zero the estimate is ill-posed)
and the maximum, relative to the configured sigmas. With fewer than ``board_plane_min_boards`` boards,
or a redundancy below one half, the configured sigmas stay, and ``BoardPlane.note`` says so. The
random range offset of each beam on each board (``LidarErrorOptions.board_beam``) is a third random
effect in the same whitening and gets its component the same way.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ilcc_graph.estimation.assembly import Assembly, Term
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.linear import Extra

log = logging.getLogger(__name__)

__all__ = [
    "KINDS",
    "BoardPlane",
    "at_floor",
    "board_plane",
    "components",
    "estimated",
    "extra_rows",
    "log_sigmas",
    "split_points",
]

#: the variance components of the boards' planes (offset, tilt) and beams' offsets, per noise group
KINDS = ("plane_offset", "plane_tilt", "board_beam")
#: an estimated plane offset sigma above this (m) is more than a bent print: the boards' returns sit
#: off where the images put the boards (a range error per board, the camera's intrinsics; see
#: docs/bench_lidar_errors.md finding 9), and the solution says so
SUSPECT_OFFSET_M = 0.015
SUSPECT_NOTE = (
    "offset {mm:.0f} mm is more than a bent print: the boards' returns sit off where the images put "
    "them (a range error per board, or the camera's intrinsics); compare with the result of "
    "--sensor-model none"
)


@dataclass(frozen=True)
class BoardPlane:
    """The boards' plane sigmas the solve used: offset (m) and tilt (rad), and the beams' offset on
    each board (m, nan without that term), each with its standard deviation when estimated (``sigma
    / sqrt(2 r)``, r the redundancy; nan when not), ``estimated`` and a note (why the configured
    value stayed, or that a bound held it)."""

    offset_m: float
    tilt_rad: float
    offset_sd: float = math.nan
    tilt_sd: float = math.nan
    estimated: bool = False
    note: str = ""
    beam_m: float = math.nan
    beam_sd: float = math.nan


def _bounds(options: LidarErrorOptions, j: int) -> tuple[float, float, float] | None:
    """(configured, floor, maximum) sigma of random effect ``KINDS[j]``, or None when it is off."""
    if j < 2:
        if options.board_plane is None:
            return None
        return options.board_plane[j], options.board_plane_floor[j], options.board_plane_max[j]
    if options.board_beam is None:
        return None
    return options.board_beam, options.board_beam_floor, options.board_beam_max


def at_floor(options: LidarErrorOptions | None, key: tuple[str, str], scale: float) -> bool:
    """Is the component ``key`` (a kind of ``KINDS``, a group) held at its floor (not estimated)?"""
    b = None if options is None else _bounds(options, KINDS.index(key[0]))
    return b is None or scale <= (b[1] / b[0]) ** 2 * 1.0001


def estimated(options: LidarErrorOptions | None, asm: Assembly, boards: Sequence[int]) -> set[str]:
    """The noise groups whose planes' components are estimated for these boards (those with at least
    ``board_plane_min_boards`` boards with returns; empty when not estimated)."""
    if options is None or not options.board_plane_estimate:
        return set()
    if options.board_plane is None and options.board_beam is None:
        return set()
    count: dict[str, int] = {}
    for i in boards:
        if i in asm.points:
            g = asm.problem.boards[i].group
            count[g] = count.get(g, 0) + 1
    return {g for g, n in count.items() if n >= options.board_plane_min_boards}


def extra_rows(asm: Assembly, comps: Mapping[tuple[str, str], float], groups: set[str]) -> Extra:
    """``linear.Extra`` of the boards' planes of ``groups`` in the graph ``asm.graph(boards, comps)``."""

    def rows(k: int, t: Term) -> tuple[tuple[str, int, int, np.ndarray], ...]:
        if t.board is None or t.board not in asm.points or not t.parts or t.group not in groups:
            return ()
        z = asm.points_factor(t.board, comps).plane_rows()
        if z is None:
            return ()
        _, a0, a1 = t.parts[0]
        return tuple((kind, a0, a1, zk) for kind, zk in zip(KINDS, z, strict=True) if zk is not None)

    return rows


def split_points(ratios: Mapping[tuple[str, str], tuple[float, float]]) -> dict:
    """The redundancies with each group's plane chi-squares and redundancies taken from its returns'
    (the returns' own noise is then what remains: the explicit model's split)."""
    out = dict(ratios)
    for (kind, g), (c2, r) in ratios.items():
        if kind in KINDS and ("points", g) in out:
            pc, pr = out[("points", g)]
            out[("points", g)] = (pc - c2, pr - r)
    return out


def components(
    ratios: Mapping[tuple[str, str], tuple[float, float]],
    comps: Mapping[tuple[str, str], float],
    options: LidarErrorOptions,
    information: Mapping[tuple[str, str], float] | None = None,
) -> dict[tuple[str, str], float]:
    """The updated plane components within their bounds (``r <= 0.5``: unchanged).

    A Fisher-scoring step of the REML likelihood in the scale t (now 1): ``t = 1 + (chi2 - r) / I``
    with ``I = sum ||Z^T P Z||^2`` (``linear.redundancies``, ``information``), at most 10x either
    way. Foerstner's ``s chi2 / r`` is the same step where each board's plane is well determined
    (``Z^T P Z`` near 1), and creeps where the boards tell it weakly (an EM step); without
    ``information`` that step is taken."""
    out = {}
    for (kind, g), (c2, r) in ratios.items():
        if kind not in KINDS:
            continue
        s0, floor, top = _bounds(options, KINDS.index(kind))  # type: ignore[misc]
        lo, hi = (floor / s0) ** 2, (top / s0) ** 2
        s = comps.get((kind, g), 1.0)
        if r <= 0.5:
            out[(kind, g)] = s
            continue
        info = (information or {}).get((kind, g), 0.0)
        t = 1.0 + (c2 - r) / info if info > 0.0 else c2 / r
        out[(kind, g)] = min(hi, max(lo, s * min(10.0, max(0.1, t))))
    return out


def board_plane(
    options: LidarErrorOptions | None,
    scales: Mapping[tuple[str, str], float],
    redundancy: Mapping[tuple[str, str], float],
    n_boards: int,
    group: str = "",
) -> BoardPlane | None:
    """The plane (and beam) sigmas of ``group``'s boards (``n_boards`` with returns in the graph), or
    None without a board plane or beam term."""
    if options is None or (options.board_plane is None and options.board_beam is None):
        return None
    so, st = options.board_plane if options.board_plane is not None else (math.nan, math.nan)
    sb = options.board_beam if options.board_beam is not None else math.nan
    if not options.board_plane_estimate:
        return BoardPlane(so, st, note="configured", beam_m=sb)
    on = [j for j in range(len(KINDS)) if _bounds(options, j) is not None]
    if not all((KINDS[j], group) in scales for j in on):
        why = (
            f"{n_boards} board(s) with returns, fewer than {options.board_plane_min_boards}"
            if n_boards < options.board_plane_min_boards
            else "the boards hardly tell it (redundancy <= 0.5)"
        )
        return BoardPlane(so, st, note=f"configured sigmas kept: {why}", beam_m=sb)
    sig, sds, notes = [so, st, sb], [math.nan] * 3, []
    for j in on:
        s0, floor, top = _bounds(options, j)  # type: ignore[misc]
        s = scales[(KINDS[j], group)]
        r = redundancy.get((KINDS[j], group), 0.0)
        sig[j] = s0 * math.sqrt(s)
        sds[j] = sig[j] / math.sqrt(2.0 * r) if r > 0.5 else math.nan
        lo, hi = (floor / s0) ** 2, (top / s0) ** 2
        if s <= lo * 1.0001 or s >= hi * 0.9999:
            notes.append(
                f"{('offset', 'tilt', 'beams')[j]} at its {'floor' if s <= lo * 1.0001 else 'maximum'}"
            )
    if math.isfinite(sig[0]) and sig[0] > SUSPECT_OFFSET_M and 0 in on:
        notes.append(SUSPECT_NOTE.format(mm=1e3 * sig[0]))
    return BoardPlane(sig[0], sig[1], sds[0], sds[1], True, "; ".join(notes), sig[2], sds[2])


def log_sigmas(options: LidarErrorOptions | None, bp: BoardPlane | None) -> None:
    """Say the boards' plane sigmas when they were to be estimated (found, or why configured; at
    info level: every candidate model's solve says it)."""
    if bp is None or options is None or not options.board_plane_estimate:
        return
    parts = []
    if math.isfinite(bp.offset_m):
        parts.append(f"plane offset {1e3 * bp.offset_m:.2f} mm, tilt {math.degrees(bp.tilt_rad):.3f} deg")
    if math.isfinite(bp.beam_m):
        parts.append(f"beams {1e3 * bp.beam_m:.2f} mm")
    # a suspect offset is in the note; the run prints the chosen model's (report.sensors), not every
    # candidate's: a model the choice leaves out must not warn about what it alone estimated
    log.info("boards' random effects' sigmas: %s%s", ", ".join(parts), f" ({bp.note})" if bp.note else "")
