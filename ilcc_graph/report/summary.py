"""The closing summary ``calibrate`` prints, for a person at an 80-column terminal (no printing here).

In this order: the verdict in plain words and what it rests on (``verdict``); one line per frame
not used; the sessions' tests; the camera's pose in the LiDAR frame, the thing one checks on the
rig with a tape measure, and the LiDAR's pose in the camera frame, each with 1-sigma values in mm
and degrees (``camera_in_lidar``, ``lidar_in_camera``); the sensors' own errors; where the report
and the files are and how long it took. docs/report.md ("The closing summary") gives the rule.

Orientations are not Euler angles of ``T_cam_lidar`` (a lens camera's frame is turned 90 degrees
from the LiDAR's, at gimbal lock for roll-pitch-yaw): the camera's viewing direction in the LiDAR
frame as azimuth and elevation, and the roll about it, which stay well defined for every camera
that does not look straight up or down; and the rotation of ``T_cam_lidar`` as one angle about
one axis.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Callable, Sequence
from pathlib import Path

import gtsam
import numpy as np

from ..cameras import CameraModel, make_camera
from ..errors import NOT_READ
from ..estimation.gate import far_above
from ..types import Calibration, worst_sigmas
from .sensors import sensors_text, square_size_text
from .text import format_joint, lidar_view_lines, short_reason

__all__ = ["NEED_DEG_MM", "WIDTH", "camera_in_lidar", "lidar_in_camera", "run_summary", "stated_camera",
           "verdict"]  # fmt: skip

#: the terminal width the summary keeps to
WIDTH = 80
#: 1-sigma (deg, mm) a result must reach to be called GOOD unless the run sets a target: about what
#: colouring a point cloud or fusing detections needs (0.1 deg is 2 px of a 1920-px, 90-degree
#: camera; 5 mm seen from 2 m is 0.14 deg)
NEED_DEG_MM = (0.1, 5.0)
#: fewer frames used than this: the result rests on too little to be called good (the graph warns too)
MIN_FRAMES = 4
#: elevation (deg) beyond which azimuth and roll of the viewing direction are not given
STEEP_DEG = 80.0


def verdict(
    cal: Calibration,
    joint: dict | None = None,
    need: tuple[float, float] | None = None,
    gate_prob: float | None = 0.999,
) -> tuple[str, str]:
    """(``GOOD`` | ``FAIR`` | ``POOR`` | ``MOVED`` | ``NO UNCERTAINTY``, the verdict's text).

    GOOD: at least ``MIN_FRAMES`` frames used, at most a quarter of the frames seen by both sensors
    dropped for disagreeing with the result, and the largest 1-sigma in any direction within
    ``need`` (deg, mm; default ``NEED_DEG_MM``). POOR: fewer than 3 frames used, more than half
    disagreeing, or a 1-sigma above 3 x ``need``. FAIR: in between. MOVED: sessions whose mount
    moved (``joint``: the sessions' ``joint.yaml`` document). NO UNCERTAINTY: a method without a
    covariance (the paper's refinement). When the residuals are far above the detectors' stated
    noise (``gate.FAR_ABOVE``) the text says more poses will not mend that and names the likely
    cause (``Calibration.causes``) or what to check, instead of asking for more poses.
    """
    need = NEED_DEG_MM if need is None else need
    used = [f for f in cal.frames if f.used]
    seen = [f for f in cal.frames if f.board is not None and f.corners is not None]
    disagree = [f for f in seen if not f.used]
    n, k, d = len(cal.frames), len(used), len(disagree)
    rot, mm = worst_sigmas(cal.covariance)
    unread = sum(1 for f in cal.frames if not f.used and (f.reason or "").startswith(NOT_READ))
    missing = n - k - d - unread
    why = [f"{d} dropped by the test"] * bool(d) + [f"{missing} without the board in both sensors"] * bool(
        missing
    ) + [f"{unread} not read"] * bool(unread)
    agree = f"{k} of {n} frames agree with the result within their noise" + (
        f" ({', '.join(why)})" if why else ""
    )
    if not math.isfinite(rot):
        return "NO UNCERTAINTY", (
            f"NO UNCERTAINTY: {k} of {n} frames used; this method gives no covariance, so nothing says "
            "how far off the result may be (calibrate without --refine paper for a verdict)."
        )
    sigma = f"1-sigma at most {rot:.3g} deg and {mm:.2g} mm in any direction"
    moved = None if joint is None else joint["consistency"]["moved"]
    if moved:
        t = next(t for t in joint["consistency"]["per_session"] if t["session"] == moved)  # type: ignore[index]
        return "MOVED", (
            f"MOVED: session {moved} differs from the others by {t['rotation_deg']:.3f} deg and "
            f"{t['translation_mm']:.1f} mm (p = {t['p_value']:.2g}): the mount moved between sessions, so "
            "one extrinsic does not hold for all of them (--mode drift estimates one per session)."
        )
    problems = []
    if k < MIN_FRAMES:
        problems.append(f"only {k} frame{'s' * (k != 1)} used ({MIN_FRAMES} or more advised)")
    if d > 0.25 * max(len(seen), 1):
        problems.append(f"{d} of {len(seen)} frames seen by both sensors disagree beyond their noise")
    if not (rot <= need[0] and mm <= need[1]):
        problems.append(f"{sigma}, above the {need[0]:g} deg / {need[1]:g} mm needed")
    poor = k < 3 or d > 0.5 * max(len(seen), 1) or not (rot <= 3 * need[0] and mm <= 3 * need[1])
    level = "GOOD" if not problems else "POOR" if poor else "FAIR"
    far = _far_text(cal)
    if level == "GOOD":
        head = f"GOOD: {agree}; {sigma} (needed: {need[0]:g} deg, {need[1]:g} mm)."
    else:
        more = k < MIN_FRAMES or not (rot <= need[0] and mm <= need[1])  # frames or sigma: more poses help
        head = f"{level}: {'; '.join(problems)}." + (
            " More board poses would help (see below)." if more and not far else ""
        )
    head += far
    basis = (
        "each frame's residuals pass a chi-square test"
        + ("" if gate_prob is None else f" ({100 * gate_prob:g} %)")
        + " under the noise estimated from all frames"
    )
    comp = (cal.diagnostics or {}).get("variance_component_bearing", 1.0)
    if comp > 1.5:
        basis += f" (image corners {math.sqrt(comp):.1f} x the stated noise)"
    basis += "; the sigmas are the factor graph's marginal covariance"
    if joint is not None and (g := joint["consistency"]["global"]) is not None:
        basis += f"; no evidence that the mount moved between sessions (p = {g['p_value']:.2g})"
    return level, f"{head}\n  Rests on: {basis}."


def _far_text(cal: Calibration) -> str:
    """When the residuals are far above the detectors' stated noise (``gate.FAR_ABOVE``): that more
    poses do not mend them, and the likely cause (``Calibration.causes``) or what to check; else ""."""
    diag = cal.diagnostics or {}
    far = far_above((diag.get("variance_component_board", 1.0), diag.get("variance_component_bearing", 1.0)))
    if not far:
        return ""
    what = {"bearing": "image corners", "board": "LiDAR board poses"}
    sizes = ", ".join(f"{what[k]} {math.sqrt(v):.1f} x" for k, v in far.items())
    text = f" The residuals are far above the detectors' stated noise ({sizes} their stated sigma): "
    if cal.causes:
        return text + "more poses will not mend that. Likely: " + "; or ".join(cal.causes) + "."
    return text + (
        "more poses will not mend that, and no cause shows in the frames: check the camera's intrinsics, "
        "board.square_size and the margin, boards cut off at the image's edge, and that both sensors "
        "capture at the same moment."
    )


# ------------------------------------------------------------------------------------ the poses
def _propagate(
    f: Callable[[np.ndarray], np.ndarray], xi_cov: np.ndarray, dim: int, eps: float = 1e-7
) -> np.ndarray:
    """1-sigma of ``f(xi)`` (a vector) for ``xi ~ N(0, xi_cov)``, by a central-difference Jacobian."""
    J = np.empty((len(f(np.zeros(dim))), dim))
    for i in range(dim):
        e = np.zeros(dim)
        e[i] = eps
        J[:, i] = (f(e) - f(-e)) / (2 * eps)
    return np.sqrt(np.clip(np.diag(J @ xi_cov @ J.T), 0.0, None))


def _view_angles(R_lidar_flu: np.ndarray) -> np.ndarray:
    """(azimuth, elevation, roll) in degrees of a camera body (x forward, y left, z up) in LiDAR axes:
    azimuth of the forward axis from LiDAR x towards y (left), its elevation above the xy plane, and
    the right-handed rotation about it (0 when the camera's left axis lies level)."""
    yaw, pitch, roll = np.degrees(np.asarray(gtsam.Rot3(R_lidar_flu).ypr()))
    return np.array([yaw, -pitch, roll])


def camera_in_lidar(
    T_cam_lidar: np.ndarray, cov: np.ndarray, R_flu_cam: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The camera's pose in the LiDAR frame: (position mm (3,), its 1-sigma (3,), view angles deg
    (azimuth, elevation, roll) (3,), their 1-sigma (3,)); sigmas NaN without a covariance.

    ``R_flu_cam``: the camera's axes in its forward-left-up body frame (``CameraModel.R_flu_cam``).
    Uncertainty: ``T_true = T Exp(xi)``, xi (rotation, translation) in the LiDAR frame, so the
    camera's position ``p = -R^T t`` moves by ``[p]x w - v`` and its axes turn by ``Exp(-w)``.
    """
    T = np.asarray(T_cam_lidar, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    R_lidar_flu = R.T @ np.asarray(R_flu_cam).T
    p = -R.T @ t
    angles = _view_angles(R_lidar_flu)
    C = np.asarray(cov, dtype=np.float64)
    if C.shape != (6, 6) or not np.all(np.isfinite(C)):
        return 1e3 * p, np.full(3, np.nan), angles, np.full(3, np.nan)
    J = np.hstack([np.array([[0, -p[2], p[1]], [p[2], 0, -p[0]], [-p[1], p[0], 0]]), -np.eye(3)])
    p_sigma = 1e3 * np.sqrt(np.clip(np.diag(J @ C @ J.T), 0.0, None))

    def view(w: np.ndarray) -> np.ndarray:
        a = _view_angles(gtsam.Rot3.Expmap(-w).matrix() @ R_lidar_flu)
        return angles + (a - angles + 180.0) % 360.0 - 180.0  # no jump across +-180

    return 1e3 * p, p_sigma, angles, _propagate(view, C[:3, :3], 3)


def lidar_in_camera(
    T_cam_lidar: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray]:
    """The LiDAR's pose in the camera frame: (position mm (3,), its 1-sigma (3,) along the camera's
    axes, rotation angle deg, unit axis (3,) in camera axes, 1-sigma deg (3,) of the rotation about
    the camera's axes); sigmas NaN without a covariance. With ``T_true = T Exp(xi)`` the position
    moves by ``R v`` and the rotation by ``Exp(R w)`` on the left."""
    T = np.asarray(T_cam_lidar, dtype=np.float64)
    R = T[:3, :3]
    rotvec = np.asarray(gtsam.Rot3.Logmap(gtsam.Rot3(R)))
    angle = float(np.linalg.norm(rotvec))
    axis = rotvec / angle if angle > 0 else np.array([0.0, 0.0, 1.0])
    C = np.asarray(cov, dtype=np.float64)
    if C.shape != (6, 6) or not np.all(np.isfinite(C)):
        return 1e3 * T[:3, 3], np.full(3, np.nan), math.degrees(angle), axis, np.full(3, np.nan)
    t_sigma = 1e3 * np.sqrt(np.clip(np.diag(R @ C[3:, 3:] @ R.T), 0.0, None))
    r_sigma = np.degrees(np.sqrt(np.clip(np.diag(R @ C[:3, :3] @ R.T), 0.0, None)))
    return 1e3 * T[:3, 3], t_sigma, math.degrees(angle), axis, r_sigma


def _decimals(sigmas: np.ndarray, lo: int, hi: int) -> int:
    """Decimals that show the smallest finite sigma with two significant digits, within [lo, hi]."""
    s = np.asarray(sigmas, dtype=np.float64)
    s = s[np.isfinite(s) & (s > 0)]
    return lo if not s.size else int(np.clip(1 - math.floor(math.log10(s.min())), lo, hi))


def stated_camera(cal: Calibration) -> CameraModel | None:
    """The camera ``cal`` names, or None when it names none or one that cannot be built."""
    try:
        return make_camera(cal.camera) if cal.camera is not None else None
    except ValueError:
        return None


def _pm(value: float, sigma: float, fmt: str, sfmt: str) -> str:
    return f"{value:{fmt}}" + ("" if not math.isfinite(sigma) else f" +- {sigma:{sfmt}}")


def _side(value: float, sigma: float, plus: str, minus: str, dec: int) -> str:
    """``4.51 +- 0.05 deg left`` for an angle whose sign says the side."""
    text = f"{abs(value):.{dec}f}" + ("" if not math.isfinite(sigma) else f" +- {sigma:.{dec}f}") + " deg "
    return text + (plus if value >= 0 else minus)


def _xyz(v: np.ndarray, s: np.ndarray) -> str:
    d = _decimals(s, 1, 2)
    return "  ".join(f"{a} {_pm(x, e, f'+{7 + d}.{d}f', f'.{d}f')}" for a, x, e in zip("xyz", v, s))


def _pose_lines(cal: Calibration, camera: CameraModel | None) -> list[str]:
    T, C = np.asarray(cal.T_cam_lidar), np.asarray(cal.covariance)
    R_flu_cam = np.eye(3) if camera is None else camera.R_flu_cam
    axes = "its own axes" if camera is None else camera.axes
    forward = "optical axis" if camera is not None and camera.optical else "forward axis"
    p, ps, ang, angs = camera_in_lidar(T, C, R_flu_cam)
    lines = [
        "camera in the LiDAR frame (x forward, y left, z up), +- 1 sigma:",
        f"  position mm   {_xyz(p, ps)}",
    ]
    d = _decimals(angs, 2, 4)
    if abs(ang[1]) < STEEP_DEG:
        lines.append(
            f"  {forward:<12s}  {_side(ang[0], angs[0], 'left', 'right', d)} of x, "
            f"{_side(ang[1], angs[1], 'up', 'down', d)},"
        )
        roll = _side(ang[2], angs[2], "clockwise", "anticlockwise", d)
        lines.append(f"                rolled {roll} (seen from behind)")
    else:
        lines.append(f"  {forward:<12s}  {_side(ang[1], angs[1], 'up', 'down', d)} (near vertical)")
    q, qs, angle, axis, rs = lidar_in_camera(T, C)
    lines += [
        f"LiDAR in the camera frame ({axes}), +- 1 sigma:",
        f"  position mm   {_xyz(q, qs)}",
        f"  rotation      {angle:.3f} deg about ({axis[0]:+.3f}, {axis[1]:+.3f}, {axis[2]:+.3f})",
    ]
    if np.all(np.isfinite(rs)):
        d = _decimals(rs, 3, 5)
        lines.append(f"                +- {rs[0]:.{d}f} {rs[1]:.{d}f} {rs[2]:.{d}f} deg about x y z")
    lines.append("T_cam_lidar (p_cam = R p_lidar + t, metres):")
    lines += ["  [" + "  ".join(f"{v:+.6f}" for v in row) + "]" for row in T]
    return lines


def _truth_lines(cal: Calibration, truth: np.ndarray) -> list[str]:
    pose, true = gtsam.Pose3(np.asarray(cal.T_cam_lidar)), gtsam.Pose3(np.asarray(truth))
    xi = pose.localCoordinates(true)  # T_true = T_est Exp(xi)
    rot = math.degrees(float(np.linalg.norm(xi[:3])))
    mm = 1e3 * float(np.linalg.norm(pose.translation() - true.translation()))
    lines = [f"against the truth: rotation off by {rot:.4f} deg, translation by {mm:.2f} mm"]
    C = np.asarray(cal.covariance)
    if np.all(np.isfinite(C)):
        nees = float(xi @ np.linalg.solve(C, xi))
        lines.append(f"  NEES {nees:.2f} (chi-square, 6 dof: 95 % of honest runs below 12.6)")
    return lines


def _dropped_lines(cal: Calibration, max_rows: int = 40) -> list[str]:
    dropped = [f for f in cal.frames if not f.used]
    width = max((len(f.name) for f in dropped), default=0)
    lines = []
    for f in dropped[:max_rows]:
        head = f"not used {f.name:<{width}}  "
        lines.append(head + short_reason(f.reason or "not used", WIDTH - len(head)))
    if len(dropped) > max_rows:
        lines.append(f"... and {len(dropped) - max_rows} more (every reason in calibration.yaml)")
    if damaged := sum(f.damaged for f in dropped):
        lines.append(f"of these, {damaged} skipped for damaged files (--strict stops at the first)")
    return lines


def _wrap(text: str) -> str:
    """Every line at most ``WIDTH`` columns: long ones wrapped, their continuation indented."""
    out = []
    for line in text.splitlines():
        if len(line) <= WIDTH:
            out.append(line)
            continue
        indent = " " * (len(line) - len(line.lstrip()) + 2)
        out += textwrap.wrap(line, WIDTH, subsequent_indent=indent, break_on_hyphens=False)
    return "\n".join(out)


def run_summary(
    cal: Calibration,
    joint: dict | None,
    truth: np.ndarray | None,
    out: Path | str,
    seconds: tuple[float, float],
    reports: Sequence[Path] = (),
    notes: Sequence[str] = (),
    need: tuple[float, float] | None = None,
    gate_prob: float | None = 0.999,
) -> str:
    """What ``calibrate`` prints (module docstring). joint: the sessions' ``joint.yaml`` document
    (``run.result.Result.documents``) or None; seconds: (calibrating, writing the outputs);
    reports: the report pages written; notes: further lines (the next board pose, ...)."""
    camera = stated_camera(cal)
    parts = [verdict(cal, joint, need, gate_prob)[1]]
    parts += _dropped_lines(cal)
    if joint is not None:
        parts += ["", format_joint(joint)]
    parts += ["", *_pose_lines(cal, camera)]
    if truth is not None:
        parts += _truth_lines(cal, truth)
    extra = [x for x in (sensors_text(cal), square_size_text(cal)) if x] + lidar_view_lines(cal)
    if (vf := (cal.diagnostics or {}).get("variance_factor", 1.0)) > 1.0:
        extra.append(f"the residuals are {vf:.2f} x the stated noise variance: sigmas x {math.sqrt(vf):.2f}")
    parts += ["", *extra] if extra else []
    parts.append("")
    parts += [f"report:  {p}" for p in reports] or ["report:  not written (--no-report)"]
    files = sorted(f.name + "/" * f.is_dir() for f in Path(out).iterdir()) if Path(out).is_dir() else []
    parts.append(f"outputs: {out}" + (f" ({', '.join(files)})" if files else ""))
    parts.append(f"time:    calibrated in {seconds[0]:.1f} s, outputs written in {seconds[1]:.1f} s")
    parts += list(notes)
    return _wrap("\n".join(parts))
