"""The one writer of a run's results, for every mode.

``write_run(out, result, ...)`` writes, into a staging folder that replaces ``out`` only when
everything is written (so ``out`` is either the complete result or untouched):

- ``calibration.yaml``: the extrinsic, its covariance, every frame's fate and the camera model
  (interface.md; everything ``export`` needs);
- ``config.resolved.yaml``: the configuration used (print colour as checked, LiDAR model as
  resolved) in our schema, plus ``options``: every stage and solver option of the run;
- sessions: ``joint.yaml`` (tests, offsets) and ``sessions/<name>/`` with each session's own
  ``calibration.yaml`` and ``config.resolved.yaml``; incremental: ``incremental.yaml`` (the state
  after each frame);
- unless ``report=False``: ``report/index.html`` (one per session under ``report/<name>/`` when
  there are several), its pictures drawn on the views the image stage kept (no picture is read
  again), on ``jobs`` processes; on request (``clouds``) the coloured clouds ``coloured/<frame>.ply``
  and (``full_views``) the whole pictures at full resolution;
- with a proposal: ``next_pose.png``; ``check``: ``check.yaml``; a failed run: ``failure.yaml``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import logging
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from ilcc_graph import signals, workers
from ilcc_graph.config import Config, config_to_dict
from ilcc_graph.errors import OutputError
from ilcc_graph.estimation.incremental import FrameUpdate
from ilcc_graph.estimation.sessions import ConsistencyTest, JointSolution
from ilcc_graph.io import atomic_write, write_calibration, write_ply, write_yaml
from ilcc_graph.pipeline import RunOptions, RunResult, SessionResult, solve_observed
from ilcc_graph.types import Estimate, sigma_dict

log = logging.getLogger(__name__)

__all__ = [
    "check_output",
    "link_latest",
    "write_evaluation",
    "write_file",
    "joint_summary",
    "options_dict",
    "resolved_config",
    "staged",
    "write_check",
    "write_run",
    "write_stage",
]


def _plain(x: Any) -> Any:
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return {f.name: _plain(getattr(x, f.name)) for f in dataclasses.fields(x)}
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


def options_dict(options: RunOptions) -> dict[str, Any]:
    """Every option of a run as plain data (stages, noise policy, joint settings, mode)."""
    return _plain(options)


def resolved_config(config: Config, options: RunOptions) -> dict[str, Any]:
    """config.resolved.yaml: the config used, in our schema, with the run's ``options``."""
    d = config_to_dict(config)
    d["options"] = options_dict(options)
    return d


def _estimate_dict(e: Estimate) -> dict[str, Any]:
    return {
        "T_cam_lidar": np.asarray(e.T),
        "covariance": np.asarray(e.covariance),
        "sigma": sigma_dict(e.covariance),
    }


def _test_dict(t: ConsistencyTest) -> dict[str, Any]:
    return {
        "label": t.label,
        "kind": t.kind,
        "session": t.session,
        "rotation_deg": t.rotation_deg,
        "translation_mm": t.translation_mm,
        "mahalanobis": t.mahalanobis,
        "dof": t.dof,
        "p_value": t.p_value,
        "moved": bool(t.moved),
    }


def joint_summary(sol: JointSolution) -> dict[str, Any]:
    """joint.yaml: joint and per-session extrinsics, the consistency tests, offsets, components."""
    return {
        "mode": sol.mode,
        "joint": _estimate_dict(sol.joint),
        "sessions": {n: _estimate_dict(e) for n, e in sol.sessions.items()},
        "alone": {n: _estimate_dict(e) for n, e in sol.alone.items()},
        "consistency": {
            "global": None if sol.global_test is None else _test_dict(sol.global_test),
            "per_session": [_test_dict(t) for t in sol.session_tests],
            "consecutive": [_test_dict(t) for t in sol.pair_tests],
            "moved": sol.moved,
        },
        "range_offsets": {
            k: {"value_mm": 1e3 * r.value_m, "sigma_mm": 1e3 * r.sigma_m}
            for k, r in sol.range_offsets.items()
        },
        "variance_components": {n: {"board": c[0], "bearing": c[1]} for n, c in sol.components.items()},
        "variance_factor": sol.variance_factor,
        "dropped": {n: [{"name": f, "reason": why} for f, why in d] for n, d in sol.dropped.items()},
    }


