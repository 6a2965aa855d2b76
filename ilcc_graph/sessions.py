"""Several data sets (sessions) of one mount calibrated together; one data set frame by frame.

Pipeline level (reads the data sets through ``pipeline`` and ``io``; writes nothing): each session
is observed and solved alone with ``pipeline.observe_frames`` and ``pipeline.solve_extrinsic`` (which
orders corners, drops bad frames, initialises with UPnP and refines), then the kept frames go into
``joint.solve_sessions``. ``joint_summary`` turns the answer into plain data for a YAML file and
``format_joint`` into a table for the terminal; the command line decides where they go.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ilcc_graph.config import Config, load_config
from ilcc_graph.graph import GraphFrame
from ilcc_graph.incremental import FrameUpdate, IncrementalCalibrator, calibrate_incrementally, format_update
from ilcc_graph.io import list_frames
from ilcc_graph.joint import ConsistencyTest, Estimate, JointOptions, JointSolution, Session, solve_sessions
from ilcc_graph.types import Calibration, FrameResult

if TYPE_CHECKING:
    from ilcc_graph.pipeline import CalibrateOptions

__all__ = [
    "SessionsResult",
    "calibrate_dataset_incrementally",
    "calibrate_sessions",
    "format_joint",
    "format_update",
    "joint_summary",
    "session_from_calibration",
]

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class SessionsResult:
    """names: session labels (unique, from the folder names). configs / alone: per session, the config
    read and the pipeline's own calibration. joint: ``joint.JointSolution``."""

    names: tuple[str, ...]
    configs: dict[str, Config]
    alone: dict[str, Calibration]
    joint: JointSolution


def session_from_calibration(
    name: str, config: Config, cal: Calibration, lidar: str | None = None
) -> Session:
    """A ``joint.Session`` from a pipeline calibration: its used frames (corners already in the order
    the pipeline chose) and its extrinsic as the start. ``lidar`` labels the range-offset variable
    (default: the LiDAR model's name, so sessions with the same model share one offset)."""
    frames = [
        GraphFrame(
            name=r.name,
            T_lidar_board=r.board.T_lidar_board,
            board_cov=r.board.covariance,
            points_board=config.board.corners_board(),
            bearings=r.corners.bearings,
            cov_px=r.corners.cov_px,
        )
        for r in cal.frames
        if r.used and r.board is not None and r.corners is not None
    ]
    return Session(
        name=name,
        frames=frames,
        camera=config.camera,
        T_init=cal.T_cam_lidar,
        lidar=lidar if lidar is not None else config.lidar.name,
        board=config.board,
    )


def _labels(dirs: Sequence[Path]) -> list[str]:
    """Folder names, made unique with their parent's name or an index."""
    names = [d.name or str(d) for d in dirs]
    out = []
    for i, (d, n) in enumerate(zip(dirs, names)):
        if names.count(n) > 1:
            n = f"{d.parent.name}/{n}" if d.parent.name else f"{n}#{i + 1}"
        out.append(n)
    if len(set(out)) != len(out):
        out = [f"{n}#{i + 1}" for i, n in enumerate(out)]
    return out


def calibrate_sessions(
    data_dirs: Sequence[Path | str],
    options: JointOptions = JointOptions(),
    calibrate_options: CalibrateOptions | None = None,
    lidar_labels: Sequence[str] | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> SessionsResult:
    """Calibrate data sets (interface.md layout, each with its own config.yaml) jointly.

    ``lidar_labels``: per data set, which LiDAR unit it used (sessions with one label share the range
    offset); default the LiDAR model name. ``calibrate_options``: the per-session pipeline settings.
    ``progress(session, done, total)`` reports observation.
    Raises ``InputError`` for a bad data set, ``CalibrationImpossible`` when one yields no extrinsic.
    """
    from ilcc_graph.pipeline import (  # heavy stage imports
        CalibrateOptions,
        check_board_colour,
        observe_frames,
        solve_extrinsic,
    )

    calibrate_options = CalibrateOptions() if calibrate_options is None else calibrate_options
    dirs = [Path(d) for d in data_dirs]
    if lidar_labels is not None and len(lidar_labels) != len(dirs):
        raise ValueError(f"lidar_labels has {len(lidar_labels)} entries for {len(dirs)} data sets")
    names = _labels(dirs)
    configs: dict[str, Config] = {}
    alone: dict[str, Calibration] = {}
    sessions: list[Session] = []
    for k, (name, d) in enumerate(zip(names, dirs)):
        config = load_config(d / "config.yaml")
        frames, unpaired = list_frames(d)
        config = check_board_colour(frames, config)
        cb = None if progress is None else (lambda i, n, name=name: progress(name, i, n))
        observed = observe_frames(frames, config, calibrate_options.jobs, cb)
        observed += [FrameResult(name=stem, used=False, reason=why) for stem, why in unpaired]
        cal = solve_extrinsic(observed, config, calibrate_options)
        configs[name], alone[name] = config, cal
        sessions.append(
            session_from_calibration(name, config, cal, None if lidar_labels is None else lidar_labels[k])
        )
    return SessionsResult(tuple(names), configs, alone, solve_sessions(sessions, options))


# ---------------------------------------------------------------------------------- output
def _estimate_dict(e: Estimate) -> dict[str, Any]:
    return {"T_cam_lidar": e.T.tolist(), "covariance": e.covariance.tolist(), "sigma": e.sigma_dict()}


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
    """Plain data (lists, floats, str) for a YAML file: joint and per-session extrinsics, tests, offsets."""
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
        "dropped": {n: [{"name": f, "reason": why} for f, why in d] for n, d in sol.dropped.items()},
    }


