"""Charts as PNG bytes (matplotlib, Agg backend; nothing is shown or written)."""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..evaluation.metric import Evaluation
from ..evaluation.studies import CrossValidation, FramesCurve, Valley

if TYPE_CHECKING:  # matplotlib is imported when a figure is drawn
    from matplotlib.figure import Figure

__all__ = [
    "plot_per_frame",
    "plot_frames_vs_accuracy",
    "plot_error_vs_frames",
    "plot_cross_validation",
    "plot_valley",
    "DrawnValley",
]

_LABELS = (
    "rotation about LiDAR x (deg)",
    "rotation about LiDAR y (deg)",
    "rotation about LiDAR z (deg)",
    "translation along LiDAR x (mm)",
    "translation along LiDAR y (mm)",
    "translation along LiDAR z (mm)",
)
_UNITS = np.array([np.degrees(1.0)] * 3 + [1000.0] * 3)


def _figure(w: float, h: float, rows: int = 1, cols: int = 1) -> tuple[Figure, np.ndarray]:
    """A figure of ``w`` x ``h`` inches and its (rows, cols) array of axes (matplotlib imported here)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=100, layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False)
    return fig, axes


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def _finite(x: np.ndarray | Sequence[float]) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    return np.where(np.isfinite(x), x, np.nan)


def plot_per_frame(evaluation: Evaluation, title: str = "", used: set[str] | None = None) -> bytes:
    """Bars per frame: the paper's intensity re-projection error and the RMS corner error.

    Dashed line: the mean over frames; dotted: mean + 3 x the standard deviation over frames.
    Frames where no board point fell inside the detected corners are marked with an x at the top;
    frames not in ``used`` (when given) are drawn gray.
    """
    names = [f.name for f in evaluation.frames]
    x = np.arange(len(names))
    fig, ax = _figure(max(6.0, 0.35 * len(names) + 2), 5.2, 2, 1)
    stats = evaluation if used is None else Evaluation(tuple(f for f in evaluation.frames if f.name in used))
    series = (
        (np.array([f.intensity_mrad for f in evaluation.frames]), stats.intensity_mrad,
         "intensity re-projection\nerror (mrad)", "tab:blue"),
        (np.array([f.corner_rms_mrad for f in evaluation.frames]), stats.corner_mrad,
         "RMS corner error (mrad)", "tab:orange"),
    )  # fmt: skip
    for a, (vals, (mean, s3), label, colour) in zip(ax[:, 0], series):
        v = _finite(vals)
        colours = [colour if used is None or n in used else "0.7" for n in names]
        a.bar(x, np.nan_to_num(v, nan=0.0), color=colours)
        top = np.nanmax(v) if np.isfinite(v).any() else 1.0
        inf = np.isinf(vals)
        if inf.any():
            a.plot(x[inf], np.full(inf.sum(), top), "rx", ms=10, label="no point inside")
            a.legend(loc="upper right", fontsize=8)
        if np.isfinite(mean):
            a.axhline(mean, ls="--", color="k", lw=1)
            if np.isfinite(s3):
                a.axhline(mean + s3, ls=":", color="k", lw=1)
            what = "" if used is None else " over the used frames (gray: not used)"
            a.set_title(f"mean {mean:.3g}, 3 x SD over frames {s3:.3g}{what}", fontsize=9, loc="right")
        a.set_ylabel(label)
        a.set_xticks(x, names, rotation=90, fontsize=8)
        a.grid(axis="y", alpha=0.3)
    if title:
        fig.suptitle(title)
    return _png(fig)


def plot_frames_vs_accuracy(curve: FramesCurve) -> bytes:
    """The six parameters against the number of frames (paper Fig. 15), with our 3 sigma band.

    Each panel shows the estimate minus the reference (ground truth or the all-frames estimate) as
    a tangent vector at the reference, and the band +-3 sigma of that estimate's covariance.
    """
    from matplotlib.ticker import MaxNLocator

    fig, ax = _figure(11.0, 6.0, 2, 3)
    n = curve.n_frames
    for k in range(6):
        a = ax[k // 3, k % 3]
        y = curve.offset[:, k] * _UNITS[k]
        s = curve.sigma[:, k] * _UNITS[k]
        if np.isfinite(s).any():
            a.fill_between(n, y - 3 * s, y + 3 * s, color="tab:blue", alpha=0.25, lw=0, label="+-3 sigma")
        a.plot(n, y, "o-", color="tab:blue", ms=3, label="estimate")
        a.axhline(0.0, color="k", lw=1, label=curve.reference)
        a.set_title(_LABELS[k], fontsize=10)
        a.set_xlabel("frames used")
        a.xaxis.set_major_locator(MaxNLocator(integer=True))
        a.grid(alpha=0.3)
        if len(n):
            half = max(1, len(y) // 2)
            lim = 4 * np.nanmax(np.abs(np.concatenate([y[-half:], 3 * s[-half:]])))
            if np.isfinite(lim) and lim > 0:
                # early, wild estimates are drawn as triangles at the edge; the converged ones stay legible
                a.set_ylim(-lim, lim)
                hi, lo = y > lim, y < -lim
                a.plot(n[hi], np.full(hi.sum(), 0.93 * lim), "^", color="tab:red", ms=7)
                a.plot(n[lo], np.full(lo.sum(), -0.93 * lim), "v", color="tab:red", ms=7)
    ax[0, 0].legend(fontsize=8, loc="upper right")
    fig.suptitle(
        f"Estimate minus {curve.reference} against the number of frames "
        "(band: 3 sigma; red triangles: off the scale)"
    )
    return _png(fig)


def plot_error_vs_frames(curve: FramesCurve) -> bytes:
    """The intensity re-projection error of each estimate against the number of frames (paper
    Fig. 14c): mean over all frames and mean + 3 x SD over frames, and the mean over the frames not used
    for that estimate. Log scale: early estimates may be off by orders of magnitude."""
    from matplotlib.ticker import MaxNLocator

    fig, ax = _figure(7.0, 4.0)
    a = ax[0, 0]
    n = curve.n_frames
    m, s3 = _finite(curve.error_mean), _finite(curve.error_3sigma)
    a.plot(n, m, "o-", ms=3, label="all frames: mean")
    a.plot(n, m + np.nan_to_num(s3), ":", color="tab:blue", label="all frames: mean + 3 x SD over frames")
    a.plot(n, _finite(curve.heldout_mean), "s--", ms=3, label="frames not used for the fit: mean")
    a.set_xlabel("frames used")
    a.set_ylabel("intensity re-projection error (mrad)")
    if np.any(m > 0):
        from matplotlib.ticker import FormatStrFormatter

        a.set_yscale("log")
        a.yaxis.set_major_formatter(FormatStrFormatter("%g"))
        a.yaxis.set_minor_formatter(FormatStrFormatter("%g"))
    a.xaxis.set_major_locator(MaxNLocator(integer=True))
    a.grid(alpha=0.3, which="both")
    a.legend(fontsize=8)
    return _png(fig)


def plot_cross_validation(cv: CrossValidation) -> bytes:
    """Left: each frame's error under the fit that did not see it vs the all-frames fit.
    Right: each fold's estimate minus the all-frames estimate, with that fold's 3 sigma."""
    fig, ax = _figure(13.0, 4.2, 1, 3)
    a = ax[0, 0]
    names = [f.name for f in cv.held_out.frames]
    x = np.arange(len(names))
    held = _finite([f.intensity_mrad for f in cv.held_out.frames])
    ins = _finite([f.intensity_mrad for f in cv.in_sample.frames])
    a.bar(x - 0.2, np.nan_to_num(ins), 0.4, label="fit on all frames")
    a.bar(x + 0.2, np.nan_to_num(held), 0.4, label="fit without this frame")
    a.set_xticks(x, names, rotation=90, fontsize=8)
    a.set_ylabel("intensity re-projection error (mrad)")
    a.legend(fontsize=8)
    a.grid(axis="y", alpha=0.3)
    ok = [f for f in cv.folds if f.offset is not None]
    for b, sl, unit, lab in (
        (ax[0, 1], slice(0, 3), np.degrees(1.0), ("rx", "ry", "rz")),
        (ax[0, 2], slice(3, 6), 1000.0, ("tx", "ty", "tz")),
    ):
        for j, f in enumerate(ok):
            y = f.offset[sl] * unit  # type: ignore[index]
            cov = f.covariance if f.covariance is not None else np.full((6, 6), np.nan)
            s = np.sqrt(np.clip(np.diag(cov)[sl], 0, None)) * unit
            xs = np.arange(3) + (j - (len(ok) - 1) / 2) * 0.7 / max(len(ok), 1)
            b.errorbar(xs, y, yerr=3 * s, fmt="o", ms=3, capsize=2, label=f"fold {j + 1}")
        b.axhline(0, color="k", lw=1)
        b.set_xticks(np.arange(3), lab)
        b.set_ylabel("deg" if unit != 1000.0 else "mm")
        b.grid(alpha=0.3)
    ax[0, 1].set_title("fold estimate minus all-frames estimate (bar: 3 sigma)", fontsize=10, loc="left")
    if ok and len(ok) <= 10:
        ax[0, 2].legend(fontsize=7, ncol=2)
    return _png(fig)


@dataclass(frozen=True)
class DrawnValley:
    """The valley study with its chart drawn already (``plot_valley``'s PNG; e.g. by a worker process
    right after the study, while the report's other parts are made)."""

    study: Valley
    png: bytes


def plot_valley(v: Valley) -> bytes:
    """Each parameter moved alone around the estimate: both metrics should bottom out at zero.

    Left axis (blue): the paper's intensity error; right axis (orange): the RMS corner error;
    gray band: +-3 sigma of the estimate.
    """
    fig, ax = _figure(11.0, 5.6, 2, 3)
    for k in range(6):
        a = ax[k // 3, k % 3]
        x = v.offsets[k] * _UNITS[k]
        if np.isfinite(v.sigma[k]):
            a.axvspan(-3 * v.sigma[k] * _UNITS[k], 3 * v.sigma[k] * _UNITS[k], color="0.85", lw=0)
        a.plot(x, _finite(v.intensity[k]), "o-", ms=3, color="tab:blue")
        a.set_ylim(bottom=0)
        a.tick_params(axis="y", colors="tab:blue")
        b = a.twinx()
        b.plot(x, _finite(v.corner[k]), "s--", ms=3, color="tab:orange")
        b.set_ylim(bottom=0)
        b.tick_params(axis="y", colors="tab:orange")
        a.axvline(0.0, color="k", lw=1)
        a.set_title("moved: " + _LABELS[k], fontsize=10)
        a.grid(alpha=0.3)
        if k % 3 == 0:
            a.set_ylabel("intensity error (mrad)", color="tab:blue")
        if k % 3 == 2:
            b.set_ylabel("RMS corner error (mrad)", color="tab:orange")
    fig.suptitle("The metrics with one parameter moved away from the result (gray: 3 sigma)")
    return _png(fig)
