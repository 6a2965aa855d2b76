"""The report of one session of a run, written into a staging folder (``app.write.write_run``).

The frames' pictures are drawn on the views the image stage kept (no picture is read again), on
the run's worker processes (``workers.pool``) while the caller's ``meanwhile`` runs here; the
report's studies (accuracy against frames, cross-validation) on request; the coloured clouds and
full-resolution views on request. The run's result types are named for the type checker only and
the studies' solver comes from the caller (``refit``: ``run.pipeline.solve_observed``), so ``report``
does not import the run.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ilcc_graph import signals, workers
from ilcc_graph.config import Config
from ilcc_graph.io import write_ply

if TYPE_CHECKING:
    from concurrent.futures import Future, ProcessPoolExecutor

    from ilcc_graph.board import Board
    from ilcc_graph.cameras import CameraModel
    from ilcc_graph.datasets import FrameRef, FrameSource
    from ilcc_graph.next_pose import Proposal
    from ilcc_graph.report import FigureOptions, FrameFigures
    from ilcc_graph.report.plots import DrawnValley
    from ilcc_graph.report.studies import CrossValidation, FramesCurve
    from ilcc_graph.run.result import Result, RunOptions, SessionResult
    from ilcc_graph.types import Calibration, FrameResult

__all__ = ["write_report"]


def _draw_frame(
    source: FrameSource, ref: FrameRef, config: Config, T: np.ndarray, result: FrameResult | None,
    options: FigureOptions, ply: Path | None,
) -> FrameFigures:  # fmt: skip
    """One frame's pictures (``report.frame_figures``; a worker process may run it): the scan is read,
    the image only when the image stage kept no views of it or the options need it; with ``ply``
    the coloured cloud is written there."""
    from ilcc_graph.report import frame_figures

    scan = source.read_scan(ref, config)
    kept = result is not None and result.corners is not None and bool(result.corners.views)
    image = source.read_image(ref) if (not kept or options.colours or options.full_views) else None
    ff = frame_figures(ref.name, scan, image, config.camera, config.board, T, result, options=options)
    if ply is not None and ff.coloured is not None:
        write_ply(ply, scan, rgb=ff.coloured.rgb)
    return dataclasses.replace(ff, coloured=None)


def _valley(cal: Calibration, camera: CameraModel, board: Board) -> DrawnValley | None:
    """The report's valley study on the used frames (as ``report.build_report`` makes it) with its
    chart drawn (a worker process runs it while the main process works out the next pose), or
    None when a used frame lacks its board points (the report then rebuilds them from the scans)."""
    from ilcc_graph.report import eval_frame
    from ilcc_graph.report.plots import DrawnValley, plot_valley
    from ilcc_graph.report.studies import valley

    got = [eval_frame(f) for f in cal.frames if f.used]
    efs = [e for e in got if e is not None and len(e.points_lidar)]
    if not got or len(efs) < len(got):
        return None
    study = valley(efs, camera, board, np.asarray(cal.T_cam_lidar), np.asarray(cal.covariance))
    return DrawnValley(study, plot_valley(study))


def _drawn(
    items: list[tuple], pool: ProcessPoolExecutor | None, cal: Calibration, config: Config
) -> tuple[Iterator[FrameFigures], Future[DrawnValley | None] | None]:
    """(``_draw_frame(*item)`` for each item in order, a future of the valley study with its chart), on
    ``pool`` (``workers.pool``; in this process when None); the valley study, the longest single job,
    goes first."""
    if pool is None:
        return (_draw_frame(*it) for it in items), None
    slim = dataclasses.replace(
        cal,
        frames=tuple(
            dataclasses.replace(f, corners=dataclasses.replace(f.corners, views=())) if f.corners else f
            for f in cal.frames
        ),
    )
    study = pool.submit(_valley, slim, config.camera, config.board)
    futures = [pool.submit(_draw_frame, *it) for it in items]

    def results() -> Iterator[FrameFigures]:
        for fut in futures:
            yield fut.result()
            signals.check()

    return results(), study


def _counted(items: Iterator, total: int, progress: Callable[[int, int], None]) -> Iterator:
    """``items`` with ``progress(k, total)`` after the k-th."""
    for k, item in enumerate(items, 1):
        yield item
        progress(k, total)


def write_report(
    out: Path,
    coloured_dir: Path,
    session: SessionResult,
    result: Result,
    studies: bool,
    truth: np.ndarray | None,
    info: dict,
    clouds: bool = False,
    full_views: bool = False,
    meanwhile: Callable[[], Proposal | None] | None = None,
    next_pose: Proposal | None = None,
    progress: Callable[[int, int], None] | None = None,
    *,
    refit: Callable[[Sequence[FrameResult], Config, RunOptions], Calibration],
) -> tuple[Proposal | None, bytes | None]:
    """``out/index.html`` with its figures for one session; with ``clouds`` ``coloured_dir/<frame>.ply``.
        ``meanwhile()`` runs here while the pictures are drawn on other processes and gives the next board
        pose (``next_pose.Proposal`` or None; else ``next_pose`` is it), drawn in the report. Returns
        (that proposal, its picture ``next_pose.png`` or None). ``progress(done, total)``: after each
        frame's pictures, and once more when the page is built. ``refit(frames, config, options)``: a
    subset of the frames solved again (``run.pipeline.solve_observed``), for the studies."""
    from ilcc_graph.report import FigureOptions, build_report
    from ilcc_graph.report.next_pose_picture import next_pose_png

    obs, cal = session.observation, session.calibration
    config, source = obs.config, obs.source
    curve = cv = None
    if studies and result.covariance is not None:  # the studies: batch refits of subsets
        curve, cv = _studies(obs.frames, config, cal, dataclasses.replace(result.options, mode="graph"),
                             truth, refit)  # fmt: skip
    damaged = {f.name for f in cal.frames if f.damaged}  # their files cannot be read
    refs = [
        r for r in source.frames() if r.scan is not None and r.image is not None and r.name not in damaged
    ]
    results = {f.name: f for f in cal.frames}
    fig_opts = FigureOptions(colours=clouds, full_views=full_views)
    if clouds:
        coloured_dir.mkdir(parents=True, exist_ok=True)
    T = np.asarray(cal.T_cam_lidar)
    items = [
        (
            source,
            r,
            config,
            T,
            results.get(r.name),
            fig_opts,
            coloured_dir / f"{r.name}.ply" if clouds else None,
        )
        for r in refs
    ]
    jobs = min(result.options.stages.jobs, len(items))
    with workers.pool(jobs) if jobs > 1 else contextlib.nullcontext() as pool:
        figures, study = _drawn(items, pool, cal, config)
        if progress is not None:
            figures = _counted(figures, len(items) + 1, progress)
        got = meanwhile() if meanwhile is not None else next_pose
        png = None if got is None else next_pose_png(got)
        files = build_report(
            cal,
            config.camera,
            config.board,
            figures=figures,
            curve=curve,
            cross_validation=cv,
            T_ground_truth=truth,
            info=info,
            valley_study=None if study is None else study.result,
            next_pose=None if got is None or png is None else (png, got.describe()),
        )
    if progress is not None:
        progress(len(items) + 1, len(items) + 1)
    for rel, blob in files.items():  # inside the staging folder: written plainly (no fsync each)
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        (out / rel).write_bytes(blob)
    return got, png


def _studies(
    frames: Sequence[FrameResult],
    config: Config,
    cal: Calibration,
    options: RunOptions,
    truth: np.ndarray | None,
    refit: Callable[[Sequence[FrameResult], Config, RunOptions], Calibration],
) -> tuple[FramesCurve, CrossValidation]:
    """The report's studies: each parameter against the number of frames, and a 5-fold
    cross-validation, the subsets solved again with ``refit`` (their warnings kept quiet)."""
    from ilcc_graph.report import cross_validate, frames_vs_accuracy

    def solve(subset: Sequence[FrameResult]) -> tuple[np.ndarray, np.ndarray]:
        c = refit(subset, config, options)
        return c.T_cam_lidar, c.covariance

    quiet = logging.getLogger("ilcc_graph")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # subsets of few frames warn by design
    try:
        curve = frames_vs_accuracy(frames, solve, config.camera, config.board, truth)
        cv = cross_validate(frames, solve, config.camera, config.board, folds=5, T_all=cal.T_cam_lidar)
    finally:
        quiet.setLevel(level)
    return curve, cv
