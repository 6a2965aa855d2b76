"""The one writer of a run's results, for every mode.

``write_run(out, result, ...)`` writes, into a staging folder that replaces ``out`` only when
everything is written (so ``out`` is either the complete result or untouched):

- ``calibration.yaml``: the extrinsic, its covariance, every frame's fate and the camera model
  (interface.md; everything ``export`` needs); a rig's: every sensor's pose and their joint
  covariance (``Result.rig`` serialised by ``io.rig_results``; docs/rig.md);
- ``config.resolved.yaml``: the configuration used (print colour as checked, LiDAR model as
  resolved) in our schema, plus ``options``: every stage and solver option of the run;
- a strategy's further documents (``Result.documents``: sessions' ``joint.yaml`` with the tests
  and offsets, incremental's ``incremental.yaml`` with the state after each frame); for several
  sessions ``sessions/<name>/`` with each session's own ``calibration.yaml`` and
  ``config.resolved.yaml``;
- unless ``report=False``: ``report/index.html`` (one per session under ``report/<name>/`` when
  there are several), its pictures drawn on the views the image stage kept (no picture is read
  again), on ``jobs`` processes; on request (``clouds``) the coloured clouds ``coloured/<frame>.ply``
  and (``full_views``) the whole pictures at full resolution;
- with a proposal and the report: ``next_pose.png``; ``check``: ``check.yaml`` (and ``next_pose.png``
  with a proposal); a failed run: ``failure.yaml``.

It reads only ``run.result.Result`` (no strategy's own types). The folder mechanics (staging, the
locked commit) are ``io.output_folders``; the report's pictures ``app.report_writer``; the studies
that solve again ``run.refit_studies`` (a step of the run, handed to the report as data).
"""

from __future__ import annotations

import logging
import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ilcc_graph.app.report_writer import write_report, write_rig_report
from ilcc_graph.config import Config, RigConfig, config_to_dict, rig_config_to_dict
from ilcc_graph.errors import OutputError
from ilcc_graph.io import atomic_write, write_calibration, write_yaml
from ilcc_graph.io.output_folders import OURS, add_file, staged, write_beside
from ilcc_graph.io.rig_results import write_rig_calibration
from ilcc_graph.report.next_pose_picture import next_pose_png
from ilcc_graph.run.refit_studies import refit_studies
from ilcc_graph.run.result import Result, RunOptions
from ilcc_graph.types import sigma_dict, to_plain

if TYPE_CHECKING:
    from ilcc_graph.datasets import FrameRef, FrameSource
    from ilcc_graph.next_pose import Proposal
    from ilcc_graph.run.live import CheckResult

log = logging.getLogger(__name__)

__all__ = [
    "options_dict",
    "resolved_config",
    "write_check",
    "write_evaluation",
    "write_failure",
    "write_run",
    "write_stage",
]


def options_dict(options: RunOptions) -> dict[str, Any]:
    """Every option of a run as plain data (stages, noise policy, joint settings, mode)."""
    return to_plain(options)


def resolved_config(config: Config | RigConfig, options: RunOptions) -> dict[str, Any]:
    """config.resolved.yaml: the config used (a pair's, or a rig's as rig.yaml), in our schema, with
    the run's ``options``."""
    d = rig_config_to_dict(config) if isinstance(config, RigConfig) else config_to_dict(config)
    d["options"] = options_dict(options)
    return d


def write_evaluation(out: Path, evaluation: Any, flag: str = "--out", command: str = "") -> Path:
    """``out/evaluation.yaml`` (``report.evaluation_to_dict``) in a new or empty folder, or added to an
    earlier result of ours (``io.output_folders.add_file``); returns its path."""
    from ilcc_graph.evaluation import evaluation_to_dict
    from ilcc_graph.io import dump_yaml

    text = dump_yaml(evaluation_to_dict(evaluation))
    return add_file(Path(out), "evaluation.yaml", text, flag, command)


