"""The closing verdict of a rig's calibration: GOOD, FAIR or POOR, and a line per sensor (no printing).

docs/rig.md, "The rig's verdict": the single pair's rule (``summary.verdict``) applied to every sensor
but the reference, with the worst sensors named and what would help; and one line per sensor for an
80-column terminal.

Per sensor: the moments whose observation entered the graph (``cal.extra["used"]``), the moments it
saw the board but its observation disagreed with the others' (the start's corner-order check or the
graph's chi-square gate dropped it; ``cal.extra["moments"]`` holds every reason), and the largest
1-sigma of its pose (rotation deg, translation mm; its 6x6 block of the joint covariance). A sensor
without a pose (``cal.extra["unsolved"]``) is POOR. The rig's verdict is its worst sensor's.
Plain strings.
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass

from ..errors import DISAGREEING
from ..io.rig_results import RigCalibration
from ..types import worst_sigmas
from .summary import MIN_FRAMES, NEED_DEG_MM, WIDTH

__all__ = [
    "DISAGREE",
    "NO_DATA",
    "USED",
    "SensorStanding",
    "fate_kind",
    "rig_sensors",
    "rig_verdict",
    "rig_verdict_lines",
    "sensor_standings",
]

#: the reason of an observation that entered the graph (``run.rig_calibrate.USED``)
USED = "used"
#: the reason of a sensor without a file at a moment (``run.rig_calibrate.fates``)
NO_DATA = "no data at this moment"
#: how the reasons of an observation that disagreed with the other sensors begin: the start's
#: corner-order check (``init.rig_start``) and the graph's chi-square gate (``estimation.gate``)
DISAGREE = DISAGREEING
_RANK = {"GOOD": 0, "FAIR": 1, "POOR": 2}


def fate_kind(reason: str) -> str:
    """What a (moment, sensor) reason says: ``used``, ``disagrees`` (seen, then dropped for not
    fitting the others), ``no data`` (no file), or ``not used`` (the stage found no board, the
    moment related nothing, the sensor has no pose...)."""
    if reason == USED:
        return "used"
    if reason == NO_DATA:
        return "no data"
    return "disagrees" if str(reason).startswith(DISAGREE) else "not used"


@dataclass(frozen=True)
class SensorStanding:
    """One sensor's part of the verdict: level (GOOD | FAIR | POOR), moments used, moments dropped
    for disagreeing, the largest 1-sigma of its pose (deg, mm; NaN without a pose), what is wrong
    (phrases) and what would help (``pose``: boards shared with a placed sensor; ``more``: more board
    poses; ``odd``: a look at the dropped moments)."""

    name: str
    level: str
    used: int
    disagree: int
    rot_deg: float
    mm: float
    problems: tuple[str, ...] = ()
    helps: tuple[str, ...] = ()


def rig_sensors(cal: RigCalibration) -> list[str]:
    """Every sensor of the rig in the rig file's order (the solved ones, then those without a pose)."""
    names = list((cal.rig or {}).get("sensors") or cal.sensors)
    names += [s for s in cal.sensors if s not in names]
    return names + [s for s in (cal.extra.get("unsolved") or {}) if s not in names]


def _standing(cal: RigCalibration, s: str, need: tuple[float, float]) -> SensorStanding:
    fates = [d[s] for d in (cal.extra.get("moments") or {}).values() if s in d]
    used_map = cal.extra.get("used") or {}
    k = int(used_map[s]) if s in used_map else sum(fate_kind(r) == "used" for r in fates)
    d = sum(fate_kind(r) == "disagrees" for r in fates)
    why = (cal.extra.get("unsolved") or {}).get(s)
    if why is not None or s not in cal.sensors:
        text = f"no pose ({why or 'not solved'})"
        return SensorStanding(s, "POOR", k, d, math.nan, math.nan, (text,), ("pose",))
    rot, mm = worst_sigmas(cal.block(s))
    problems, helps = [], set()
    if k < MIN_FRAMES:
        problems.append(f"only {k} moment{'s' * (k != 1)} used ({MIN_FRAMES} or more advised)")
        helps.add("more")
    if d > 0.25 * max(k + d, 1):
        problems.append(f"{d} of {k + d} moments with the board disagree beyond their noise")
        helps.add("odd")
    if not (rot <= need[0] and mm <= need[1]):  # also NaN: no uncertainty
        problems.append(
            f"1-sigma up to {rot:.3g} deg and {mm:.2g} mm, above the {need[0]:g} deg / {need[1]:g} mm needed"
        )
        helps.add("more")
    poor = k < 3 or d > 0.5 * max(k + d, 1) or not (rot <= 3 * need[0] and mm <= 3 * need[1])
    level = "GOOD" if not problems else "POOR" if poor else "FAIR"
    return SensorStanding(s, level, k, d, rot, mm, tuple(problems), tuple(sorted(helps)))


