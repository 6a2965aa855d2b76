"""estimation.chi2 against scipy.stats' chi-square, including far in the tail."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from ilcc_graph.estimation import chi2 as ours


@pytest.mark.parametrize("dof", [1, 6, 70, 400])
def test_quantiles_and_tails_match_scipy_stats(dof: int) -> None:
    for q in (0.5, 0.95, 0.999):
        assert ours.ppf(q, dof) == pytest.approx(chi2.ppf(q, dof), rel=1e-10)
    for x in (0.5 * dof, dof, 3.0 * dof):
        assert ours.sf(x, dof) == pytest.approx(chi2.sf(x, dof), rel=1e-9)
        assert ours.logsf(x, dof) == pytest.approx(chi2.logsf(x, dof), rel=1e-9)


@pytest.mark.parametrize("dof", [6, 70, 280])
def test_log_tail_is_finite_and_ordered_where_the_probability_underflows(dof: int) -> None:
    xs = np.array([40.0, 80.0, 160.0]) * dof
    logs = [ours.logsf(float(x), dof) for x in xs]
    assert all(np.isfinite(logs)) and logs[0] > logs[1] > logs[2]
    ref = chi2.logsf(xs, dof)  # scipy.stats is accurate here too, where it does not underflow
    for a, b in zip(logs, ref, strict=True):
        if np.isfinite(b):
            assert a == pytest.approx(b, rel=2e-3)
