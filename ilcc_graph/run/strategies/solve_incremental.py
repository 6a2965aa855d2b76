"""Incremental (``incremental``): frames observed one at a time and fed to iSAM2 until a target.

The frames come from ``Observation.stream`` (``observe.FrameStream``: with ``--jobs N``, observed
on N processes up to N frames ahead) as the strategy reads them, so that with
``RunOptions.stop_at_target`` no frame is used after the target is reached (when iSAM2's
sigmas reach it, confirmed by ``calibrate``'s answer on the frames read: the update ``(batch)``); the last
update is the batch answer on every frame offered (``IncrementalCalibrator.finish``). Each update is
reported as one line (``format_update``) and kept in ``incremental.yaml``. The run then takes the
frames read as ``calibrate`` takes them once it has an answer (``pipeline``: the boards on corrected
ranges, the second look); when those change a board, ``restate`` makes the batch answer of the
frames so changed the written one, with one more update, ``(again)``.
"""

from __future__ import annotations

import dataclasses
import logging
import textwrap
from collections.abc import Sequence
from typing import Any

import numpy as np

from ilcc_graph.errors import NOT_READ, CalibrationError
from ilcc_graph.estimation.batch import BatchSolution
from ilcc_graph.estimation.incremental import FrameUpdate, IncrementalCalibrator
from ilcc_graph.run.after import after, without_print
from ilcc_graph.run.finish import finish, from_batch
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.prepare import Prepared, permute_corners, prepare
from ilcc_graph.run.result import Result, RunOptions, SessionResult
from ilcc_graph.run.strategies import Reporter, Strategy, one, register, strategy
from ilcc_graph.types import (
    Calibration,
    FrameResult,
    reaches,
    sigma_dict,
    sigmas_deg_mm,
    target_gap,
    worst_sigmas,
)

log = logging.getLogger(__name__)

#: once calibrate's answer on the frames read has not reached the target, it is asked again after
#: one more frame and a further 1 / CONFIRM_EVERY of the frames read (a long stream whose LiDAR
#: errors keep its sigmas above the target solves about CONFIRM_EVERY * ln(n) times, not n times)
CONFIRM_EVERY = 10

__all__ = ["format_update", "restate", "solve"]


def solve(observations: Sequence[Observation], options: RunOptions, report: Reporter | None = None) -> Result:
    """iSAM2 over the frames of one source's stream; ``report(line)`` after each update."""
    obs = one(observations, "incremental")
    stream, config = obs.stream, obs.pair_config
    if stream is None:
        raise ValueError("incremental mode observes frame by frame: give Observation.stream (run() does)")
    cal = IncrementalCalibrator(
        config.camera, config.board, target_sigma=options.target_sigma, noise=options.noise,
        lidar_errors=options.lidar_errors, intrinsics=options.intrinsics, models=options.models,
        intrinsics_choice=options.intrinsics_choice,
    )  # fmt: skip
    observed: list[FrameResult] = []
    updates: list[FrameUpdate] = []

    def tell(u: FrameUpdate) -> None:
        updates.append(u)
        if report is not None:
            report(format_update(u, options.target_sigma))

    confirm_at = 0  # frames read before calibrate's answer is asked again (it grows with the frames)
    for fr in stream:
        observed.append(fr)
        if fr.damaged:
            log.warning("%s: skipped, %s", fr.name, fr.reason)
        if not fr.used or fr.board is None or fr.corners is None:
            continue
        u = cal.add_frame(fr)
        tell(u)
        if not (options.stop_at_target and u.reached_target and len(observed) >= confirm_at):
            continue
        if (batch := _as_calibrate(obs, observed, options)) is not None:
            tell(batch)
            if batch.reached_target:
                break
        confirm_at = len(observed) + 1 + len(observed) // CONFIRM_EVERY
    observed += stream.unread(observed, f"{NOT_READ}: the target sigma was reached")
    if not updates:
        prepare(observed, config)  # no frame reached the calibrator: raises with every frame's reason
    final = cal.finish()
    tell(final)
    results = {f.name: f for f in observed}
    for name in cal.flipped:  # the corner order the calibrator chose
        f = results[name]
        assert f.corners is not None  # the calibrator turned the corners of a frame it was offered
        results[name] = dataclasses.replace(
            f, corners=permute_corners(f.corners, config.board.half_turn_permutation())
        )
    offered = {f.name for f in cal.offered}
    sol = final.solution
    assert sol is not None
    not_offered = [(f.name, "not offered") for f in observed if f.used and f.name not in offered]
    prep = Prepared(cal.offered, np.asarray(final.T_cam_lidar), results)
    answer = from_batch(dataclasses.replace(sol, dropped=sol.dropped + not_offered), config)
    calib = finish(prep, observed, config, "incremental", answer)
    done = dataclasses.replace(obs, frames=observed, stream=None)
    doc = {"updates": [_update_dict(u) for u in updates]}
    return Result("incremental", calib, (SessionResult(obs.name, done, calib),), options, calib.covariance,
                  documents={"incremental.yaml": doc})  # fmt: skip