def _update_dict(u: FrameUpdate) -> dict[str, Any]:
    d: dict[str, Any] = {
        "frame": u.name or "(final)",
        "accepted": bool(u.accepted),
        "n_frames": int(u.n_frames),
    }
    if u.reason:
        d["reason"] = u.reason
    if u.T_cam_lidar is not None:
        d["sigma"] = sigma_dict(u.covariance)
        d["reached_target"] = bool(u.reached_target)
    d["seconds"] = float(u.seconds)
    return d


def link_latest(path: Path) -> None:
    """Point ``<parent>/latest`` at the run folder ``path`` (best effort: a link is a convenience)."""
    latest = Path(path).parent / "latest"
    try:
        if latest.is_symlink() or latest.exists():
            latest.unlink()
        latest.symlink_to(Path(path).name)
    except OSError:
        pass


def write_file(path: Path, data: str | bytes, flag: str = "--out") -> Path:
    """One file written atomically; ``OutputError`` naming ``flag`` and the path when it cannot be."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{flag} {path}: is a folder; give a file name")
    if path.parent.exists() and not path.parent.is_dir():
        raise OutputError(f"{flag} {path}: {path.parent} is a file, so nothing can be written under it")
    check_output(path.parent, flag)
    try:
        return atomic_write(path, data)
    except OSError as err:
        raise OutputError(f"{flag} {path}: cannot write ({err.strerror or err})") from None


def write_evaluation(out: Path, evaluation: Any, flag: str = "--out") -> Path:
    """``out/evaluation.yaml`` (``report.evaluation_to_dict``); returns its path."""
    from ilcc_graph.io import dump_yaml
    from ilcc_graph.report import evaluation_to_dict

    out = Path(out)
    check_output(out, flag)
    return write_file(out / "evaluation.yaml", dump_yaml(evaluation_to_dict(evaluation)), flag)


def check_output(out: Path, flag: str = "--out") -> None:
    """Raise ``OutputError`` now when ``out`` cannot become an output folder (before a long run).

    ``out`` may be absent or a folder; it must not be a file or lie under a file, and its nearest
    existing parent must be writable (tried with a probe folder, removed again: permission bits do
    not stop root, a read-only file system does).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{flag} {out}: is an existing file, not a folder; give a folder for the results")
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"{flag} {out}: {parent} is a file, so no folder can be made under it")
    try:
        probe = tempfile.mkdtemp(prefix=".ilcc-graph-probe-", dir=parent)
        os.rmdir(probe)
    except OSError as err:
        raise OutputError(f"{flag} {out}: cannot write in {parent} ({err.strerror or err})") from None


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux renameat2 RENAME_EXCHANGE); False where not available."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    if ctypes.get_errno() in (errno.EINVAL, errno.ENOSYS, errno.EPERM):
        return False  # a file system without the exchange: rename in two steps
    raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()), str(b))


@contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """An exclusive lock on ``folder`` (flock on its descriptor; nothing where unsupported)."""
    try:
        import fcntl

        fd = os.open(folder, os.O_RDONLY)
    except (ImportError, OSError):
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _commit(stage: Path, out: Path) -> None:
    """Put the complete ``stage`` at ``out`` (replacing an old ``out``); signals held, runs serialised.

    Two runs writing to one folder at once each stage their own folder; the commits take turns
    under a lock on the parent, so ``out`` is always one run's complete result (the last to commit).
    """
    with signals.held(), _locked(out.parent):
        if out.exists() and not out.is_dir():
            raise OutputError(f"{out}: is a file now (it was not when the run started); nothing written")
        if not out.exists():
            os.replace(stage, out)
            return
        if _exchange(stage, out):
            shutil.rmtree(stage, ignore_errors=True)  # the old result, swapped out
            return
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
        os.replace(out, old / "x")
        os.replace(stage, out)
        shutil.rmtree(old, ignore_errors=True)


