"""The sensors' own errors the graph estimated, for the report and the terminal.

From ``Calibration.sensors`` (``run.finish``): the LiDAR's per-beam range offsets and its
dark-print offset with their sigmas, the terms left out and why, the refined camera intrinsics
against the stated ones, and what each group moved the extrinsic (``estimation.effects``); and
what the board's printed scale would move (``square_size_text``). Pure: returns strings.
"""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..estimation.effects import SQUARE_SIZE_KEY
from ..estimation.selection import Selection
from ..types import Calibration, lidar_term_units

__all__ = ["model_text", "sensors_html", "sensors_lines", "sensors_text", "square_size_text"]

_GROUPS = {
    "lidar_errors": "LiDAR error terms (held at zero)",
    "camera_intrinsics": "camera intrinsics (as stated)",
}


def _e(s: object) -> str:
    return html.escape(str(s), quote=True)


def _term_rows(lid: dict[str, Any]) -> list[tuple[str, str, str, str]]:
    """(term, elevation deg, value, sigma) with units, per LiDAR term."""
    elev = lid.get("elevation_deg", {})
    rows = []
    for n, u, v, s in zip(lid["names"], lidar_term_units(lid), lid["values"], lid["sigmas"], strict=True):
        e = f"{elev[n]:+.2f}" if n in elev else ""
        if u == "m":
            rows.append((n, e, f"{1e3 * v:+.2f} mm", f"{1e3 * s:.2f} mm"))
        elif u == "rad":
            rows.append((n, e, f"{1e3 * v:+.3f} mrad", f"{1e3 * s:.3f} mrad"))
        else:
            rows.append((n, e, f"{v:+.2e}", f"{s:.1e}"))
    return rows


def _effect_rows(effects: dict[str, dict[str, float]]) -> list[tuple[str, str, str, str]]:
    return [
        (
            _GROUPS.get(k, k),
            f"{v['rotation_deg']:.4f}",
            f"{v['translation_mm']:.2f}",
            f"{v['mahalanobis']:.1f}",
        )
        for k, v in effects.items()
    ]


def _html_table(header: tuple[str, ...], rows: Sequence[tuple[str, ...]]) -> str:
    th = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def sensors_html(cal: Calibration) -> str:
    """The report's section on the sensors' own errors ("" when the graph estimated none)."""
    sensors = cal.sensors or {}
    parts: list[str] = [f"<p>{_e(line)}</p>"] if (line := model_text(cal)) else []
    lid = sensors.get("lidar_errors")
    if lid is not None:
        if lid["names"]:
            parts.append(
                "<p>LiDAR error terms estimated from the boards' returns, shared by every frame: range "
                "offset per beam (measured minus true range; beam 0 is the lowest), the extra range of "
                "returns from black print (<code>dark</code>). The board corners in calibration.yaml are "
                "those of the boards the graph settled on.</p>"
            )
            parts.append(_html_table(("term", "beam elevation (deg)", "value", "sigma"), _term_rows(lid)))
        if lid.get("board_plane"):
            parts.append(f"<p>{_e(board_plane_text(lid['board_plane']))}</p>")
        if lid.get("left_out"):
            parts.append("<p>Left out (not estimated, so that they do not absorb noise):</p><ul>")
            parts += [f"<li><b>{_e(t)}</b>: {_e(r)}</li>" for t, r in lid["left_out"]]
            parts.append("</ul>")
    cam = sensors.get("camera_intrinsics")
    if cam is not None:
        rows = [
            (n, f"{a:.6g}", f"{v:.6g}", f"{s:.2g}", f"{(v - a) / s:+.1f}" if s > 0 else "")
            for n, a, v, s in zip(cam["names"], cam["stated"], cam["values"], cam["sigmas"], strict=True)
        ]
        parts.append("<p>Camera intrinsics refined (prior: the config's values):</p>")
        parts.append(_html_table(("parameter", "stated", "refined", "sigma", "change (sigma)"), rows))
    if sensors.get("effects"):
        parts.append(
            "<p>What the terms moved the extrinsic: the same frames solved once more with each group "
            "taken back (the same noise, no gate).</p>"
        )
        parts.append(
            _html_table(
                ("without", "rotation (deg)", "camera position (mm)", "in sigmas"),
                _effect_rows(sensors["effects"]),
            )
        )
    return "\n".join(parts)


