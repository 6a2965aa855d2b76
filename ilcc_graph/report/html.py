"""The report: ``index.html`` with its figures, returned as ``{relative path: bytes}``.

The caller (the command line) writes the files under ``OUT/report/``; nothing here touches the
disk. The page is self-contained and offline: inline CSS, no scripts, figures as PNG files in
``figures/`` beside it.
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..board import Board
from ..cameras import CameraModel
from ..types import Calibration, FrameResult, Scan
from .metric import (
    EvalFrame,
    Evaluation,
    FrameEvaluation,
    eval_frame,
    eval_frame_with_scan,
    evaluate,
    expected_corner_px,
    metric_points,
    transform_points,
)
from .overlays import (
    ColouredPoints,
    Crop,
    colour_map,
    colour_points,
    crop_around,
    downscale,
    draw_metric,
    draw_points,
    draw_reprojection,
    edge_image,
    encode_png,
)
from .plots import (
    plot_cross_validation,
    plot_error_vs_frames,
    plot_frames_vs_accuracy,
    plot_per_frame,
    plot_valley,
)
from .sensors import sensors_html
from .studies import CrossValidation, FramesCurve, pose_difference, valley

__all__ = ["FrameFigures", "frame_figures", "build_report", "FIGURES_DIR"]

FIGURES_DIR = "figures"
#: chi-square quantile of 6 degrees of freedom at 99.73 % (the 3-sigma probability).
CHI2_6DOF_3SIGMA = 20.06


@dataclass(frozen=True)
class FrameFigures:
    """One frame's pictures ({relative path: PNG bytes}, in display order with captions), its
    coloured points (for a PLY the caller writes) and what the metric needs (board points rebuilt
    from the scan when the result lacks them)."""

    name: str
    files: dict[str, bytes]
    captions: dict[str, str]
    coloured: ColouredPoints
    eval_frame: EvalFrame | None = None


def _frame_crop(
    image: np.ndarray,
    camera: CameraModel,
    candidates: tuple[np.ndarray | None, ...],
    pad: float,
    min_size: int,
    zoom_to: int,
    max_zoom: int,
    max_size: int = 1000,
) -> Crop | None:
    """A crop around the first usable pixel set of ``candidates``, enlarged to ``zoom_to`` pixels."""
    for uv in candidates:
        if uv is not None and len(uv) and np.isfinite(uv).all(axis=1).any():
            crop = crop_around(image, uv, camera, pad=pad, min_size=min_size)
            return crop.zoomed(zoom_to, max_zoom, max_size) if crop.image.size else None
    return None


def frame_figures(
    name: str,
    scan: Scan,
    image: np.ndarray,
    camera: CameraModel,
    board: Board,
    T_cam_lidar: np.ndarray,
    result: FrameResult | None = None,
    max_width: int = 1600,
) -> FrameFigures:
    """Pictures of one frame under ``T_cam_lidar``.

    - ``<name>_corners.png``: detected corners numbered (0 green, last blue) and the LiDAR corners
      re-projected (cyan crosses), cropped around the board;
    - ``<name>_range.png``: the scan's points the camera can see, on the image, coloured by range;
    - ``<name>_edges.png``: the same on the image's edges, coloured by intensity;
    - ``<name>_metric.png``: the board points as the intensity metric judges them;
    - ``<name>_whole.png``: the whole picture downscaled to ``max_width``, points by range.
    Points hidden from the camera (behind the board, or behind nearer points) are left out.
    """
    T = np.asarray(T_cam_lidar, dtype=np.float64)
    bf = result.board if result is not None else None
    cr = result.corners if result is not None else None
    T_lb = None if bf is None or not np.all(np.isfinite(bf.T_lidar_board)) else bf.T_lidar_board
    coloured = colour_points(scan, image, camera, T, T_lb, board if T_lb is not None else None)
    vis = coloured.visibility
    rng_lidar = np.linalg.norm(scan.points, axis=1)
    files: dict[str, bytes] = {}
    captions: dict[str, str] = {}

    def put(suffix: str, img: np.ndarray, caption: str) -> None:
        key = f"{FIGURES_DIR}/{name}_{suffix}.png"
        files[key] = encode_png(img, bits=6)
        captions[key] = caption

    uv_corners = None if cr is None else np.asarray(cr.uv, dtype=np.float64)
    uv_rep = None
    if bf is not None and bf.corners_lidar is not None and len(bf.corners_lidar):
        uv_rep = camera.project(transform_points(T, bf.corners_lidar))
    ef = eval_frame_with_scan(result, scan, board) if result is not None else None
    uv_board = None
    if ef is not None and len(ef.points_lidar):
        uv_board = camera.project(transform_points(T, ef.points_lidar))
    where = (uv_corners, uv_board, uv_rep)
    tight = _frame_crop(image, camera, where, pad=0.2, min_size=40, zoom_to=720, max_zoom=8)
    crop = _frame_crop(image, camera, where, pad=0.9, min_size=120, zoom_to=720, max_zoom=4)
    vis_idx = np.flatnonzero(vis.visible)
    far_first = vis_idx[np.argsort(-vis.depth[vis_idx])]
    if tight is not None and uv_corners is not None:
        put(
            "corners",
            draw_reprojection(tight, uv_corners, uv_rep),
            "Detected corners (0 green, last blue, joined in index order) and the LiDAR corners "
            "re-projected with the result (cyan crosses).",
        )
    if tight is not None and ef is not None and len(ef.points_lidar):
        mp = metric_points(ef, camera, board, T)
        put(
            "metric",
            draw_metric(tight, mp, ef.uv),
            "The intensity metric: board points inside the detected cells agreeing with the printed "
            "colour (green), disagreeing (red, larger = farther from the grid), in the gray zone "
            "(yellow), outside the cells (blue).",
        )
    if crop is not None:
        uvc = crop.to_crop(vis.uv[far_first])
        h, w = crop.image.shape[:2]
        inside = (uvc[:, 0] >= -0.5) & (uvc[:, 0] < w - 0.5) & (uvc[:, 1] >= -0.5) & (uvc[:, 1] < h - 0.5)
        sel, uvc = far_first[inside], uvc[inside]
        r = 2 if crop.zoom > 1 else None
        if sel.size:
            put(
                "range",
                draw_points(crop.image, uvc, colour_map(rng_lidar[sel], name="turbo"), radius=r),
                "Visible LiDAR points on the image, coloured by range (blue near, red far).",
            )
            put(
                "edges",
                draw_points(
                    edge_image(crop.image), uvc, colour_map(scan.intensity[sel], name="jet"), radius=r
                ),
                "Visible LiDAR points on the image's edges, coloured by intensity (blue low, red high).",
            )
    small, f = downscale(image, max_width)
    uv_small = (vis.uv[far_first] + 0.5) * f - 0.5
    # 3x3 dots where points are sparse on the picture, single pixels where they would cover it
    sparse = small.shape[0] * small.shape[1] > 40 * max(len(far_first), 1)
    put(
        "whole",
        draw_points(small, uv_small, colour_map(rng_lidar[far_first], name="turbo"), radius=int(sparse)),
        f"The whole picture (scaled by {f:.2f}) with every visible LiDAR point, coloured by range.",
    )
    return FrameFigures(name, files, captions, coloured, ef)


# --------------------------------------------------------------------------------- HTML
_CSS = """
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