@contextmanager
def staged(out: Path) -> Iterator[Path]:
    """A staging folder beside ``out`` that becomes ``out`` when the block ends without an error.

    An existing ``out`` is replaced only then, in one step where the system allows; on an error or a
    signal the staging folder is removed and ``out`` is untouched. A write that fails (disk full,
    read-only, permissions) raises ``OutputError`` naming the file.
    """
    out = Path(out)
    check_output(out, "output folder")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    except OSError as err:
        raise OutputError(f"{out}: cannot create the output folder ({err.strerror or err})") from None
    with signals.on_stop(lambda: shutil.rmtree(stage, ignore_errors=True)):
        try:
            yield stage
            _commit(stage, out)
        except OSError as err:
            shutil.rmtree(stage, ignore_errors=True)
            where = f" ({err.filename})" if err.filename else ""
            raise OutputError(f"{out}: cannot write the results: {err.strerror or err}{where}") from None
        except BaseException:
            shutil.rmtree(stage, ignore_errors=True)
            raise


def _draw_frame(source, ref, config: Config, T: np.ndarray, result, options, ply: Path | None):  # noqa: ANN001, ANN202
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


def _valley(cal, camera, board):  # noqa: ANN001, ANN202 - report.studies.Valley | None
    """The report's valley study on the used frames (as ``report.build_report`` makes it), or None
    when a used frame lacks its board points (the report then rebuilds them from the scans)."""
    from ilcc_graph.report import eval_frame
    from ilcc_graph.report.studies import valley

    efs = [eval_frame(f) for f in cal.frames if f.used]
    if not efs or any(e is None or not len(e.points_lidar) for e in efs):
        return None
    return valley(efs, camera, board, np.asarray(cal.T_cam_lidar), np.asarray(cal.covariance))


def _drawn(items: list[tuple], pool, cal, config: Config) -> tuple[Iterator, object]:  # noqa: ANN001
    """(``_draw_frame(*item)`` for each item in order, a future of the valley study), on ``pool``
    (``workers.pool``; in this process when None); the valley study, the longest single job, goes first."""
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

    def results() -> Iterator:
        for fut in futures:
            yield fut.result()
            signals.check()

    return results(), study


def _write_report(
    out: Path,
    coloured_dir: Path,
    session: SessionResult,
    result: RunResult,
    studies: bool,
    truth: np.ndarray | None,
    info: dict,
    clouds: bool = False,
    full_views: bool = False,
    meanwhile: Callable[[], object] | None = None,
) -> object:
    """``out/index.html`` with its figures for one session; with ``clouds`` ``coloured_dir/<frame>.ply``.
    ``meanwhile()`` runs here while the pictures are drawn on other processes; returns its result."""
    from ilcc_graph.report import FigureOptions, build_report, cross_validate, frames_vs_accuracy

    obs, cal = session.observation, session.calibration
    config, source = obs.config, obs.source
    curve = cv = None
    if studies and result.mode in ("graph", "incremental", "sessions"):
        options = dataclasses.replace(result.options, mode="graph")

        def solve(subset):  # noqa: ANN001, ANN202
            c = solve_observed(subset, config, options)
            return c.T_cam_lidar, c.covariance

        quiet = logging.getLogger("ilcc_graph")
        level = quiet.level
        quiet.setLevel(logging.ERROR)  # subsets of few frames warn by design
        try:
            curve = frames_vs_accuracy(obs.frames, solve, config.camera, config.board, truth)
            cv = cross_validate(
                obs.frames, solve, config.camera, config.board, folds=5, T_all=cal.T_cam_lidar
            )
        finally:
            quiet.setLevel(level)
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
        got = meanwhile() if meanwhile is not None else None
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
        )
    for rel, blob in files.items():  # inside the staging folder: written plainly (no fsync each)
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        (out / rel).write_bytes(blob)
    return got


