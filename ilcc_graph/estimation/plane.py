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
redundancy. Each update ``s <- s chi2 / r`` runs with the other components; the scale stays between
the floor (a plane never taken as ideal: near zero the estimate is ill-posed, the steps vanish) and
the maximum, relative to the configured sigmas. With fewer than ``board_plane_min_boards`` boards,
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
    history: dict[tuple[str, str], list[float]] | None = None,
) -> dict[tuple[str, str], float]:
    """The updated plane components ``s chi2 / r`` within their bounds (``r <= 0.5``: unchanged).

    history: per component the log-scales of the updates so far (appended to). The update converges
    geometrically, and slowly where the boards tell the plane weakly (an EM step: the step shrinks
    with the plane's share of the information); three updates the same way with shrinking steps
    are extrapolated to their limit (Aitken's delta-squared on the log-scales, at most 10x)."""
    out = {}
    for (kind, g), (c2, r) in ratios.items():
        if kind not in KINDS:
            continue
        j = KINDS.index(kind)
        lo = math.log((options.board_plane_floor[j] / options.board_plane[j]) ** 2)  # type: ignore[index]
        hi = math.log((options.board_plane_max[j] / options.board_plane[j]) ** 2)  # type: ignore[index]
        s = comps.get((kind, g), 1.0)
        if r <= 0.5:
            out[(kind, g)] = s
            continue
        x = min(hi, max(lo, math.log(s * max(c2, 1e-12) / r)))
        past = history.setdefault((kind, g), [math.log(s)]) if history is not None else [math.log(s)]
        if len(past) >= 2:
            d0, d1 = past[-1] - past[-2], x - past[-1]
            rho = d1 / d0 if d0 != 0.0 else 0.0
            if 0.0 < rho < 0.95:
                x += max(-math.log(10.0), min(math.log(10.0), d1 * rho / (1.0 - rho)))
                x = min(hi, max(lo, x))
        past.append(x)
        out[(kind, g)] = math.exp(x)
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