def sensor_standings(cal: RigCalibration, need: tuple[float, float] | None = None) -> list[SensorStanding]:
    """Every sensor but the reference, in the rig's order, judged (module docstring)."""
    need = NEED_DEG_MM if need is None else need
    return [_standing(cal, s, need) for s in rig_sensors(cal) if s != cal.reference]


def _help(worst: list[SensorStanding]) -> list[str]:
    """What would help the worst sensors, one phrase per kind of problem."""
    names = {h: [s.name for s in worst if h in s.helps] for h in ("pose", "more", "odd")}
    out = []
    if names["pose"]:
        out.append(
            f"boards that {', '.join(names['pose'])} and a sensor with a pose see at the same moment, at two "
            "or more moments (one shared moment cannot tell the board's half turn)"
        )
    if names["more"]:
        out.append(
            f"more board poses in view of {', '.join(names['more'])} and another sensor at once (near and "
            "far, tilted, across the field of view)"
        )
    if names["odd"]:
        out.append(
            f"a look at the moments dropped for {', '.join(names['odd'])} (each reason in the report's "
            "table of moments): a wrong camera model or beam table, a moved mount, moments out of sync"
        )
    return out


def rig_verdict(cal: RigCalibration, need: tuple[float, float] | None = None) -> tuple[str, str]:
    """(``GOOD`` | ``FAIR`` | ``POOR``, the verdict's text) of a rig's calibration.

    Per sensor but the reference, as ``summary.verdict`` for a pair: GOOD with at least
    ``MIN_FRAMES`` moments used, at most a quarter of the moments it saw the board dropped for
    disagreeing, and its pose's largest 1-sigma within ``need`` (deg, mm; default ``NEED_DEG_MM``);
    POOR with fewer than 3 moments used, more than half disagreeing, a 1-sigma above 3 x ``need``,
    or no pose; FAIR in between. The rig takes its worst sensor's level; the text names the sensors
    at that level and what would help, then what the verdict rests on."""
    need = NEED_DEG_MM if need is None else need
    st = sensor_standings(cal, need)
    level = max((s.level for s in st), key=_RANK.__getitem__, default="GOOD")
    if level == "GOOD":
        sure = [s for s in st if math.isfinite(s.rot_deg)]
        least = max(sure, key=lambda s: max(s.rot_deg / need[0], s.mm / need[1]), default=None)
        detail = (
            ""
            if least is None
            else f" (the least sure: {least.name}, {least.rot_deg:.3g} deg and {least.mm:.2g} mm)"
        )
        head = (
            f"GOOD: every sensor's pose in the frame of {cal.reference} rests on {MIN_FRAMES} or more "
            "moments that agree with the others and has its 1-sigma within "
            f"{need[0]:g} deg and {need[1]:g} mm{detail}."
        )
    else:
        worst = [s for s in st if s.level == level]
        head = f"{level}: " + "; ".join(f"{s.name}: {', '.join(s.problems)}" for s in worst) + "."
        fair = [s.name for s in st if s.level == "FAIR" and level == "POOR"]
        head += f" Also FAIR: {', '.join(fair)}." if fair else ""
        helps = _help(worst)
        head += (" Would help: " + "; ".join(helps) + ".") if helps else ""
    basis = (
        "per sensor the moments its observation entered the graph, the moments the start's corner-order "
        "check or the chi-square gate dropped it, and the largest 1-sigma of its pose (the graph's joint "
        "covariance)"
    )
    vf = float(cal.extra.get("variance_factor", 1.0) or 1.0)
    if vf > 1.5:
        basis += f"; the residuals are {vf:.2f} x the stated noise variance (the sigmas include it)"
    return level, f"{head}\n  Rests on: {basis}."


def rig_verdict_lines(cal: RigCalibration, need: tuple[float, float] | None = None) -> list[str]:
    """A line per sensor but the reference, at most ``WIDTH`` (80) columns: its level, the moments
    used and dropped for disagreeing, its pose's largest 1-sigma (deg, mm); under a sensor that is not
    GOOD, what is wrong (indented, wrapped)."""
    st = sensor_standings(cal, need)
    w = min(max([len(s.name) for s in st] + [6]), WIDTH - 44)
    lines = [f"{'sensor':<{w}}  verdict  used  dropped  1-sigma deg      mm"]
    for s in st:
        sig = "-" if not math.isfinite(s.rot_deg) else f"{s.rot_deg:.3f}"
        mm = "-" if not math.isfinite(s.mm) else f"{s.mm:.2f}"
        lines.append(f"{s.name:<{w}}  {s.level:<7}  {s.used:4d}  {s.disagree:7d}  {sig:>11}  {mm:>6}")
        for p in s.problems:
            lines += textwrap.wrap(p, WIDTH, initial_indent="  ", subsequent_indent="    ")
    return lines
