"""The variance components' own uncertainty in the covariances (``noise`` step 5).

A component s estimated from a redundancy r is itself uncertain: the sd of its log is
``sqrt(psi'(r / 2))``, about ``sqrt(2 / r)`` (``psi'`` the trigamma function: s is a chi-square
over its dof; with 5 boards the in-plane priors' component has r ~ 9). Two things follow, both
for the covariances only (the estimate is that of the components found):

- the covariances use each estimated component's posterior mean ``s r / (r - 2)`` (Jeffreys prior
  on the variance) instead of s;
- what the components' uncertainty moves the estimate is added: ``sum_k psi'(r_k / 2) d_k d_k^T``, with
  ``d_k`` the global variables' shift per unit of ``log s_k``, one Gauss-Newton step of the graph
  with ``s_k`` moved (no re-solve; it matches re-solves, ``tests/test_component_uncertainty.py``).

Components held at their floor are not estimated and are left as they are.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import gtsam
import numpy as np
from scipy.special import polygamma

from ilcc_graph.estimation import plane
from ilcc_graph.estimation.assembly import Assembly
from ilcc_graph.estimation.keys import I, L, O, X
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.noise_loop import component_floor

__all__ = ["LOG_STEP", "MIN_POSTERIOR_REDUNDANCY", "component_uncertainty", "estimated_components"]

#: below this redundancy a component's posterior mean ``r / (r - 2)`` is capped at twice its estimate
MIN_POSTERIOR_REDUNDANCY = 4.0
#: step in ``log s`` of the components' sensitivities
LOG_STEP = 0.05


def estimated_components(
    comps: Mapping[tuple[str, str], float],
    redundancy: Mapping[tuple[str, str], float],
    lidar_errors: LidarErrorOptions | None,
) -> dict[tuple[str, str], float]:
    """The components a solve estimated, with their redundancies: those above their floor
    (``noise_loop.component_floor``; a board plane's: its configured floor) with a redundancy above
    one half."""
    out = {}
    for key, s in comps.items():
        r = redundancy.get(key, 0.0)
        floored = plane.at_floor(lidar_errors, key, s) if key[0] in plane.KINDS else s <= component_floor(key)
        if r > 0.5 and not floored:
            out[key] = r
    return out


def component_uncertainty(
    asm: Assembly,
    kept: Sequence[int],
    comps: Mapping[tuple[str, str], float],
    estimated: Mapping[tuple[str, str], float],
    values: gtsam.Values,
) -> tuple[dict[tuple[str, str], float] | None, list[tuple[float, dict[int, np.ndarray]]]]:
    """(the components the covariances use, the spread) of the ``estimated`` components (key:
    redundancy) of a solve at ``values`` (module docstring step 5). The spread leaves out the
    per-view bearing components: each moves one board's weight (r ~ 64 each; on the recorded
    Ouster set their spread is below 0.1 % of the extrinsic's covariance, the others' up to 30 %
    with the LiDAR's error terms). (None, []) when nothing was estimated."""
    estimated = {k: r for k, r in estimated.items() if k in comps}
    if not estimated:
        return None, []
    post = dict(comps)
    for key, r in estimated.items():
        post[key] = comps[key] * (r / (r - 2.0) if r > MIN_POSTERIOR_REDUNDANCY else 2.0)
    globals_ = [X(e) for e in asm.extrinsics(kept)] + [L(lid) for lid in asm.point_lidars(kept)]
    globals_ += [I(c) for c in asm.view_cameras(kept)] + [O(lid) for lid in asm.lidars(kept)]
    globals_ = [k for k in globals_ if values.exists(k)]

    def step(c: Mapping[tuple[str, str], float]) -> dict[int, np.ndarray]:
        delta = asm.newton_step(kept, c, values)
        return {k: np.asarray(delta.at(k), dtype=np.float64) for k in globals_}

    shifts = [(key, r) for key, r in estimated.items() if not (key[0] == "bearing" and asm.per_view)]
    spread = []
    if shifts:
        base = step(comps)
        for key, r in shifts:
            moved = step({**comps, key: comps[key] * math.exp(LOG_STEP)})
            var_log = float(polygamma(1, r / 2.0))  # of log s, s ~ chi2_r / r
            spread.append((var_log, {k: (moved[k] - base[k]) / LOG_STEP for k in globals_}))
    return post, spread
