"""Joint sessions (``sessions``): several sources as sessions of one mount, or one with a range offset.

``estimation.sessions.solve_sessions`` (the sensor model chosen for all sessions as the batch
chooses it; rigid: one extrinsic; drift: one per session tied by a random walk; the LiDAR's own
errors one set per LiDAR; the moved-mount tests); each session's calibration from its part of the
answer as the batch's (``session_part``, ``finish.from_batch``), the headline from the joint
estimate with the model chosen, the tests and offsets as ``joint.yaml`` (``joint_summary``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from ilcc_graph.estimation.sessions import (
    ConsistencyTest,
    JointSolution,
    Session,
    own_part,
    session_part,
    solve_sessions,
)
from ilcc_graph.run.finish import finish, from_batch
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.prepare import prepare
from ilcc_graph.run.result import Result, RunOptions, SessionResult
from ilcc_graph.run.strategies import Reporter, Strategy, register
from ilcc_graph.types import Calibration, Estimate, sigma_dict

__all__ = ["joint_summary", "solve"]


def solve(observations: Sequence[Observation], options: RunOptions, report: Reporter | None = None) -> Result:
    """The sources as sessions of one mount (``Observation.name`` names each)."""
    configs = [o.pair_config for o in observations]
    preps = [prepare(o.frames, c) for o, c in zip(observations, configs, strict=True)]
    sessions = [
        Session(o.name, p.frames, c.camera, p.T_init, c.lidar.name if c.lidar else "lidar", c.board)
        for p, o, c in zip(preps, observations, configs, strict=True)
    ]
    joint_opts = dataclasses.replace(
        options.joint, noise=options.noise, lidar_errors=options.lidar_errors, intrinsics=options.intrinsics,
        models=options.models, intrinsics_choice=options.intrinsics_choice,
    )  # fmt: skip
    sol = solve_sessions(sessions, joint_opts)
    method = f"joint-{joint_opts.mode}"
    results = []
    for p, o, cfg in zip(preps, observations, configs, strict=True):
        part = finish(p, o.frames, cfg, method, from_batch(session_part(sol, o.name), cfg), False)
        own = finish(p, o.frames, cfg, "graph", from_batch(own_part(sol, o.name), cfg), False)
        results.append(SessionResult(o.name, o, part, own))
    prefix = len(observations) > 1
    frames = tuple(
        dataclasses.replace(f, name=f"{r.name}/{f.name}") if prefix else f
        for r in results
        for f in r.calibration.frames
    )
    diag = {"variance_factor": sol.variance_factor}
    for lab, ro in sol.range_offsets.items():
        diag[f"range_offset_mm/{lab}"] = 1e3 * ro.value_m
        diag[f"range_offset_sigma_mm/{lab}"] = 1e3 * ro.sigma_m
    camera = configs[0].camera.to_dict()
    sensors = results[0].calibration.sensors  # the model chosen for all, the first LiDAR's errors
    cal = Calibration(sol.joint.T, sol.joint.covariance, frames, method, diag, camera, sensors)
    poses = {f"sessions/{n}": e for n, e in sol.sessions.items()}
    return Result(
        "sessions",
        cal,
        tuple(results),
        options,
        cal.covariance,
        documents={"joint.yaml": joint_summary(sol)},
        poses=poses,
        per_session=True,
    )


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
    """joint.yaml: joint and per-session extrinsics, the consistency tests, offsets, components
    (``report.text.format_joint`` prints it)."""
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


register(Strategy("sessions", solve, joint="sessions"))