def _sig(e: Estimate) -> str:
    s = e.sigmas
    return (
        " ".join(f"{v:.3f}" for v in np.degrees(s[:3])) + "  |  " + " ".join(f"{v:.2f}" for v in 1e3 * s[3:])
    )


def format_joint(sol: JointSolution) -> str:
    """A terminal report: sigmas (deg | mm) of each estimate, the tests, the verdict."""
    lines = [f"joint calibration ({sol.mode}), sigma rx ry rz [deg] | tx ty tz [mm]:"]
    lines.append(f"  {'joint':<18s} {_sig(sol.joint)}")
    for n in sol.alone:
        lines.append(f"  {n + ' alone':<18s} {_sig(sol.alone[n])}")
        if sol.mode == "drift":
            lines.append(f"  {n + ' in joint':<18s} {_sig(sol.sessions[n])}")
    for r in sol.range_offsets.values():
        lines.append(f"  range offset {r.lidar}: {1e3 * r.value_m:+.1f} +- {1e3 * r.sigma_m:.1f} mm")
    tests = ([sol.global_test] if sol.global_test else []) + sol.session_tests + sol.pair_tests
    if tests:
        lines.append("consistency (chi-square):")
        for t in tests:
            size = "" if t.session is None else f"  {t.rotation_deg:.3f} deg, {t.translation_mm:.1f} mm"
            flag = ("differs" if t.kind == "session" else "MOVED") if t.moved else "ok"
            lines.append(
                f"  {t.label:<24s} chi2 {t.mahalanobis:8.1f} ({t.dof} dof)  p={t.p_value:.2g}{size}  {flag}"
            )
    if sol.global_test is not None:
        if sol.moved:
            t = next(t for t in sol.session_tests if t.session == sol.moved)
            lines.append(
                f"the mount moved: session {sol.moved} differs from the others by "
                f"{t.rotation_deg:.3f} deg and {t.translation_mm:.1f} mm (p = {t.p_value:.2g})"
            )
        else:
            lines.append(f"no evidence that the mount moved (p = {sol.global_test.p_value:.2g})")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- incremental
def calibrate_dataset_incrementally(
    data_dir: Path | str,
    target_sigma: tuple[float, float] | None = None,
    report: Callable[[FrameUpdate], None] | None = None,
    stop_at_target: bool = False,
    T_init: np.ndarray | None = None,
) -> tuple[IncrementalCalibrator, FrameUpdate]:
    """Observe a data set frame by frame and feed an ``IncrementalCalibrator`` (iSAM2).

    ``report(update)`` is called after each frame with a board in both sensors and after the final
    relinearisation (e.g. ``lambda u: print(format_update(u, target_sigma))``). ``target_sigma`` is
    (rotation deg, translation mm); with ``stop_at_target`` the remaining frames are not read.
    """
    from ilcc_graph.pipeline import check_board_colour, observe_frame  # the stages' heavy imports

    d = Path(data_dir)
    config = load_config(d / "config.yaml")
    frames, _ = list_frames(d)
    config = check_board_colour(frames, config)
    observed = (observe_frame(paths, config) for paths in frames)  # lazy: stop_at_target reads no more
    return calibrate_incrementally(
        observed, config.camera, config.board, T_init, target_sigma, report, stop_at_target
    )
