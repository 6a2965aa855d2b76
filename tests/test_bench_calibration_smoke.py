"""Smoke test of scripts/bench_calibration.py: one small simulated set, observed and solved three ways,
its NEES checked against chi-square bounds and the summary's NEES and coverage against the sets'."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest
from accuracy import NEES_BOUND, mean_band

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

from bench_calibration import CHI2_6_95, run_set, summarize  # noqa: E402


@pytest.mark.slow
def test_one_small_set_solves_three_ways() -> None:
    (res,) = run_set(seed=3, width=1600, modes=("off",), n_frames=8)
    assert res.failure is None, res.failure
    assert set(res.errors) == {"UPnP", "paper", "graph"}
    assert res.used >= 4
    for deg, mm in res.errors.values():  # a 1600-px panorama still pins the extrinsic to ~0.1 deg / cm
        assert deg < 0.2 and mm < 20.0
    # the graph's error within its covariance (one draw: fails a covariance ~4 x too small in sigma)
    assert 0 < res.graph_nees < NEES_BOUND, res.graph_nees
    # each board's LiDAR pose against the truth: the mean NEES of the boards (6 dof each, ~independent)
    # in the two-sided 99.9 % band of chi2(6 n) / n (8 boards: 2.8 .. 10.9): fails a board covariance
    # 2 x too small or too large in sigma (mean ~24 or ~1.5)
    lo, hi = mean_band(6, len(res.board_nees))
    assert len(res.board_nees) == len(res.board_z) >= 4
    assert lo < np.mean(res.board_nees) < hi, (lo, np.mean(res.board_nees), hi)
    # the corners' covariance is conservative by design (docs/bench_calibration.md: corner NEES mean
    # 0.5-1 against 2 at 3000-8000 px, ~1.6 here): never above chi2(2 n) / n at 99.95 %, and not 4 x
    # too wide in variance (mean 0.5)
    assert len(res.corner_nees) == len(res.corner_err_px) >= 4 * 35
    assert 0.5 < np.mean(res.corner_nees) < mean_band(2, len(res.corner_nees))[1], np.mean(res.corner_nees)
    s = summarize([res])
    assert s["sets"] == 1 and s["failed"] == 0
    assert s["nees_mean"] == res.graph_nees and s["coverage"] == 1.0
    # the summary's NEES and coverage are the sets' own: a second set outside the 95 % bound halves it
    other = dataclasses.replace(res, seed=4, graph_nees=CHI2_6_95 + 1.0)
    s2 = summarize([res, other])
    assert s2["coverage"] == 0.5 and s2["nees_mean"] == pytest.approx((res.graph_nees + CHI2_6_95 + 1) / 2)
    assert s2["nees_median"] == pytest.approx(s2["nees_mean"])
