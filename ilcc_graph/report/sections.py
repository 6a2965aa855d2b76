"""The report page's parts: style, tables, the result and ground-truth section, per-frame rows and
hints, the verdict (HTML strings)."""

from __future__ import annotations

import html
import math

import numpy as np

from ..evaluation.metric import Evaluation, FrameEvaluation
from ..evaluation.studies import pose_difference
from ..types import Calibration
from .summary import camera_in_lidar, lidar_in_camera, stated_camera
from .text import lidar_frame_note

__all__ = ["CHI2_6DOF_3SIGMA", "CSS", "GALLERY_NOTE", "TABLE_NOTE", "esc", "figure", "frame_rows", "num",
           "page", "pm", "standing_out", "summary_verdict", "table", "transform_section"]  # fmt: skip

#: chi-square quantile of 6 degrees of freedom at 99.73 % (the 3-sigma probability).
CHI2_6DOF_3SIGMA = 20.06


CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:1.5em auto;max-width:1200px;
 padding:0 1em;color:#222;line-height:1.4}
h1{font-size:1.6em;margin-bottom:.2em} h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em} td,th{border:1px solid #ccc;padding:.25em .6em;
 text-align:right} th{background:#f3f3f3} td.l,th.l{text-align:left}
tr.drop td{color:#999} .ok{color:#070;font-weight:bold} .bad{color:#b00;font-weight:bold}
.verdict{padding:.6em 1em;border-radius:6px;margin:.8em 0;font-size:1.05em}
.verdict.ok{background:#e8f6e8;border:1px solid #7c7} .verdict.bad{background:#fbeaea;border:1px solid #d77}
figure{display:inline-block;margin:.4em;vertical-align:top;max-width:100%} figure img{max-width:100%;
 border:1px solid #ddd} figcaption{font-size:.8em;color:#555;max-width:560px}
.gallery figure{width:380px} .gallery img{width:380px} code{background:#f5f5f5;padding:0 .2em}
.note{font-size:.85em;color:#555} summary{font-weight:bold;cursor:pointer;margin:.5em 0}
"""


TABLE_NOTE = " ".join(
    [
        '<p class="note"><b>fit RMS</b>: the solver\'s bearing residual (after it moves each board pose',
        "within its uncertainty). <b>corner RMS</b>: LiDAR corners re-projected with the result against",
        "the detected image corners; <b>explained</b>: what the stated uncertainties of both account for.",
        "<b>intensity error</b>: the paper's re-projection error (Eq. 14, gray zone epsilon_g = 4): board",
        "points that land inside the detected corners' cells and whose intensity colour disagrees with the",
        "printed colour cost their L1 distance to the nearest grid lines, divided by range, averaged and",
        "divided by the attendance rate (points inside over points the LiDAR fit puts inside). Near zero",
        "when right; a 1 degree error gives several mrad. <b>image detector</b>: which chessboard detector",
        "found the corners (all are refined and weighed alike; see docs/image_stage.md).</p>",
    ]
)

GALLERY_NOTE = " ".join(
    [
        '<p class="note">Click a frame to open or close it, a picture for full size.',
        "Points the camera cannot see (hidden behind the board or a nearer surface, as the LiDAR",
        "sees from elsewhere) are left out. On a right result the range colours change where the",
        "image's edges are and the corners' cyan crosses sit on their circles.</p>",
    ]
)


def page(title: str, body: list[str], css: str = CSS) -> bytes:
    """A whole HTML page (UTF-8) of ``body``'s parts, one a line, under ``title``."""
    head = f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title>'
    return (head + f"<style>{css}</style></head><body>" + "\n".join(body) + "</body></html>").encode("utf-8")


def esc(s: object) -> str:
    return html.escape(str(s), quote=True)


def num(x: float | None, fmt: str = ".3g") -> str:
    if x is None:
        return "–"
    if math.isnan(x):  # an int is never NaN nor infinite
        return "–"
    if math.isinf(x):
        return "∞"
    return format(x, fmt)


def table(
    header: list[str],
    rows: list[list[str]],
    left: int = 1,
    row_class: list[str] | None = None,
    left_last: int = 0,
) -> str:
    """An HTML table; the first ``left`` and the last ``left_last`` columns are left-aligned."""
    n = len(header)

    def is_left(i: int) -> bool:
        return i < left or i >= n - left_last

    th = "".join(f'<th class="l">{h}</th>' if is_left(i) else f"<th>{h}</th>" for i, h in enumerate(header))
    body = []
    for r, cells in enumerate(rows):
        cls = f' class="{row_class[r]}"' if row_class and row_class[r] else ""
        tds = "".join(
            f'<td class="l">{c}</td>' if is_left(i) else f"<td>{c}</td>" for i, c in enumerate(cells)
        )
        body.append(f"<tr{cls}>{tds}</tr>")
    return f"<table><tr>{th}</tr>{''.join(body)}</table>"


def figure(path: str, caption: str, width: int | None = None) -> str:
    w = f' style="width:{width}px"' if width else ""
    return (
        f'<figure{w}><a href="{esc(path)}"><img src="{esc(path)}" alt="{esc(caption)}" loading="lazy"></a>'
        f"<figcaption>{esc(caption)}</figcaption></figure>"
    )


def _sigmas(cov: np.ndarray) -> np.ndarray:
    cov = np.asarray(cov, dtype=np.float64)
    if cov.shape != (6, 6):
        return np.full(6, np.nan)
    return np.sqrt(np.clip(np.diag(cov), 0.0, None))


def pm(v: float, s: float, fmt: str) -> str:
    """``v ± s`` (``s`` in ``fmt`` without its sign; no ± when ``s`` is not finite)."""
    return format(v, fmt) + ("" if not math.isfinite(s) else f" ± {format(s, fmt.lstrip('+'))}")


def transform_section(cal: Calibration, T_gt: np.ndarray | None) -> tuple[str, str | None]:
    """The result (the matrix; the camera's pose in the LiDAR frame and the LiDAR's in the camera
    frame, 1-sigma beside each value, as ``summary`` prints them) and, with a ground truth, its verdict."""
    T = np.asarray(cal.T_cam_lidar, dtype=np.float64)
    s = _sigmas(cal.covariance)
    camera = stated_camera(cal)
    R_flu_cam = np.eye(3) if camera is None else camera.R_flu_cam
    axes = "its own axes" if camera is None else camera.axes
    p, ps, ang, angs = camera_in_lidar(T, cal.covariance, R_flu_cam)
    q, qs, angle, axis, rs = lidar_in_camera(T, cal.covariance)
    mat = "<br>".join(" ".join(f"{v: .6f}" for v in row) for row in T)
    rot = f"{angle:.3f} deg about ({', '.join(f'{a:+.3f}' for a in axis)})"
    if np.all(np.isfinite(rs)):
        rot += f", ± {rs[0]:.4f} {rs[1]:.4f} {rs[2]:.4f} deg about the camera's x, y, z"
    parts = [
        "<p><code>T_cam_lidar</code> maps LiDAR points into the camera frame: "
        "<code>p_cam = R p_lidar + t</code>.</p>",
        f"<pre>{mat}</pre>",
        table(
            ["position (mm), ± 1 sigma", "x", "y", "z"],
            [
                ["the camera in the LiDAR frame (x forward, y left, z up)"]
                + [pm(v, e, "+.2f") for v, e in zip(p, ps)],
                [f"the LiDAR in the camera frame ({esc(axes)})"] + [pm(v, e, "+.2f") for v, e in zip(q, qs)],
            ],
        ),
        table(
            [
                "the camera's view in the LiDAR frame (deg), ± 1 sigma",
                "azimuth (+ left of x)",
                "elevation (+ up)",
                "roll about it (+ clockwise seen from behind)",
            ],
            [
                ["viewing direction (optical axis; a panorama's centre column)"]
                + [pm(v, e, "+.4f") for v, e in zip(ang, angs)]
            ],
        ),  # fmt: skip
        f"<p>The rotation of <code>T_cam_lidar</code>: {rot}.</p>",
        '<p class="note">No Euler angles of <code>T_cam_lidar</code>: a lens camera\'s frame is turned 90 '
        "degrees from the LiDAR's, where roll-pitch-yaw sit at gimbal lock. Every 1-sigma is propagated "
        "from the covariance in GTSAM's convention (<code>T_true = T_est * Exp(xi)</code>, xi = rotation "
        "then translation, in the LiDAR frame); its square roots of the diagonal are in calibration.yaml "
        "(<code>sigma</code>).</p>",
    ]
    verdict = None
    if T_gt is not None:
        d = pose_difference(T, np.asarray(T_gt, dtype=np.float64))
        off_deg = math.degrees(float(np.linalg.norm(d[:3])))
        dist = 1000 * float(np.linalg.norm(d[3:]))
        z = d / np.where(s > 0, s, np.nan)
        try:
            m2 = float(d @ np.linalg.solve(np.asarray(cal.covariance, dtype=np.float64), d))
        except np.linalg.LinAlgError:
            m2 = float("nan")
        parts.append("<h3>Against the ground truth</h3>")
        parts.append(
            table(
                ["", "rx", "ry", "rz", "tx", "ty", "tz"],
                [
                    ["truth minus estimate (deg / mm)"]
                    + [num(math.degrees(v), ".4f") for v in d[:3]]
                    + [num(1000 * v, ".2f") for v in d[3:]],
                    ["in sigmas"] + [num(v, ".2f") for v in z],
                ],
            )
        )
        within = bool(np.isfinite(z).all() and np.all(np.abs(z) < 3.0))
        ok = within and bool(m2 < CHI2_6DOF_3SIGMA)
        verdict = (
            f'<div class="verdict {"ok" if ok else "bad"}">Against the ground truth: rotation off by '
            f"{off_deg:.3f} deg, translation by {dist:.1f} mm. "
            + ("Every parameter lies within 3 sigma" if within else "Some parameter lies beyond 3 sigma")
            + f"; Mahalanobis distance squared {m2:.1f} (6 on average for an honest covariance, "
            f"{'below' if m2 < CHI2_6DOF_3SIGMA else 'above'} its 3-sigma bound "
            f"{CHI2_6DOF_3SIGMA:.1f}).</div>"
        )
    return "\n".join(parts), verdict


def _hints(ev: Evaluation, names: set[str]) -> dict[str, str]:
    """What a frame's pair of errors suggests, for frames far off the typical (median over
    ``names``, the used frames) corner or intensity error."""
    frames = [e for e in ev.frames if e.name in names] or list(ev.frames)
    c = np.array([e.corner_rms_mrad for e in frames], dtype=np.float64)
    i = np.array([e.intensity_mrad for e in frames], dtype=np.float64)
    med_c = float(np.median(c[np.isfinite(c)])) if np.isfinite(c).any() else float("nan")
    med_i = float(np.median(i[np.isfinite(i)])) if np.isfinite(i).any() else float("nan")
    out: dict[str, str] = {}
    for e in ev.frames:
        if np.isinf(e.intensity_mrad):
            out[e.name] = (
                "no board point lands on the detected pattern: wrong extrinsic, wrong corners or a scan "
                "and image that do not belong together"
            )
            continue
        corner_bad = np.isfinite(med_c) and e.corner_rms_mrad > max(3.0 * med_c, med_c + 2.0)
        inten_bad = np.isfinite(med_i) and e.intensity_mrad > max(3.0 * med_i, 1.0)
        if corner_bad and not inten_bad:
            out[e.name] = (
                "the LiDAR points match the image but the LiDAR corners do not: the LiDAR board fit is "
                "likely off (by a square?)"
            )
        elif corner_bad and inten_bad:
            out[e.name] = (
                "neither corners nor points match: image corners wrong (order?) or the extrinsic does "
                "not hold for this frame"
            )
        elif inten_bad:
            out[e.name] = (
                "corners match but the points' colours do not: intensities unreliable here or the board "
                "segment holds other points"
            )
    return out


def frame_rows(
    cal: Calibration, ev: Evaluation, expected: dict[str, float], pictured: set[str]
) -> tuple[list[list[str]], list[str]]:
    by = ev.by_name()
    hints = _hints(ev, {f.name for f in cal.frames if f.used})
    rows, classes = [], []
    for f in cal.frames:
        e: FrameEvaluation | None = by.get(f.name)
        notes = [x for x in (f.reason, hints.get(f.name), lidar_frame_note(f.board)) if x]
        rows.append(
            [
                f'<a href="#f{esc(f.name)}">{esc(f.name)}</a>' if f.name in pictured else esc(f.name),
                '<span class="ok">yes</span>' if f.used else '<span class="bad">no</span>',
                num(f.rms_bearing_error_mrad),
                num(e.corner_rms_px if e else None),
                num(expected.get(f.name)),
                num(e.corner_rms_mrad if e else None),
                num(e.intensity_mrad if e else None),
                num(e.attendance if e else None, ".2f"),
                f"{e.n_inside}/{e.n_points}" if e else "–",
                str(e.n_mismatch) if e else "–",
                num(e.range_m if e else None, ".1f"),
                esc(f.corners.detector) if f.corners is not None and f.corners.detector else "–",
                "<br>".join(esc(n) for n in notes),
            ]
        )
        classes.append("" if f.used else "drop")
    return rows, classes


def standing_out(ev: Evaluation, names: set[str]) -> list[str]:
    """Frames among ``names`` whose corner or intensity error is far above the others', or infinite.

    Robust: above ``factor`` x the median, the median + 5 x 1.4826 x MAD and an absolute floor
    (the intensity error of a single frame rests on few points: 1 mrad, about 0.06 degree).
    """
    out: set[str] = set()
    frames = [e for e in ev.frames if e.name in names]
    for key, factor, floor in (("corner_rms_mrad", 2.0, 0.0), ("intensity_mrad", 3.0, 1.0)):
        v = np.array([getattr(e, key) for e in frames], dtype=np.float64)
        fin = np.isfinite(v)
        if fin.sum() >= 3:
            med = float(np.median(v[fin]))
            mad = 1.4826 * float(np.median(np.abs(v[fin] - med)))
            limit = max(factor * med, med + 5.0 * mad, floor)
            out.update(e.name for e, x in zip(frames, v) if np.isfinite(x) and x > limit)
        out.update(e.name for e, x in zip(frames, v) if np.isinf(x))
    return [e.name for e in frames if e.name in out]


def summary_verdict(cal: Calibration, ev: Evaluation, odd: list[str], expected: dict[str, float]) -> str:
    n_used = sum(f.used for f in cal.frames)
    im, i3 = ev.intensity_mrad
    cm, c3 = ev.corner_mrad
    pm, _ = ev.corner_px
    msg = (
        f"{n_used} of {len(cal.frames)} frames used. Corner re-projection error {num(pm)} px "
        f"({num(cm)} mrad) on average over the used frames (3 x SD over frames {num(c3)} mrad)"
    )
    used = {f.name for f in cal.frames if f.used}
    exp = np.array([v for n, v in expected.items() if n in used and np.isfinite(v)])
    too_big = False
    if exp.size:
        exp_px = float(np.mean(exp))
        too_big = bool(np.isfinite(pm) and pm > 3.0 * exp_px)
        msg += (
            f"; the stated uncertainties of the image corners and LiDAR board poses explain about "
            f"{num(exp_px)} px"
            + (
                " &mdash; <b>the error is several times larger: something they do not cover is off</b>"
                if too_big
                else ""
            )
        )
    msg += f". The paper's intensity re-projection error: {num(im)} mrad (3 x SD over frames {num(i3)})."
    if odd:
        msg += (
            f" Frame(s) {', '.join(esc(n) for n in odd)} stand out from the others: see their pictures below."
        )
    dropped = [f for f in cal.frames if not f.used]
    if dropped:
        msg += "<br>Dropped: " + "; ".join(f"{esc(f.name)} ({esc(f.reason or 'not used')})" for f in dropped)
    good = n_used > 0 and not odd and not too_big
    return f'<div class="verdict {"ok" if good else "bad"}">{msg}</div>'
