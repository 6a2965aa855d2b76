"""Variance components of the boards' random planes (``LidarErrorOptions.board_plane_estimate``).

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
or a redundancy below one half, the configured sigmas stay, and ``BoardPlane.note`` says so.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from ilcc_graph.estimation.assembly import Assembly
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.linear import Extra

log = logging.getLogger(__name__)

__all__ = [
    "KINDS",
    "BoardPlane",
    "board_plane",
    "components",
    "estimated",
    "extra_rows",
    "log_sigmas",
    "split_points",
]

#: the variance components of the boards' planes, per noise group
KINDS = ("plane_offset", "plane_tilt")


@dataclass(frozen=True)
class BoardPlane:
    """The boards' plane sigmas the solve used: offset (m) and tilt (rad), each with its standard
    deviation when estimated (``sigma / sqrt(2 r)``, r the redundancy; nan when not), ``estimated``
    and a note (why the configured value stayed, or that a bound held it)."""

    offset_m: float
    tilt_rad: float
    offset_sd: float = math.nan
    tilt_sd: float = math.nan
    estimated: bool = False
    note: str = ""


def estimated(options: LidarErrorOptions | None, asm: Assembly, boards: Sequence[int]) -> set[str]:
    """The noise groups whose planes' components are estimated for these boards (those with at least
    ``board_plane_min_boards`` boards with returns; empty when not estimated)."""
    if options is None or not options.board_plane_estimate or options.board_plane is None:
        return set()
    count: dict[str, int] = {}
    for i in boards:
        if i in asm.points:
            g = asm.problem.boards[i].group
            count[g] = count.get(g, 0) + 1
    return {g for g, n in count.items() if n >= options.board_plane_min_boards}


def extra_rows(asm: Assembly, comps: Mapping[tuple[str, str], float], groups: set[str]) -> Extra:
    """``linear.Extra`` of the boards' planes of ``groups`` in the graph ``asm.graph(boards, comps)``."""

    def rows(k: int, t) -> tuple:  # noqa: ANN001 - assembly.Term
        if t.board is None or t.board not in asm.points or not t.parts or t.group not in groups:
            return ()
        z = asm.points_factor(t.board, comps).plane_rows()
        if z is None:
            return ()
        _, a0, a1 = t.parts[0]
        return ((KINDS[0], a0, a1, z[0]), (KINDS[1], a0, a1, z[1]))

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
        j = KINDS.index(kind)
        lo = (options.board_plane_floor[j] / options.board_plane[j]) ** 2  # type: ignore[index]
        hi = (options.board_plane_max[j] / options.board_plane[j]) ** 2  # type: ignore[index]
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
    """The plane sigmas of ``group``'s boards (``n_boards`` with returns in the graph), or None
    without a board plane."""
    if options is None or options.board_plane is None:
        return None
    so, st = options.board_plane
    if not options.board_plane_estimate:
        return BoardPlane(so, st, note="configured")
    keys = [(k, group) for k in KINDS]
    if not all(k in scales for k in keys):
        why = (
            f"{n_boards} board(s) with returns, fewer than {options.board_plane_min_boards}"
            if n_boards < options.board_plane_min_boards
            else "the boards hardly tell it (redundancy <= 0.5)"
        )
        return BoardPlane(so, st, note=f"configured sigmas kept: {why}")
    sig, sds, notes = [], [], []
    for j, (k, s0) in enumerate(zip(keys, (so, st), strict=True)):
        s = scales[k]
        r = redundancy.get(k, 0.0)
        sig.append(s0 * math.sqrt(s))
        sds.append(sig[-1] / math.sqrt(2.0 * r) if r > 0.5 else math.nan)
        lo = (options.board_plane_floor[j] / s0) ** 2
        hi = (options.board_plane_max[j] / s0) ** 2
        if s <= lo * 1.0001 or s >= hi * 0.9999:
            notes.append(f"{('offset', 'tilt')[j]} at its {'floor' if s <= lo * 1.0001 else 'maximum'}")
    return BoardPlane(sig[0], sig[1], sds[0], sds[1], True, "; ".join(notes))


def log_sigmas(options: LidarErrorOptions | None, bp: BoardPlane | None) -> None:
    """Say the boards' plane sigmas when they were to be estimated (found, or why configured)."""
    if bp is None or options is None or not options.board_plane_estimate:
        return
    log.info(
        "boards' plane sigmas: offset %.2f mm, tilt %.3f deg%s",
        1e3 * bp.offset_m, math.degrees(bp.tilt_rad), f" ({bp.note})" if bp.note else "",
    )  # fmt: skip
