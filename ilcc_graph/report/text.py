"""What the command line prints: tables and lines as plain strings (no printing here; the closing
summary of ``calibrate`` is ``summary``)."""

from __future__ import annotations

from collections.abc import Sequence

from ..estimation.incremental import FrameUpdate
from ..estimation.sessions import JointSolution
from ..lidar.outline import BEYOND_FOV_SHARE
from ..types import BoardFit, Calibration, Estimate, sigmas_deg_mm

__all__ = [
    "STAGE_HEADERS",
    "evaluation_text",
    "failure_table",
    "format_joint",
    "format_table",
    "format_update",
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


def format_table(rows: Sequence[Sequence[object]], header: Sequence[str]) -> str:
    """Left-aligned columns with a rule under the header."""
    cells = [[str(c) for c in header]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = []
    for j, r in enumerate(cells):
        lines.append("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
        if j == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _sig(e: Estimate) -> str:
    s = sigmas_deg_mm(e.covariance)
    return " ".join(f"{v:.3f}" for v in s[:3]) + "  |  " + " ".join(f"{v:.2f}" for v in s[3:])


def format_joint(sol: JointSolution) -> str:
    """Sessions: sigmas (deg | mm) of each estimate, the consistency tests, the verdict."""
    lines = [f"joint calibration ({sol.mode}), sigma rx ry rz [deg] | tx ty tz [mm]:"]
    lines.append(f"  {'joint':<18s} {_sig(sol.joint)}")
    for n in sol.alone:
        lines.append(f"  {n + ' alone':<18s} {_sig(sol.alone[n])}")
        if sol.mode == "drift":
            lines.append(f"  {n + ' in joint':<18s} {_sig(sol.sessions[n])}")
    for r in sol.range_offsets.values():
        lines.append(f"  range offset {r.lidar}: {1e3 * r.value_m:+.1f} +- {1e3 * r.sigma_m:.1f} mm")
    tests = ([sol.global_test] if sol.global_test else []) + sol.session_tests + sol.pair_tests
    if tests:
        lines.append("consistency (chi-square):")
        for t in tests:
            size = "" if t.session is None else f"  {t.rotation_deg:.3f} deg, {t.translation_mm:.1f} mm"
            flag = ("differs" if t.kind == "session" else "MOVED") if t.moved else "ok"
            lines.append(
                f"  {t.label:<24s} chi2 {t.mahalanobis:8.1f} ({t.dof} dof)  p={t.p_value:.2g}{size}  {flag}"
            )
    if sol.global_test is not None:
        if sol.moved:
            t = next(t for t in sol.session_tests if t.session == sol.moved)
            lines.append(
                f"the mount moved: session {sol.moved} differs from the others by "
                f"{t.rotation_deg:.3f} deg and {t.translation_mm:.1f} mm (p = {t.p_value:.2g})"
            )
        else:
            lines.append(f"no evidence that the mount moved (p = {sol.global_test.p_value:.2g})")
    return "\n".join(lines)


def format_update(u: FrameUpdate, target_sigma: tuple[float, float] | None = None) -> str:
    """One line per incremental update: frame, count, sigmas in deg / mm, time, target status."""
    head = f"{u.name or '(final)':>10s}  n={u.n_frames:<4d}"
    if not u.accepted:
        return f"{head}  rejected: {u.reason}"
    if u.T_cam_lidar is None:
        return f"{head}  {u.reason or 'waiting'}"
    s = sigmas_deg_mm(u.covariance)
    body = (
        f"sigma rot [deg] {s[0]:.3f} {s[1]:.3f} {s[2]:.3f}  "
        f"trans [mm] {s[3]:.2f} {s[4]:.2f} {s[5]:.2f}  ({1e3 * u.seconds:.0f} ms)"
    )
    if target_sigma is not None:
        body += "  target reached" if u.reached_target else "  target not yet reached"
    return f"{head}  {body}"


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
    intensity), partly beyond its field of view (more than ``beyond`` of the board's area)."""
    used = [f for f in cal.frames if f.used and f.board is not None]
    plain = [f.name for f in used if f.board.diagnostics.get("no_contrast")]  # type: ignore[union-attr]
    out = [f.name for f in used if f.board.diagnostics.get("outside_fov_share", 0.0) > beyond]  # type: ignore[union-attr]
    lines = []
    if plain:
        lines.append(f"boards placed by their outline (no print in the LiDAR intensity): {_names(plain)}")
    if out:
        lines.append(f"boards partly beyond the LiDAR's field of view (that part unused): {_names(out)}")
    return lines