def write_run(
    out: Path,
    result: Result,
    *,
    report: bool = True,
    studies: bool = False,
    truth: np.ndarray | None = None,
    command: str = "",
    next_pose: Proposal | Callable[[], Proposal | None] | None = None,
    clouds: bool = False,
    full_views: bool = False,
    progress: Callable[[str], Callable[[int, int], None]] | None = None,
) -> Path:
    """Write every output of ``result`` to ``out`` (module docstring); returns ``out``. With a
    ``next_pose`` proposal and the report also ``next_pose.png`` (the rig, the boards, the proposal;
    a callable is called while the report's pictures are drawn on other processes, and without the
    report still called: the summary says the proposal), shown in the report too;
    ``clouds``: the coloured clouds; ``full_views``: the report's whole pictures at full resolution too;
    ``progress(name)``: a ``(done, total)`` callback for each session's report (``console.Progress``)."""
    later = next_pose if callable(next_pose) else None
    proposal: Proposal | None = None if callable(next_pose) else next_pose
    png: bytes | None = None
    with staged(out, command=command) as d:
        if result.rig is None:
            write_calibration(d / "calibration.yaml", result.calibration)
        else:  # a rig's: every sensor's pose (docs/rig.md), serialised here and only here
            write_rig_calibration(d / "calibration.yaml", result.rig)
        first = result.sessions[0].observation.config
        write_yaml(d / "config.resolved.yaml", resolved_config(first, result.options))
        for name, doc in result.documents.items():  # a strategy's further results (joint.yaml, ...)
            write_yaml(d / name, doc)
        if result.per_session:
            for s in result.sessions:
                write_calibration(d / "sessions" / s.name / "calibration.yaml", s.calibration)
                write_yaml(
                    d / "sessions" / s.name / "config.resolved.yaml",
                    resolved_config(s.observation.config, result.options),
                )
        if report:
            several = len(result.sessions) > 1
            for s in result.sessions:
                obs = s.observation
                info = {"data": obs.location, "command": command or "ilcc-graph", "mode": result.mode}
                if result.rig is not None:  # a rig: its own page (docs/rig.md)
                    if obs.data is not None:
                        write_rig_report(d / "report", result.rig, obs.data, obs.rig_source, info)
                    continue
                sub = (s.name,) if several else ()
                bar = progress and progress(f"report {s.name}" if several else "report")
                study = refit_studies(s, result, truth) if studies else None
                proposal, png = write_report(
                    d.joinpath("report", *sub), d.joinpath("coloured", *sub), s, result, study, truth, info,
                    clouds, full_views, later, proposal, bar,
                )  # fmt: skip
                later = None
        if later is not None:
            proposal = later()
        if proposal is not None and report:  # --no-report: the advice in words only (the summary's)
            atomic_write(d / "next_pose.png", png if png is not None else next_pose_png(proposal))
    return out


def write_stage(
    out: Path, stage: str, source: FrameSource, refs: Sequence[FrameRef], results: list, command: str = ""
) -> list[tuple]:
    """One stage alone (``lidar`` or ``image``) over a source's frames: per frame ``<name>.yaml`` and
    ``<name>_board.pcd`` (LiDAR) or ``<name>_corners.png`` (image). Returns one table row per frame:
    (name, found, points, reason) or (name, found, detector, sigma px, reason). ``results``: per frame
    the stage's answer or its FrameError, as ``run.observe.stage_alone`` gives them."""
    from ilcc_graph.io import write_image, write_pcd
    from ilcc_graph.report.overlays import draw_corners
    from ilcc_graph.types import Scan

    rows: list[tuple[str | int, ...]] = []
    with staged(out, command=command) as d:
        for ref, res in zip(refs, results, strict=True):
            doc: dict[str, Any] = {"name": ref.name, "found": not isinstance(res, Exception)}
            if isinstance(res, Exception):
                doc["reason"] = str(res)
                rows.append((ref.name, "no", *[""] * (stage == "image"), "", str(res)))
            elif stage == "lidar":
                doc.update(
                    T_lidar_board=res.T_lidar_board,
                    covariance=res.covariance,
                    sigma=sigma_dict(res.covariance),
                    half_turn_ambiguous=res.half_turn_ambiguous,
                    corners_lidar=res.corners_lidar,
                    n_points=int(len(res.points_lidar)),
                    cost=res.cost,
                    diagnostics=res.diagnostics,
                )
                write_pcd(d / f"{ref.name}_board.pcd", Scan(res.points_lidar, res.intensity))
                rows.append((ref.name, "yes", len(res.points_lidar), ""))
            else:
                doc.update(
                    detector=res.detector,
                    half_turn_ambiguous=res.half_turn_ambiguous,
                    image_corners=res.uv,
                    bearings=res.bearings,
                    cov_px=res.cov_px,
                    diagnostics=res.diagnostics,
                )
                write_image(d / f"{ref.name}_corners.png", draw_corners(source.read_image(ref), res.uv))
                sigma = np.sqrt(np.mean(np.trace(res.cov_px, axis1=1, axis2=2) / 2))
                rows.append((ref.name, "yes", res.detector, f"{sigma:.3f}", ""))
            write_yaml(d / f"{ref.name}.yaml", doc)
    return rows


