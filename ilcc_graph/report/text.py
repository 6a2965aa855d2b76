"""What the command line prints: tables and lines as plain strings (no printing here; the closing
summary of ``calibrate`` is ``summary``)."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence

from ..lidar.margin import margin_words
from ..lidar.outline import BEYOND_FOV_SHARE
from ..types import BoardFit, Calibration, sigmas_deg_mm

__all__ = [
    "STAGE_HEADERS",
    "evaluation_text",
    "failure_table",
    "format_joint",
    "format_table",
    "lidar_frame_note",
    "lidar_view_lines",
    "short_reason",
    "stage_table",
]

#: the columns of the stage commands' tables (rows from ``outputs.write_stage``)
STAGE_HEADERS = {
    "lidar": ("frame", "found", "points", "reason"),
    "image": ("frame", "found", "detector", "sigma px", "reason"),
}


def format_table(rows: Sequence[Sequence[object]], header: Sequence[str], width: int = 80) -> str:
    """Left-aligned columns with a rule under the header; the last column (a reason, as long as it
    needs) wrapped to ``width`` columns below its own start, its rule no wider than that."""
    cells = [[str(c) for c in header]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    start = sum(w + 2 for w in widths[:-1])
    room = max(width - start, len(cells[0][-1]), 20)
    widths[-1] = min(widths[-1], room)
    lines = []
    for j, r in enumerate(cells):
        last = textwrap.wrap(r[-1], room, break_long_words=True) or [""]
        head = "  ".join(c.ljust(w) for c, w in zip(r[:-1], widths[:-1]))
        lines.append(f"{head}  {last[0]}".rstrip() if r[:-1] else last[0])
        lines += [" " * start + more for more in last[1:]]
        if j == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _sig(e: dict) -> str:
    s = sigmas_deg_mm(e["covariance"])
    return " ".join(f"{v:.3f}" for v in s[:3]) + "  |  " + " ".join(f"{v:.2f}" for v in s[3:])


def format_joint(joint: dict) -> str:
    """Sessions: sigmas (deg | mm) of each estimate, the consistency tests, the verdict; from the
    sessions' ``joint.yaml`` document (``run.strategies.solve_sessions.joint_summary``)."""
    lines = [f"joint calibration ({joint['mode']}), sigma rx ry rz [deg] | tx ty tz [mm]:"]
    lines.append(f"  {'joint':<18s} {_sig(joint['joint'])}")
    for n in joint["alone"]:
        lines.append(f"  {n + ' alone':<18s} {_sig(joint['alone'][n])}")
        if joint["mode"] == "drift":
            lines.append(f"  {n + ' in joint':<18s} {_sig(joint['sessions'][n])}")
    for lidar, r in joint["range_offsets"].items():
        lines.append(f"  range offset {lidar}: {r['value_mm']:+.1f} +- {r['sigma_mm']:.1f} mm")
    c = joint["consistency"]
    tests = ([c["global"]] if c["global"] else []) + c["per_session"] + c["consecutive"]
    if tests:
        lines.append("consistency (chi-square):")
        for t in tests:
            size = (
                "" if t["session"] is None else f"  {t['rotation_deg']:.3f} deg, {t['translation_mm']:.1f} mm"
            )
            flag = ("differs" if t["kind"] == "session" else "MOVED") if t["moved"] else "ok"
            chi2 = f"chi2 {t['mahalanobis']:8.1f} ({t['dof']} dof)  p={t['p_value']:.2g}"
            lines.append(f"  {t['label']:<24s} {chi2}{size}  {flag}")
    if c["global"] is not None:
        if c["moved"]:
            t = next(t for t in c["per_session"] if t["session"] == c["moved"])
            lines.append(
                f"the mount moved: session {c['moved']} differs from the others by "
                f"{t['rotation_deg']:.3f} deg and {t['translation_mm']:.1f} mm (p = {t['p_value']:.2g})"
            )
        else:
            lines.append(f"no evidence that the mount moved (p = {c['global']['p_value']:.2g})")
    return "\n".join(lines)


