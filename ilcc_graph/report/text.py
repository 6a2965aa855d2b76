"""What the command line prints: tables and summaries as plain strings (no printing here)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..estimation.incremental import FrameUpdate
from ..estimation.sessions import JointSolution
from ..lidar.outline import BEYOND_FOV_SHARE
from ..types import BoardFit, Calibration, Estimate, sigmas_deg_mm
from .sensors import sensors_text, square_size_text

__all__ = [
    "STAGE_HEADERS",
    "evaluation_text",
    "failure_table",
    "format_joint",
    "format_table",
    "format_update",
    "frames_table",
    "lidar_frame_note",
    "lidar_view_lines",
    "run_summary",
    "short_reason",
    "stage_table",
    "summarise",
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


def frames_table(cal: Calibration) -> str:
    """Per frame: used, RMS bearing error, and why it was dropped."""
    rows = []
    for f in cal.frames:
        rms = "" if f.rms_bearing_error_mrad is None else f"{f.rms_bearing_error_mrad:.3f}"
        rows.append((f.name, "yes" if f.used else "no", rms, f.reason or ""))
    return format_table(rows, ("frame", "used", "rms mrad", "reason"))


def summarise(T: np.ndarray, cov: np.ndarray, truth: np.ndarray | None = None) -> str:
    """An extrinsic for a person: matrix, roll/pitch/yaw, translation, 1-sigma values, and, when a
    truth is given, the truth beside each value and the error."""
    import gtsam

    pose = gtsam.Pose3(T)
    rpy = np.degrees(pose.rotation().rpy())
    sig = sigmas_deg_mm(cov)
    has_cov = bool(np.all(np.isfinite(sig)))
    true_rpy = true_t = None
    if truth is not None:
        true_rpy = np.degrees(gtsam.Pose3(truth).rotation().rpy())
        true_t = 1e3 * np.asarray(truth)[:3, 3]

    def row(name: str, value: float, s: float, true: float | None, fmt: str) -> str:
        text = f"  {name:5s} {value:{fmt}}"
        if has_cov:
            text += f"   sigma {s:.4f}" if fmt.endswith("4f") else f"   sigma {s:.2f}"
        if true is not None:
            text += f"   truth {true:{fmt}}"
        return text

    lines = ["T_cam_lidar (p_cam = R p_lidar + t):"]
    lines += ["  [" + "  ".join(f"{v:+.6f}" for v in row_) + "]" for row_ in T]
    if has_cov:
        lines.append("rotation (deg, Rz(yaw) Ry(pitch) Rx(roll)); 1-sigma about the body axes rx, ry, rz:")
    else:
        lines.append(
            "rotation (deg, Rz(yaw) Ry(pitch) Rx(roll)); no covariance (the paper's refinement gives none):"
        )
    for i, name in enumerate(("roll", "pitch", "yaw")):
        lines.append(row(name, rpy[i], sig[i], None if true_rpy is None else true_rpy[i], "+10.4f"))
    lines.append("translation (mm):")
    for i, name in enumerate("xyz"):
        lines.append(row(name, 1e3 * T[i, 3], sig[3 + i], None if true_t is None else true_t[i], "+10.2f"))
    if truth is not None:
        err = gtsam.Pose3(truth).between(pose)  # T_true^-1 T_est
        rot = np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(err.rotation())))
        trans = 1e3 * np.linalg.norm(T[:3, 3] - truth[:3, 3])
        lines.append(f"against the truth: rotation error {rot:.4f} deg, translation error {trans:.2f} mm")
        if has_cov:
            xi = gtsam.Pose3.Logmap(pose.between(gtsam.Pose3(truth)))  # T_true = T_est Exp(xi)
            nees = float(xi @ np.linalg.solve(cov, xi))
            lines.append(f"  NEES {nees:.2f} (chi-square, 6 dof: 95 % of runs below 12.6)")
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


def run_summary(
    cal: Calibration,
    joint: JointSolution | None,
    truth: np.ndarray | None,
    out: object,
    seconds: tuple[float, float],
    report: bool,
    notes: Sequence[str] = (),
) -> str:
    """What ``calibrate`` prints: the frames, the sessions' tests, the extrinsic, the sensors' own
    error terms, the frame count (and the damaged files), and where the result went. seconds:
    (calibrating, writing)."""
    parts = [frames_table(cal), ""]
    if joint is not None:
        parts += [format_joint(joint), ""]
    parts.append(summarise(cal.T_cam_lidar, cal.covariance, truth))
    if sensor_lines := sensors_text(cal):
        parts.append(sensor_lines)
    if scale_line := square_size_text(cal):
        parts.append(scale_line)
    parts += lidar_view_lines(cal)
    if (vf := cal.diagnostics.get("variance_factor", 1.0)) > 1.0:
        parts.append(
            f"  (the residuals are {vf:.2f} x the stated noise variance: sigmas x {np.sqrt(vf):.2f})"
        )
    n_used = sum(f.used for f in cal.frames)
    damaged = sum(f.damaged for f in cal.frames)
    what = "calibration.yaml and the report" if report else "calibration.yaml"
    hurt = f" ({damaged} skipped for damaged files)" if damaged else ""
    parts.append(
        f"\n{n_used} of {len(cal.frames)} frames used{hurt}; calibrated in {seconds[0]:.1f} s; "
        f"wrote {what} to {out} ({seconds[1]:.1f} s)"
    )
    parts += list(notes)
    return "\n".join(parts)


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
    """Lines on how the LiDAR saw the used boards: fitted by their outline alone (no print in its
    intensity), partly beyond its field of view (more than ``beyond`` of the board's area)."""
    used = [f for f in cal.frames if f.used and f.board is not None]
    plain = [f.name for f in used if f.board.diagnostics.get("no_contrast")]  # type: ignore[union-attr]
    out = [f.name for f in used if f.board.diagnostics.get("outside_fov_share", 0.0) > beyond]  # type: ignore[union-attr]
    lines = []
    if plain:
        lines.append(f"  boards placed by their outline (no print in the LiDAR intensity): {_names(plain)}")
    if out:
        lines.append(f"  boards partly beyond the LiDAR's field of view (that part unused): {_names(out)}")
    return lines


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
    characters."""
    text = " ".join(str(text).split())
    for sep in ("; ", ". "):
        head = text.split(sep)[0]
        if len(head) >= 20:
            text = head
            break
    return text if len(text) <= limit else text[: limit - 3].rstrip() + "..."


def failure_table(frames: Sequence[tuple[str, str, str]], limit: int = 90, max_rows: int = 40) -> str:
    """(frame, stage, reason) rows as a table, each reason cut short (``short_reason``); at most
    ``max_rows`` rows (then a line says how many more)."""
    rows = [(f, stage, short_reason(why, limit)) for f, stage, why in frames[:max_rows]]
    text = format_table(rows, ("frame", "stage", "reason"))
    if len(frames) > max_rows:
        text += f"\n... and {len(frames) - max_rows} more"
    return text