def write_check(
    out: Path, result: CheckResult, proposal: Proposal | None = None, command: str = ""
) -> Path:
    """``check.yaml`` (every frame's verdict, the batch answer, why the check ended) and, with a
    proposal, ``next_pose.png``, into ``out`` (staged like ``write_run``)."""
    verdicts = []
    for v in result.verdicts:
        d: dict[str, Any] = {"frame": v.name, "scan": v.lidar or "found", "image": v.image or "found"}
        if v.found:
            d["pose"] = f"repeat of {v.repeat_of}" if v.repeat_of else "new"
            d["accepted"] = bool(v.accepted)
        if v.note:
            d["note"] = v.note
        if v.sigmas is not None:
            d["sigma"] = dict(
                zip(("rx_deg", "ry_deg", "rz_deg", "tx_mm", "ty_mm", "tz_mm"), map(float, v.sigmas))
            )
        d["seconds"] = float(v.seconds)
        if v.latency is not None:
            d["latency_s"] = float(v.latency)
        verdicts.append(d)
    doc: dict[str, Any] = {"stopped": result.stopped, "frames": verdicts}
    if result.final is not None:
        doc["final"] = {
            "T_cam_lidar": np.asarray(result.final.T_cam_lidar),
            "covariance": result.final.covariance,
            "sigma": sigma_dict(result.final.covariance),
            "n_frames": int(result.final.n_frames),
        }
    if proposal is not None:
        doc["next_pose"] = {"T_lidar_board": proposal.T_lidar_board, "advice": proposal.describe()}
    with staged(out, command=command) as folder:
        write_yaml(folder / "check.yaml", doc)
        if proposal is not None:
            atomic_write(folder / "next_pose.png", next_pose_png(proposal))
    return out


def write_failure(out: Path, error: Exception, command: str = "") -> Path | None:
    """The message, the advice and every frame's full reason of a failed run, as ``out/failure.yaml``
    (staged) in a new or empty ``out``, or as ``OUT.failure.yaml`` beside an ``out`` that holds an
    earlier result (kept), unless a file not ours is there: then in the temporary folder. Returns
    the file written (None when nothing could be)."""
    from ilcc_graph.io import dump_yaml

    doc: dict[str, Any] = {"error": str(error), "advice": getattr(error, "advice", None)}
    doc["frames"] = [{"frame": f, "stage": st, "reason": why} for f, st, why in getattr(error, "frames", ())]
    text = f"{OURS}: why the run gave no calibration\n" + dump_yaml(doc)
    out = Path(out)
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        try:
            with staged(out, command=command) as d:
                atomic_write(d / "failure.yaml", text)
            return out / "failure.yaml"
        except OutputError:
            pass  # the folder cannot be ours now: beside it, or in the temporary folder
    temp = Path(tempfile.gettempdir()) / f"ilcc-graph-failure-{os.getpid()}.yaml"
    for path in (out.parent / f"{out.name}.failure.yaml", temp):
        if write_beside(path, text) is not None:
            return path
    return None
