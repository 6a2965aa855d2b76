"""The report of a run's session written into a staging folder (``app.write.write_run``): the one
place where the report's pictures are drawn from the data and its files land on disk.

The frames' pictures are drawn on the views the image stage kept (no picture is read again), on
the run's worker processes (``workers.pool``) while the caller's ``meanwhile`` runs here; the
coloured clouds and full-resolution views on request. The studies that solve again (accuracy
against frames, cross-validation) are a step of the run (``run.refit_studies``), handed in as
data. ``report`` itself only turns these into files' bytes (``build_report``,
``rig_report_files``).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ilcc_graph import signals, workers
from ilcc_graph.config import Config
from ilcc_graph.config.rig_config import solved_camera
from ilcc_graph.io import write_ply
from ilcc_graph.io.rig_results import RigCalibration
from ilcc_graph.report.rig_report import RigImages, RigSeen, rig_report_files

if TYPE_CHECKING:
    from concurrent.futures import Future, ProcessPoolExecutor

    from ilcc_graph.board import Board
    from ilcc_graph.cameras import CameraModel
    from ilcc_graph.datasets import FrameRef, FrameSource
    from ilcc_graph.evaluation.studies import CrossValidation, FramesCurve
    from ilcc_graph.next_pose import Proposal
    from ilcc_graph.report import FigureOptions, FrameFigures
    from ilcc_graph.report.plots import DrawnValley
    from ilcc_graph.run.result import Result, SessionResult
    from ilcc_graph.types import Calibration, FrameResult

__all__ = ["write_report", "write_rig_report"]


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
    from ilcc_graph.evaluation import eval_frame
    from ilcc_graph.evaluation.studies import valley
    from ilcc_graph.report.plots import DrawnValley, plot_valley

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
    studies: tuple[FramesCurve, CrossValidation] | None,
    truth: np.ndarray | None,
    info: dict,
    clouds: bool = False,
    full_views: bool = False,
    meanwhile: Callable[[], Proposal | None] | None = None,
    next_pose: Proposal | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[Proposal | None, bytes | None]:
    """``out/index.html`` with its figures for one session; with ``clouds`` ``coloured_dir/<frame>.ply``.
    The frames' pictures need the pair's source (``Observation.pair_source``): without one the page
    has none.
    ``studies``: the run's refit studies of this session (``run.refit_studies``) or None.
    ``meanwhile()`` runs here while the pictures are drawn on other processes and gives the next board
    pose (``next_pose.Proposal`` or None; else ``next_pose`` is it), drawn in the report. Returns
    (that proposal, its picture ``next_pose.png`` or None). ``progress(done, total)``: after each
    frame's pictures, and once more when the page is built."""
    from ilcc_graph.report import FigureOptions, build_report
    from ilcc_graph.report.next_pose_picture import next_pose_png

    obs, cal = session.observation, session.calibration
    config, source = obs.pair_config, obs.pair_source  # the camera as solved (refined intrinsics):
    config = dataclasses.replace(config, camera=solved_camera(config.camera, cal.sensors))
    curve, cv = studies if studies is not None else (None, None)
    damaged = {f.name for f in cal.frames if f.damaged}  # their files cannot be read
    frames = source.frames() if source is not None else []  # no pair's source: no frame's pictures
    refs = [r for r in frames if r.scan is not None and r.image is not None and r.name not in damaged]
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
    _write_files(out, files)
    return got, png


def _write_files(folder: Path, files: dict[str, bytes]) -> None:
    """``files`` (path in ``folder``: bytes) into a staging folder: written plainly (no fsync each)."""
    for rel, blob in files.items():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_bytes(blob)


def write_rig_report(
    folder: Path,
    cal: RigCalibration,
    observation: RigSeen,
    source: RigImages | None,
    info: dict[str, str],
    *,
    need: tuple[float, float] | None = None,
) -> Path:
    """Write ``folder/index.html`` and its pictures ``folder/figures/*.webp`` (``rig_report_files``);
    returns the page's path. ``folder`` is made when missing (a staging folder: written plainly)."""
    _write_files(Path(folder), rig_report_files(cal, observation, source, info, need=need))
    return Path(folder) / "index.html"