def _as_calibrate(
    obs: Observation, observed: Sequence[FrameResult], options: RunOptions
) -> FrameUpdate | None:
    """``calibrate``'s answer on the frames read so far (the batch strategy and the steps after its
    answer, ``run.after``), as the update ``(batch)`` with whether it reaches the target; None when
    they do not calibrate. The stream's own sigmas leave out the LiDAR's errors (its sensor model):
    on the recorded VLP-16 set they said 0.050 deg / 1.87 mm after 9 frames where ``calibrate`` of
    the same frames says 0.071 deg / 2.8 mm, so the stream stops only where this answer reaches the
    target."""
    graph = strategy("graph")
    seen = dataclasses.replace(obs, frames=list(observed), stream=None)
    opts = without_print([seen], dataclasses.replace(options, mode="graph"), graph, say=False)
    try:
        cal = after(graph, opts, graph.solve([seen], opts, None), [seen]).calibration
    except CalibrationError:
        return None
    return update_of(cal, options.target_sigma, "(batch)")


def update_of(
    cal: Calibration, target: tuple[float, float] | None, name: str = "", seconds: float = 0.0,
    solution: BatchSolution | None = None,
) -> FrameUpdate:  # fmt: skip
    """A calibration's answer as an update named ``name`` (the frames it used, whether it reaches
    ``target`` as the verdict judges it, the solve's wall time in s and its batch ``solution``): the
    one conversion the incremental mode and ``check`` make."""
    reached = reaches(cal.covariance, target)
    used = sum(1 for f in cal.frames if f.used)
    return FrameUpdate(cal.T_cam_lidar, np.sqrt(np.diag(cal.covariance)), reached, cal.covariance, name,
                       n_frames=used, seconds=seconds, solution=solution)  # fmt: skip


def restate(streamed: Result, again: Result, report: Reporter | None = None) -> Result:
    """``streamed`` (this strategy's result) with ``again``'s answer (its frames solved by the batch
    strategy after the boards on corrected ranges or the second look changed them), labelled
    ``incremental``; the change reported and kept as the update ``(again)``."""
    cal = dataclasses.replace(again.calibration, method="incremental")
    target = streamed.options.target_sigma
    u = update_of(cal, target, "(again)")
    if report is not None:
        report(format_update(u, target))
    doc = streamed.documents.get("incremental.yaml", {})
    doc = {**doc, "updates": [*doc.get("updates", []), _update_dict(u)]}
    sessions = tuple(dataclasses.replace(x, calibration=cal) for x in again.sessions)
    return dataclasses.replace(
        again, mode="incremental", calibration=cal, sessions=sessions, covariance=cal.covariance,
        documents={**streamed.documents, "incremental.yaml": doc},
    )  # fmt: skip


def format_update(u: FrameUpdate, target_sigma: tuple[float, float] | None = None) -> str:
    """One line per incremental update (80 columns, wrapped): frame, boards in the graph, 1-sigma in
    deg (rx ry rz) and mm (tx ty tz), the update's time, and with a target the largest 1-sigma in any
    direction over it (``types.target_gap``: what decides whether the target is reached)."""
    head = f"{u.name or '(final)':>8s} n={u.n_frames:<3d}"
    if not u.accepted:
        return "\n".join(textwrap.wrap(f"{head} rejected: {u.reason}", 80, subsequent_indent=" " * 15))
    if u.T_cam_lidar is None:
        return f"{head} {u.reason or 'waiting'}"
    s = sigmas_deg_mm(u.covariance)
    mm = " ".join(f"{v:.{2 if v < 10 else 1 if v < 100 else 0}f}" for v in s[3:])  # 4 digits
    body = f"deg {s[0]:.3f} {s[1]:.3f} {s[2]:.3f}  mm {mm}"
    if u.seconds:  # the time of an update the calibrator made (none: the run's solve again)
        body += f"  {1e3 * u.seconds:.0f} ms" if u.seconds < 10 else f"  {u.seconds:.1f} s"
    if target_sigma is not None:
        gap = target_gap(worst_sigmas(u.covariance), target_sigma)  # as reached_target judges it
        body += "  " + f"target {gap}".replace(" ", "\xa0")  # wrapped as one word
    return "\n".join(textwrap.wrap(f"{head} {body}", 80, subsequent_indent=" " * 15)).replace("\xa0", " ")


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


register(Strategy("incremental", solve, streams=True, restate=restate))
