"""The paper's refinement (``paper``): UPnP, then bearing refinement (Wang et al. 2017); no covariance."""

from __future__ import annotations

import logging
from collections.abc import Sequence

from ilcc_graph.estimation.paper import refine_paper, rms_bearing_mrad
from ilcc_graph.run.finish import Answer, finish
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.prepare import prepare
from ilcc_graph.run.result import Result, RunOptions, SessionResult
from ilcc_graph.run.strategies import Reporter, Strategy, one, register

log = logging.getLogger(__name__)

__all__ = ["solve"]


def solve(observations: Sequence[Observation], options: RunOptions, report: Reporter | None = None) -> Result:
    """The paper's answer on one source's observation (``Result.covariance`` None)."""
    obs = one(observations, "paper")
    config = obs.pair_config
    prep = prepare(obs.frames, config)
    T = refine_paper(prep.frames, prep.T_init, R_pano_cam=config.camera.R_flu_cam)
    if len(prep.frames) < 4:
        log.warning("only %d usable frame(s); at least 4 are advised", len(prep.frames))
    rms = {f.name: rms_bearing_mrad(T, f) for f in prep.frames}
    cal = finish(prep, obs.frames, config, "paper", Answer(T, None, rms))
    return Result("paper", cal, (SessionResult(obs.name, obs, cal),), options, None)


register(Strategy("paper", solve, sensor_errors=False, refinement=True))