def stage_table(
    stage: str, rows: Sequence[Sequence[object]], skipped: Sequence[tuple[str, str]], out: object
) -> str:
    """What a stage command prints: its table, the frames skipped, where it wrote."""
    lines = [format_table(rows, STAGE_HEADERS[stage])]
    lines += [f"{name}: skipped ({why})" for name, why in skipped]
    lines.append(f"wrote {out}")
    return "\n".join(lines)


def evaluation_text(
    rows: tuple[Sequence[str], Sequence[Sequence[object]]], not_evaluated: Sequence[tuple[str, str]]
) -> str:
    """What ``evaluate`` prints: the frames not evaluated and why, then the metric's table."""
    header, body = rows
    lines = [f"{name}: not evaluated ({why})" for name, why in not_evaluated]
    lines.append(format_table(body, header))
    return "\n".join(lines)


def short_reason(text: str, limit: int = 90) -> str:
    """A reason cut to its first clause (before the first ``"; "`` or ``". "``), at most ``limit``
    characters (cut at a word when it is longer)."""
    text = " ".join(str(text).split())
    for sep in ("; ", ". "):
        head = text.split(sep)[0]
        if len(head) >= 20:
            text = head
            break
    if len(text) <= limit:
        return text
    head = text[: limit - 3]
    return (head.rsplit(" ", 1)[0] if " " in head[limit // 2 :] else head).rstrip(" ,;:") + "..."


def failure_table(frames: Sequence[tuple[str, str, str]], limit: int = 90, max_rows: int = 40) -> str:
    """(frame, stage, reason) rows as a table, each reason cut short (``short_reason``); at most
    ``max_rows`` rows (then a line says how many more)."""
    rows = [(f, stage, short_reason(why, limit)) for f, stage, why in frames[:max_rows]]
    text = format_table(rows, ("frame", "stage", "reason"))
    if len(frames) > max_rows:
        text += f"\n... and {len(frames) - max_rows} more"
    return text


def _names(names: Sequence[str], limit: int = 6) -> str:
    return ", ".join(names[:limit]) + (f" and {len(names) - limit} more" if len(names) > limit else "")


def lidar_frame_note(board: BoardFit | None, beyond: float = BEYOND_FOV_SHARE) -> str | None:
    """How the LiDAR saw one frame's board, when worth a note in the report: placed by its outline
    (no print in the intensity), partly beyond the beams' field."""
    if board is None:
        return None
    d = board.diagnostics
    notes = ["placed by its outline (no print in the LiDAR intensity)"] * bool(d.get("no_contrast"))
    if (share := d.get("outside_fov_share", 0.0)) > beyond:
        notes.append(f"{share:.0%} of the board beyond the LiDAR's field of view (not used)")
    return "; ".join(notes) or None


def lidar_view_lines(cal: Calibration, beyond: float = BEYOND_FOV_SHARE) -> list[str]:
    """Lines on how the LiDAR saw the used boards: placed by their outline alone (no print in its
    intensity), partly beyond its field of view (more than ``beyond`` of the board's area), a margin
    that contradicts the configured one (``lidar.margin.margin_words``)."""
    used = [f for f in cal.frames if f.used and f.board is not None]
    plain = [f.name for f in used if f.board.diagnostics.get("no_contrast")]  # type: ignore[union-attr]
    out = [f.name for f in used if f.board.diagnostics.get("outside_fov_share", 0.0) > beyond]  # type: ignore[union-attr]
    lines = []
    if plain:
        lines.append(f"boards placed by their outline (no print in the LiDAR intensity): {_names(plain)}")
    if out:
        lines.append(f"boards partly beyond the LiDAR's field of view (that part unused): {_names(out)}")
    if margin := margin_words(cal.diagnostics or {}):
        lines.append(margin[0].upper() + margin[1:])
    return lines
