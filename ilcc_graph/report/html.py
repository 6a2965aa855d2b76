"""The report: ``index.html`` with its figures, returned as ``{relative path: bytes}``.

The caller (the command line) writes the files under ``OUT/report/``; nothing here touches the
disk. The page is self-contained and offline: inline CSS, no scripts, the frames' pictures as
compressed files (WebP) and the charts as PNG in ``figures/`` beside it. The page's parts are in
``sections``, a frame's pictures in ``figures``.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ..board import Board
from ..cameras import CameraModel
from ..evaluation.frame_errors import eval_frame, evaluate, expected_corner_px
from ..evaluation.metric import EvalFrame, Evaluation
from ..evaluation.studies import CrossValidation, FramesCurve, Valley, valley
from ..image.previews import WHOLE_WIDTH
from ..types import Calibration, FrameResult, Scan
from .figures import FIGURES_DIR, FigureOptions, FrameFigures, frame_figures
from .plots import (
    DrawnValley,
    plot_cross_validation,
    plot_error_vs_frames,
    plot_frames_vs_accuracy,
    plot_per_frame,
    plot_valley,
)
from .sections import (
    GALLERY_NOTE,
    TABLE_NOTE,
    esc,
    figure,
    frame_rows,
    num,
    page,
    standing_out,
    summary_verdict,
    table,
    transform_section,
)
from .sensors import sensors_html, square_size_text

__all__ = ["FIGURES_DIR", "FigureOptions", "FrameFigures", "build_report", "frame_figures"]


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
    max_width: int = WHOLE_WIDTH,
    show_valley: bool = True,
    figures: Iterable[FrameFigures] = (),
    figure_options: FigureOptions = FigureOptions(),
    valley_study: Valley | DrawnValley | Callable[[], Valley | DrawnValley | None] | None = None,
    next_pose: tuple[bytes, str] | None = None,
) -> dict[str, bytes]:
    """All files of the report: ``{"index.html": ..., "figures/<...>.webp|png": ...}``.

    Parameters
    ----------
    calibration : the result (its frames carry the board fits and image corners).
    camera, board : the models used.
    sources : (name, scan, image BGR or None) per frame to draw, consumed one at a time (pass a
        generator that reads lazily; None: the views the image stage kept suffice, see ``figures``).
    figures : frames' pictures drawn already (``figures.frame_figures``, e.g. in other processes),
        consumed one at a time, after ``sources``. figure_options: how ``sources`` are drawn.
    evaluation : the metric on the frames; computed from ``calibration`` when None.
    curve, cross_validation : optional studies (:mod:`.studies`), drawn when given.
    T_ground_truth : (4, 4) for simulated data: the result is compared with it.
    info : extra key/value lines for the header (data folder, command, version...).
    on_frame : called with each frame's :class:`FrameFigures` and scan (e.g. to write the coloured PLY).
    show_valley : draw the metrics with each parameter moved alone (:func:`.studies.valley`);
        ``valley_study``: that study computed already (or with its chart drawn: ``plots.DrawnValley``),
        or a callable that gives it (e.g. a future's ``result`` of another process; None: computed here).
    next_pose : (``next_pose.png``'s bytes, its advice) of the next board pose to take, or None.
    """
    T = np.asarray(calibration.T_cam_lidar, dtype=np.float64)
    results = {f.name: f for f in calibration.frames}

    def drawn() -> Iterable[tuple[FrameFigures, Scan | None]]:
        for name, scan, image in sources:
            opts = figure_options
            yield frame_figures(name, scan, image, camera, board, T, results.get(name), max_width, opts), scan
        for ff in figures:
            yield ff, None

    got = _collect(drawn(), on_frame)
    files = got.files
    efs = [
        e for e in (got.from_scans.get(f.name) or eval_frame(f) for f in calibration.frames) if e is not None
    ]
    ev = evaluation if evaluation is not None else evaluate(efs, camera, board, T)

    def add(name: str, data: bytes) -> str:
        path = f"{FIGURES_DIR}/{name}"
        files[path] = data
        return path

    used_names = {f.name for f in calibration.frames if f.used}
    odd = standing_out(ev, used_names)
    expected = {f.name: expected_corner_px(f, camera, board, T) for f in calibration.frames}
    ev_used = Evaluation(tuple(e for e in ev.frames if e.name in used_names), ev.T_cam_lidar)
    body = _head_html(calibration, camera, board, title, info, T_ground_truth, ev_used, odd, expected)
    body += _frames_html(calibration, ev, ev_used, expected, {n for n, _ in got.pictures})
    body.append(
        figure(
            add("per_frame.png", plot_per_frame(ev, used=used_names)),
            "Per-frame errors under the result.",
        )
    )
    used_efs = [e for e in efs if e.name in used_names and len(e.points_lidar)]
    study = (valley_study() if callable(valley_study) else valley_study) if show_valley else None
    if show_valley and study is None and used_efs:
        study = valley(used_efs, camera, board, T, np.asarray(calibration.covariance))
    body += _valley_html(study, add) + _next_pose_html(next_pose, add)
    body += _stability_html(curve, cross_validation, add)
    body += _gallery_html(got, results, odd, used_names)
    files["index.html"] = page(title, body)
    return files


def _head_html(
    calibration: Calibration,
    camera: CameraModel,
    board: Board,
    title: str,
    info: Mapping[str, str] | None,
    T_ground_truth: np.ndarray | None,
    ev_used: Evaluation,
    odd: list[str],
    expected: dict[str, float],
) -> list[str]:
    """The page's title, its header line, the verdict and the result with the sensors' errors."""
    body: list[str] = [f"<h1>{esc(title)}</h1>"]
    meta = {
        "method": calibration.method,
        "camera": camera.kind,
        "image": f"{camera.width} x {camera.height}",
        "board": f"{board.rows} x {board.cols} squares of {1000 * board.square_size:.1f} mm",
    }
    meta.update(dict(info or {}))
    body.append("<p>" + " · ".join(f"<b>{esc(k)}</b>: {esc(v)}" for k, v in meta.items()) + "</p>")
    transform_html, gt_verdict = transform_section(calibration, T_ground_truth)
    body.append(summary_verdict(calibration, ev_used, odd, expected))
    if gt_verdict:
        body.append(gt_verdict)
    body.append("<h2>The result</h2>")
    body.append(transform_html)
    if scale_line := square_size_text(calibration):
        body.append(f"<p>{esc(scale_line)}</p>")
    if sensor_html := sensors_html(calibration):
        body += ["<h2>The sensors' own errors</h2>", sensor_html]
    return body


def _valley_html(study: Valley | DrawnValley | None, add: Callable[[str, bytes], str]) -> list[str]:
    """The valley study's chart (stored with ``add``; drawn here unless it was), or nothing."""
    if study is None:
        return []
    return [
        figure(
            add("valley.png", study.png if isinstance(study, DrawnValley) else plot_valley(study)),
            "Each of the six parameters moved alone away from the result (about / along the LiDAR "
            "axes, the covariance's convention): on a right result both metrics bottom out at zero, "
            "inside the gray 3-sigma band.",
        )
    ]


def _next_pose_html(next_pose: tuple[bytes, str] | None, add: Callable[[str, bytes], str]) -> list[str]:
    """Where to hold the board next: the advice and its picture (stored with ``add``), or nothing."""
    if next_pose is None:
        return []
    caption = (
        "The rig from above and from the side (LiDAR frame): the boards so far (blue, numbered) and "
        "the proposed next pose (red); next_pose.png beside calibration.yaml."
    )
    return [
        "<h2>Where to hold the board next</h2>",
        f"<p>{esc(next_pose[1])}</p>",
        figure(add("next_pose.png", next_pose[0]), caption),
    ]


@dataclass
class _Collected:
    """The frames' pictures gathered: every file, per frame its captions (in order), the board
    points rebuilt from its scan and its full-resolution view's path (when drawn)."""

    files: dict[str, bytes] = field(default_factory=dict)
    pictures: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    from_scans: dict[str, EvalFrame | None] = field(default_factory=dict)
    full: dict[str, str] = field(default_factory=dict)


def _collect(
    drawn: Iterable[tuple[FrameFigures, Scan | None]], on_frame: Callable[[FrameFigures, Scan], None] | None
) -> _Collected:
    """The frames' pictures as they come (one frame's held at a time), ``on_frame`` on each with its scan."""
    got = _Collected()
    for ff, scan in drawn:
        got.files.update(ff.files)
        if on_frame is not None and scan is not None:
            on_frame(ff, scan)
        got.pictures.append((ff.name, ff.captions))
        got.from_scans[ff.name] = ff.eval_frame
        if ff.full is not None:
            got.full[ff.name] = ff.full
        del ff
    return got


def _frames_html(
    calibration: Calibration,
    ev: Evaluation,
    ev_used: Evaluation,
    expected: dict[str, float],
    pictured: set[str],
) -> list[str]:
    """The "Frames" section: the per-frame table and the statistics over frames (used, all)."""
    body = ["<h2>Frames</h2>"]
    rows, classes = frame_rows(calibration, ev, expected, pictured)
    body.append(
        table(
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
    body.append(TABLE_NOTE)
    stats = [(e.intensity_mrad, e.corner_mrad, e.corner_px) for e in (ev_used, ev)]
    labels = ("intensity error (mrad)", "corner RMS (mrad)", "corner RMS (px)")
    stat_rows = [
        [label, num(stats[0][k][0]), num(stats[0][k][1]), num(stats[1][k][0]), num(stats[1][k][1])]
        for k, label in enumerate(labels)
    ]
    header = [
        "over frames",
        f"used ({len(ev_used.frames)}): mean",
        "3 x SD over frames",
        f"all with board and corners ({len(ev.frames)}): mean",
        "3 x SD over frames",
    ]
    body.append(table(header, stat_rows))
    return body


def _stability_html(
    curve: FramesCurve | None, cross_validation: CrossValidation | None, add: Callable[[str, bytes], str]
) -> list[str]:
    """The "Stability" section (the studies' charts, each stored with ``add``), empty without them."""
    body: list[str] = []
    if curve is not None or cross_validation is not None:
        body.append("<h2>Stability</h2>")
    if curve is not None:
        body.append(
            figure(
                add("frames_vs_parameters.png", plot_frames_vs_accuracy(curve)),
                f"Each parameter against the number of frames used (order: {', '.join(curve.order)}), "
                f"minus the {curve.reference}; band: +-3 sigma of each estimate's covariance. A right result "
                "settles on the zero line inside a band that narrows.",
            )
        )
        body.append(
            figure(
                add("frames_vs_error.png", plot_error_vs_frames(curve)),
                "The intensity re-projection error of each estimate against the number of frames used.",
            )
        )
        if curve.failures:
            body.append(
                "<p class=note>Subsets the solver refused: "
                + "; ".join(f"{n} frame(s): {esc(why)}" for n, why in curve.failures)
                + "</p>"
            )
    if cross_validation is not None:
        cvs = cross_validation.summary()
        body.append(
            f"<p>Cross-validation, {int(cvs['folds'])} folds: on frames it was not fitted on, the intensity "
            f"error is {num(cvs['held_out_intensity_mrad_mean'])} mrad and the corner error "
            f"{num(cvs['held_out_corner_mrad_mean'])} mrad (fitted on all: "
            f"{num(cvs['in_sample_intensity_mrad_mean'])} and {num(cvs['in_sample_corner_mrad_mean'])}). "
            "Similar numbers mean the result does not just fit its own frames.</p>"
        )
        body.append(
            figure(add("cross_validation.png", plot_cross_validation(cross_validation)), "Cross-validation.")
        )
        fails = [f for f in cross_validation.folds if f.failure]
        if fails:
            body.append("<p class=note>Failed folds: " + "; ".join(esc(f.failure) for f in fails) + "</p>")
    return body


def _gallery_html(
    got: _Collected, results: Mapping[str, FrameResult], odd: Collection[str], used_names: set[str]
) -> list[str]:
    """The "Pictures per frame" section: one folding entry per frame drawn, empty without pictures."""
    gallery: list[str] = []
    for k, (name, captions) in enumerate(got.pictures):
        res = results.get(name)
        status = "used" if res is not None and res.used else f"not used: {res.reason if res else 'unknown'}"
        if name in odd:
            status += "; stands out"
        figs = "".join(figure(p, c) for p, c in captions.items())
        if name in got.full:
            link = f'<a href="{esc(got.full[name])}">the whole picture at full resolution</a>'
            figs += f'<p class="note">{link}</p>'
        is_open = " open" if k < 2 or name in odd or name not in used_names else ""
        gallery.append(
            f'<details id="f{esc(name)}"{is_open}><summary>Frame {esc(name)} ({esc(status)})</summary>'
            f'<div class="gallery">{figs}</div></details>'
        )
    if not gallery:
        return []
    return ["<h2>Pictures per frame</h2>", GALLERY_NOTE, *gallery]
