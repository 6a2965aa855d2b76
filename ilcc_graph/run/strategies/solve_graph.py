"""Batch (``graph``): every frame of one source in one factor graph, with its covariance.

The estimation core's noise policy (gate, variance components, the sensor model the boards support:
``estimation.batch.solve``) on the frames ``prepare`` ordered; several sources: ``sessions``.
"""

from __future__ import annotations

from collections.abc import Sequence

from ilcc_graph.estimation.batch import solve as solve_batch
from ilcc_graph.run.finish import finish, from_batch
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.prepare import prepare
from ilcc_graph.run.result import Result, RunOptions, SessionResult
from ilcc_graph.run.strategies import Reporter, Strategy, one, register

__all__ = ["solve"]


def solve(observations: Sequence[Observation], options: RunOptions, report: Reporter | None = None) -> Result:
    """The batch answer of one source's observation. Raises CalibrationImpossible."""
    obs = one(observations, "graph")
    config = obs.pair_config
    prep = prepare(obs.frames, config)
    sol = solve_batch(
        prep.frames, config.camera, prep.T_init, options.noise, options.lidar_errors, options.intrinsics,
        effects=True, models=options.models, intrinsics_choice=options.intrinsics_choice,
    )  # fmt: skip
    gated = options.noise.chi2_gate_prob is not None  # without a gate every frame is kept as asked
    cal = finish(prep, obs.frames, config, "graph", from_batch(sol, config), agree=gated)
    used = tuple(f for f in prep.frames if f.name in sol.per_frame)
    return Result("graph", cal, (SessionResult(obs.name, obs, cal),), options, cal.covariance,
                  solved=sol.solved, batch=sol, used_frames=used)  # fmt: skip


register(Strategy("graph", solve, joint="sessions", refinement=True))
