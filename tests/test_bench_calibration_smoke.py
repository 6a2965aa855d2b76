"""Smoke test of scripts/bench_calibration.py: one small simulated set, observed and solved three ways."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

from bench_calibration import run_set, summarize  # noqa: E402


@pytest.mark.slow
def test_one_small_set_solves_three_ways() -> None:
    (res,) = run_set(seed=3, width=1600, modes=("off",), n_frames=8)
    assert res.failure is None, res.failure
    assert set(res.errors) == {"UPnP", "paper", "graph"}
    assert res.used >= 4
    for deg, mm in res.errors.values():  # a 1600-px panorama still pins the extrinsic to ~0.1 deg / cm
        assert deg < 0.2 and mm < 20.0
    assert np.isfinite(res.graph_nees) and res.graph_nees >= 0
    assert len(res.board_nees) == len(res.board_z) >= 4
    assert len(res.corner_nees) == len(res.corner_err_px) >= 4 * 35
    s = summarize([res])
    assert s["sets"] == 1 and s["failed"] == 0 and 0.0 <= s["coverage"] <= 1.0