def write_run(
    out: Path,
    result: RunResult,
    *,
    report: bool = True,
    studies: bool = False,
    truth: np.ndarray | None = None,
    command: str = "",
    next_pose=None,  # noqa: ANN001 - next_pose.Proposal, or a callable giving one
    clouds: bool = False,
    full_views: bool = False,
) -> Path:
    """Write every output of ``result`` to ``out`` (module docstring); returns ``out``. With a
    ``next_pose`` proposal also ``next_pose.png`` (the rig, the boards, the proposal; a callable is
    called while the report's pictures are drawn on other processes); ``clouds``: the coloured
    clouds; ``full_views``: the report's whole pictures at full resolution too."""
    later = next_pose if callable(next_pose) else None
    with staged(out) as d:
        write_calibration(d / "calibration.yaml", result.calibration)
        first = result.sessions[0].observation.config
        write_yaml(d / "config.resolved.yaml", resolved_config(first, result.options))
        if result.joint is not None:
            write_yaml(d / "joint.yaml", joint_summary(result.joint))
            for s in result.sessions:
                write_calibration(d / "sessions" / s.name / "calibration.yaml", s.calibration)
                write_yaml(
                    d / "sessions" / s.name / "config.resolved.yaml",
                    resolved_config(s.observation.config, result.options),
                )
        if result.updates:
            write_yaml(d / "incremental.yaml", {"updates": [_update_dict(u) for u in result.updates]})
        if report:
            several = len(result.sessions) > 1
            for s in result.sessions:
                info = {
                    "data": s.observation.source.location,
                    "command": command or "ilcc-graph",
                    "mode": result.mode,
                }
                sub = (s.name,) if several else ()
                got = _write_report(
                    d.joinpath("report", *sub), d.joinpath("coloured", *sub), s, result, studies, truth, info,
                    clouds, full_views, later,
                )  # fmt: skip
                if later is not None:
                    next_pose, later = got, None
        if later is not None:
            next_pose = later()
        if next_pose is not None:
            atomic_write(d / "next_pose.png", next_pose_png(next_pose))
    return out


def write_stage(out: Path, stage: str, source, refs, results) -> list[tuple]:  # noqa: ANN001
    """One stage alone (``lidar`` or ``image``) over a source's frames: per frame ``<name>.yaml`` and
    ``<name>_board.pcd`` (LiDAR) or ``<name>_corners.png`` (image). Returns one table row per frame:
    (name, found, points, reason) or (name, found, detector, sigma px, reason)."""
    from ilcc_graph.io import write_image, write_pcd
    from ilcc_graph.report.overlays import draw_corners
    from ilcc_graph.types import Scan

    rows = []
    with staged(out) as d:
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


def next_pose_png(proposal) -> bytes:  # noqa: ANN001 - next_pose.Proposal
    """The rig from above and the side with the boards so far and the proposal (``report.rig``)."""
    import textwrap

    from ilcc_graph.report.rig import plot_next_pose

    rig = proposal.rig
    return plot_next_pose(
        rig.board,
        proposal.boards,
        proposal.T_lidar_board,
        rig.T_cam_lidar,
        rig.camera,
        rig.lidar.vertical_angles_deg,
        "\n".join(textwrap.wrap(proposal.describe(), 150)),
    )


def write_check(out: Path, result, proposal=None) -> Path:  # noqa: ANN001 - live.CheckResult, next_pose.Proposal
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
    with staged(out) as d:
        write_yaml(d / "check.yaml", doc)
        if proposal is not None:
            atomic_write(d / "next_pose.png", next_pose_png(proposal))
    return out


def write_failure(out: Path, error: Exception) -> Path:
    """The message, the advice and every frame's full reason of a failed run, as ``out/failure.yaml``
    (staged), or as ``OUT.failure.yaml`` beside an ``out`` that holds an earlier result (kept).
    Returns the file written."""
    doc: dict[str, Any] = {"error": str(error), "advice": getattr(error, "advice", None)}
    doc["frames"] = [{"frame": f, "stage": st, "reason": why} for f, st, why in getattr(error, "frames", ())]
    out = Path(out)
    if out.exists():
        path = out.parent / f"{out.name}.failure.yaml"
        write_yaml(path, doc)
        return path
    with staged(out) as d:
        write_yaml(d / "failure.yaml", doc)
    return out / "failure.yaml"