def board_plane_text(bp: dict) -> str:
    """One line on each board's own plane and beam offsets (``plane.BoardPlane`` as a dict): their
    sigmas and how set."""
    how = "estimated from the boards" if bp["estimated"] else "as configured"
    parts = []
    if np.isfinite(bp["offset_m"]):
        sd = (
            f" (+- {1e3 * bp['offset_sd']:.1f} mm, +- {np.degrees(bp['tilt_sd']):.2f} deg)"
            if bp["estimated"] and np.isfinite(bp["offset_sd"]) and np.isfinite(bp["tilt_sd"])
            else ""
        )
        parts.append(
            f"each board's own plane (bend, tilt of the print against its returns): offset "
            f"{1e3 * bp['offset_m']:.1f} mm, tilt {np.degrees(bp['tilt_rad']):.2f} deg{sd}"
        )
    beam = bp.get("beam_m", float("nan"))
    if np.isfinite(beam):
        sd = (
            f" +- {1e3 * bp['beam_sd']:.2f}"
            if bp["estimated"] and np.isfinite(bp.get("beam_sd", np.nan))
            else ""
        )
        parts.append(f"each beam's range offset changing from board to board: {1e3 * beam:.2f}{sd} mm")
    note = f"; {bp['note']}" if bp["note"] and bp["note"] != "configured" else ""
    return f"{'; '.join(parts)} ({how}){note}"


def model_text(cal: Calibration) -> str:
    """One line: the sensor model chosen and the evidence ("" when the run chose none)."""
    model = (cal.sensors or {}).get("model")
    return "" if not model else Selection.from_dict(model).summary()


def sensors_text(cal: Calibration) -> str:
    """A few lines for the terminal: the sensor model chosen, the sensors' own errors ("" when
    neither)."""
    return "\n".join(sensors_lines(cal.sensors or {}, cal.diagnostics or {}))


def sensors_lines(sensors: Mapping[str, Any], diagnostics: Mapping[str, float]) -> list[str]:
    """``sensors_text``'s lines from a calibration's ``sensors`` (a pair's ``Calibration.sensors``;
    a rig's ``sensor_model`` and ``lidar_errors`` as ``model`` and ``lidar_errors``) and its
    ``diagnostics`` (the boards fitted again)."""
    model = sensors.get("model")
    lines: list[str] = [Selection.from_dict(model).summary()] if model else []
    lid = sensors.get("lidar_errors")
    if lid is not None and lid["names"]:
        names = list(lid["names"])
        v, s = np.asarray(lid["values"]), np.asarray(lid["sigmas"])
        beams = [i for i, n in enumerate(names) if n.startswith("offset[")]
        if beams:
            lo, hi = 1e3 * v[beams].min(), 1e3 * v[beams].max()
            lines.append(
                f"LiDAR beam offsets: {len(beams)} beams, {lo:+.1f} .. {hi:+.1f} mm "
                f"(sigma {1e3 * np.median(s[beams]):.1f} mm median)"
            )
        for i, n in enumerate(names):
            if i in beams:
                continue
            if n in ("dark", "offset"):
                lines.append(f"LiDAR {n}: {1e3 * v[i]:+.2f} mm, sigma {1e3 * s[i]:.2f} mm")
            else:
                lines.append(f"LiDAR {n}: {v[i]:+.3g}, sigma {s[i]:.2g}")
    refit = diagnostics.get("lidar_boards_on_corrected_ranges")
    if refit:
        lines.append(
            f"{refit:.0f} boards fitted again on their ranges corrected by these errors "
            f"({diagnostics.get('lidar_range_correction_mm', 0.0):+.1f} mm on average)"
        )
    if lid is not None and lid.get("board_plane"):
        lines.append(board_plane_text(lid["board_plane"]))
    if lid is not None and lid.get("left_out"):
        lines.append(f"left out: {', '.join(t for t, _ in lid['left_out'])}")
    for k, e in (sensors.get("effects") or {}).items():
        lines.append(
            f"without the {_GROUPS.get(k, k)}: the extrinsic moves {e['rotation_deg']:.4f} deg, "
            f"{e['translation_mm']:.2f} mm ({e['mahalanobis']:.1f} sigma)"
        )
    return lines


def square_size_text(cal: Calibration) -> str:
    """One line: what a print 0.1 % larger than ``board.square_size`` would move ("" when not known;
    from ``Calibration.diagnostics``, ``estimation.effects.square_size_effect``)."""
    d = cal.diagnostics or {}
    key = SQUARE_SIZE_KEY
    if f"{key}_translation_mm" not in d:
        return ""
    beams = d.get(f"{key}_beams_mm")
    also = "" if beams is None else f", the LiDAR's beam offsets {beams:+.2f} mm"
    return (
        f"a print 0.1 % larger than board.square_size would move the extrinsic "
        f"{d[f'{key}_rotation_deg']:.4f} deg, {d[f'{key}_translation_mm']:.2f} mm "
        f"({d[f'{key}_sigmas']:.2f} sigma){also}: the scans do not show a print's scale, so know "
        f"the square size to {0.1 / max(d[f'{key}_sigmas'], 1e-9):.2g} % (1 sigma; measure the whole "
        "pattern, not one square)"
    )