_TABLE_NOTE = " ".join(
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

_GALLERY_NOTE = " ".join(
    [
        '<p class="note">Click a frame to open or close it, a picture for full size.',
        "Points the camera cannot see (hidden behind the board or a nearer surface, as the LiDAR",
        "sees from elsewhere) are left out. On a right result the range colours change where the",
        "image's edges are and the corners' cyan crosses sit on their circles.</p>",
    ]
)


def _e(s: object) -> str:
    return html.escape(str(s), quote=True)


def _num(x: float | None, fmt: str = ".3g") -> str:
    if x is None:
        return "–"
    if isinstance(x, float) and math.isnan(x):
        return "–"
    if isinstance(x, float) and math.isinf(x):
        return "∞"
    return format(x, fmt)


def _table(
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


def _img(path: str, caption: str, width: int | None = None) -> str:
    w = f' style="width:{width}px"' if width else ""
    return (
        f'<figure{w}><a href="{_e(path)}"><img src="{_e(path)}" alt="{_e(caption)}" loading="lazy"></a>'
        f"<figcaption>{_e(caption)}</figcaption></figure>"
    )


def _sigmas(cov: np.ndarray) -> np.ndarray:
    cov = np.asarray(cov, dtype=np.float64)
    if cov.shape != (6, 6):
        return np.full(6, np.nan)
    return np.sqrt(np.clip(np.diag(cov), 0.0, None))


def _transform_section(cal: Calibration, T_gt: np.ndarray | None) -> tuple[str, str | None]:
    T = np.asarray(cal.T_cam_lidar, dtype=np.float64)
    s = _sigmas(cal.covariance)
    rotvec = np.degrees(Rotation.from_matrix(T[:3, :3]).as_rotvec())
    ypr = Rotation.from_matrix(T[:3, :3]).as_euler("ZYX", degrees=True)
    mat = "<br>".join(" ".join(f"{v: .6f}" for v in row) for row in T)
    parts = [
        "<p><code>T_cam_lidar</code> maps LiDAR points into the camera frame: "
        "<code>p_cam = R p_lidar + t</code>.</p>",
        f"<pre>{mat}</pre>",
        _table(
            ["", "x", "y", "z"],
            [
                ["t (mm)"] + [_num(1000 * v, ".1f") for v in T[:3, 3]],
                ["rotation vector (deg)"] + [_num(v, ".3f") for v in rotvec],
                ["yaw, pitch, roll (Z-Y-X, deg)"] + [_num(v, ".3f") for v in ypr],
                ["1 sigma rotation (deg)"] + [_num(math.degrees(v), ".4f") for v in s[:3]],
                ["1 sigma translation (mm)"] + [_num(1000 * v, ".2f") for v in s[3:]],
            ],
        ),
        '<p class="note">Sigmas are the square roots of the covariance diagonal, in GTSAM\'s convention '
        "(<code>T_true = T_est * Exp(xi)</code>, xi = rotation then translation, in the LiDAR frame).</p>",
    ]
    verdict = None
    if T_gt is not None:
        d = pose_difference(T, np.asarray(T_gt, dtype=np.float64))
        ang = math.degrees(float(np.linalg.norm(d[:3])))
        dist = 1000 * float(np.linalg.norm(d[3:]))
        z = d / np.where(s > 0, s, np.nan)
        try:
            m2 = float(d @ np.linalg.solve(np.asarray(cal.covariance, dtype=np.float64), d))
        except np.linalg.LinAlgError:
            m2 = float("nan")
        parts.append("<h3>Against the ground truth</h3>")
        parts.append(
            _table(
                ["", "rx", "ry", "rz", "tx", "ty", "tz"],
                [
                    ["truth minus estimate (deg / mm)"]
                    + [_num(math.degrees(v), ".4f") for v in d[:3]]
                    + [_num(1000 * v, ".2f") for v in d[3:]],
                    ["in sigmas"] + [_num(v, ".2f") for v in z],
                ],
            )
        )
        within = bool(np.isfinite(z).all() and np.all(np.abs(z) < 3.0))
        ok = within and bool(m2 < CHI2_6DOF_3SIGMA)
        verdict = (
            f'<div class="verdict {"ok" if ok else "bad"}">Against the ground truth: rotation off by '
            f"{ang:.3f} deg, translation by {dist:.1f} mm. "
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


def _frame_rows(
    cal: Calibration, ev: Evaluation, expected: dict[str, float], pictured: set[str]
) -> tuple[list[list[str]], list[str]]:
    by = ev.by_name()
    hints = _hints(ev, {f.name for f in cal.frames if f.used})
    rows, classes = [], []
    for f in cal.frames:
        e: FrameEvaluation | None = by.get(f.name)
        notes = [x for x in (f.reason, hints.get(f.name)) if x]
        rows.append(
            [
                f'<a href="#f{_e(f.name)}">{_e(f.name)}</a>' if f.name in pictured else _e(f.name),
                '<span class="ok">yes</span>' if f.used else '<span class="bad">no</span>',
                _num(f.rms_bearing_error_mrad),
                _num(e.corner_rms_px if e else None),
                _num(expected.get(f.name)),
                _num(e.corner_rms_mrad if e else None),
                _num(e.intensity_mrad if e else None),
                _num(e.attendance if e else None, ".2f"),
                f"{e.n_inside}/{e.n_points}" if e else "–",
                str(e.n_mismatch) if e else "–",
                _num(e.range_m if e else None, ".1f"),
                _e(f.corners.detector) if f.corners is not None and f.corners.detector else "–",
                "<br>".join(_e(n) for n in notes),
            ]
        )
        classes.append("" if f.used else "drop")
    return rows, classes


def _standing_out(ev: Evaluation, names: set[str]) -> list[str]:
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


def _summary_verdict(cal: Calibration, ev: Evaluation, odd: list[str], expected: dict[str, float]) -> str:
    n_used = sum(f.used for f in cal.frames)
    im, i3 = ev.intensity_mrad
    cm, c3 = ev.corner_mrad
    pm, _ = ev.corner_px
    msg = (
        f"{n_used} of {len(cal.frames)} frames used. Corner re-projection error {_num(pm)} px "
        f"({_num(cm)} mrad) on average over the used frames (3 sigma {_num(c3)} mrad)"
    )
    used = {f.name for f in cal.frames if f.used}
    exp = np.array([v for n, v in expected.items() if n in used and np.isfinite(v)])
    too_big = False
    if exp.size:
        exp_px = float(np.mean(exp))
        too_big = bool(np.isfinite(pm) and pm > 3.0 * exp_px)
        msg += (
            f"; the stated uncertainties of the image corners and LiDAR board poses explain about "
            f"{_num(exp_px)} px"
            + (
                " &mdash; <b>the error is several times larger: something they do not cover is off</b>"
                if too_big
                else ""
            )
        )
    msg += f". The paper's intensity re-projection error: {_num(im)} mrad (3 sigma {_num(i3)})."
    if odd:
        msg += (
            f" Frame(s) {', '.join(_e(n) for n in odd)} stand out from the others: see their pictures below."
        )
    dropped = [f for f in cal.frames if not f.used]
    if dropped:
        msg += "<br>Dropped: " + "; ".join(f"{_e(f.name)} ({_e(f.reason or 'not used')})" for f in dropped)
    good = n_used > 0 and not odd and not too_big
    return f'<div class="verdict {"ok" if good else "bad"}">{msg}</div>'


def build_report(
    calibration: Calibration,
    camera: CameraModel,
    board: Board,
    sources: Iterable[tuple[str, Scan, np.ndarray]] = (),
    *,
    evaluation: Evaluation | None = None,
    curve: FramesCurve | None = None,
    cross_validation: CrossValidation | None = None,
    T_ground_truth: np.ndarray | None = None,
    title: str = "LiDAR-camera calibration report",
    info: Mapping[str, str] | None = None,
    on_frame: Callable[[FrameFigures, Scan], None] | None = None,
    max_width: int = 1600,
    show_valley: bool = True,
) -> dict[str, bytes]:
    """All files of the report: ``{"index.html": ..., "figures/<...>.png": ...}``.

    Parameters
    ----------
    calibration : the result (its frames carry the board fits and image corners).
    camera, board : the models used.
    sources : (name, scan, image BGR) per frame to draw, consumed one at a time (pass a generator
        that reads lazily; large panoramas then never sit in memory together).
    evaluation : the metric on the frames; computed from ``calibration`` when None.
    curve, cross_validation : optional studies (:mod:`.studies`), drawn when given.
    T_ground_truth : (4, 4) for simulated data: the result is compared with it.
    info : extra key/value lines for the header (data folder, command, version...).
    on_frame : called with each frame's :class:`FrameFigures` and scan (e.g. to write the coloured PLY).
    show_valley : draw the metrics with each parameter moved alone (:func:`.studies.valley`).
    """
    T = np.asarray(calibration.T_cam_lidar, dtype=np.float64)
    files: dict[str, bytes] = {}
    results = {f.name: f for f in calibration.frames}
    pictures: list[tuple[str, dict[str, str]]] = []
    from_scans: dict[str, EvalFrame | None] = {}
    for name, scan, image in sources:
        ff = frame_figures(name, scan, image, camera, board, T, results.get(name), max_width)
        files.update(ff.files)
        if on_frame is not None:
            on_frame(ff, scan)
        pictures.append((name, ff.captions))
        from_scans[name] = ff.eval_frame
        del ff
    efs = [e for e in (from_scans.get(f.name) or eval_frame(f) for f in calibration.frames) if e is not None]
    ev = evaluation if evaluation is not None else evaluate(efs, camera, board, T)

    def add(name: str, data: bytes) -> str:
        path = f"{FIGURES_DIR}/{name}"
        files[path] = data
        return path

    body: list[str] = [f"<h1>{_e(title)}</h1>"]
    meta = {
        "method": calibration.method,
        "camera": camera.kind,
        "image": f"{camera.width} x {camera.height}",
        "board": f"{board.rows} x {board.cols} squares of {1000 * board.square_size:.1f} mm",
    }
    meta.update(dict(info or {}))
    body.append("<p>" + " · ".join(f"<b>{_e(k)}</b>: {_e(v)}" for k, v in meta.items()) + "</p>")
    transform_html, gt_verdict = _transform_section(calibration, T_ground_truth)
    used_names = {f.name for f in calibration.frames if f.used}
    odd = _standing_out(ev, used_names)
    expected = {f.name: expected_corner_px(f, camera, board, T) for f in calibration.frames}
    ev_used = Evaluation(tuple(e for e in ev.frames if e.name in used_names), ev.T_cam_lidar)
    body.append(_summary_verdict(calibration, ev_used, odd, expected))
    if gt_verdict:
        body.append(gt_verdict)
    body.append("<h2>The result</h2>")
    body.append(transform_html)
    if sensor_html := sensors_html(calibration):
        body += ["<h2>The sensors' own errors</h2>", sensor_html]

    body.append("<h2>Frames</h2>")
    rows, classes = _frame_rows(calibration, ev, expected, {n for n, _ in pictures})
    body.append(
        _table(
            [
                "frame",
                "used",
                "fit RMS (mrad)",
                "corner RMS (px)",
                "explained (px)",
                "corner RMS (mrad)",
                "intensity error (mrad)",
                "attendance",
                "points inside",
                "mismatched",
                "range (m)",
                "image detector",
                "why dropped; what the errors suggest",
            ],
            rows,
            left=1,
            row_class=classes,
            left_last=2,
        )
    )
    body.append(_TABLE_NOTE)
    stats = [(e.intensity_mrad, e.corner_mrad, e.corner_px) for e in (ev_used, ev)]
    labels = ("intensity error (mrad)", "corner RMS (mrad)", "corner RMS (px)")
    stat_rows = [
        [label, _num(stats[0][k][0]), _num(stats[0][k][1]), _num(stats[1][k][0]), _num(stats[1][k][1])]
        for k, label in enumerate(labels)
    ]
    header = [
        "over frames",
        f"used ({len(ev_used.frames)}): mean",
        "3 sigma",
        f"all with board and corners ({len(ev.frames)}): mean",
        "3 sigma",
    ]
    body.append(_table(header, stat_rows))
    body.append(
        _img(
            add("per_frame.png", plot_per_frame(ev, used=used_names)),
            "Per-frame errors under the result.",
        )
    )
    used_efs = [e for e in efs if e.name in used_names and len(e.points_lidar)]
    if show_valley and used_efs:
        body.append(
            _img(
                add(
                    "valley.png",
                    plot_valley(valley(used_efs, camera, board, T, np.asarray(calibration.covariance))),
                ),
                "Each of the six parameters moved alone away from the result (about / along the LiDAR "
                "axes, the covariance's convention): on a right result both metrics bottom out at zero, "
                "inside the gray 3-sigma band.",
            )
        )

    if curve is not None or cross_validation is not None:
        body.append("<h2>Stability</h2>")
    if curve is not None:
        body.append(
            _img(
                add("frames_vs_parameters.png", plot_frames_vs_accuracy(curve)),
                f"Each parameter against the number of frames used (order: {', '.join(curve.order)}), "
                f"minus the {curve.reference}; band: +-3 sigma of each estimate's covariance. A right result "
                "settles on the zero line inside a band that narrows.",
            )
        )
        body.append(
            _img(
                add("frames_vs_error.png", plot_error_vs_frames(curve)),
                "The intensity re-projection error of each estimate against the number of frames used.",
            )
        )
        if curve.failures:
            body.append(
                "<p class=note>Subsets the solver refused: "
                + "; ".join(f"{n} frame(s): {_e(why)}" for n, why in curve.failures)
                + "</p>"
            )
    if cross_validation is not None:
        cvs = cross_validation.summary()
        body.append(
            f"<p>Cross-validation, {int(cvs['folds'])} folds: on frames it was not fitted on, the intensity "
            f"error is {_num(cvs['held_out_intensity_mrad_mean'])} mrad and the corner error "
            f"{_num(cvs['held_out_corner_mrad_mean'])} mrad (fitted on all: "
            f"{_num(cvs['in_sample_intensity_mrad_mean'])} and {_num(cvs['in_sample_corner_mrad_mean'])}). "
            "Similar numbers mean the result does not just fit its own frames.</p>"
        )
        body.append(
            _img(add("cross_validation.png", plot_cross_validation(cross_validation)), "Cross-validation.")
        )
        fails = [f for f in cross_validation.folds if f.failure]
        if fails:
            body.append("<p class=note>Failed folds: " + "; ".join(_e(f.failure) for f in fails) + "</p>")

    gallery: list[str] = []
    for k, (name, captions) in enumerate(pictures):
        res = results.get(name)
        status = "used" if res is not None and res.used else f"not used: {res.reason if res else 'unknown'}"
        if name in odd:
            status += "; stands out"
        figs = "".join(_img(p, c) for p, c in captions.items())
        is_open = " open" if k < 2 or name in odd or name not in used_names else ""
        gallery.append(
            f'<details id="f{_e(name)}"{is_open}><summary>Frame {_e(name)} ({_e(status)})</summary>'
            f'<div class="gallery">{figs}</div></details>'
        )
    if gallery:
        body.append("<h2>Pictures per frame</h2>")
        body.append(_GALLERY_NOTE)
        body.extend(gallery)

    page = (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>" + "\n".join(body) + "</body></html>"
    )
    files["index.html"] = page.encode("utf-8")
    return files
