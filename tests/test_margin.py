"""The margin measured where the print shows (lidar/margin.py): one edge's place from in/out samples,
"no usable edge" without a ray past it, the contradiction per axis, and the run's summary."""

from __future__ import annotations

import numpy as np

from ilcc_graph.board import Board
from ilcc_graph.lidar.margin import MarginFit, _edge, margin_summary, margin_words

GRID = np.arange(-0.02, 0.4, 0.001)


def _samples(edge: float, outside: bool = True) -> tuple[np.ndarray, ...]:
    """Samples every 10 mm across an edge ``edge`` m past the pattern: returns inside it, rays
    past it (none when not ``outside``)."""
    x = np.arange(-0.3, 0.35, 0.01) + 0.003
    inside = x < edge
    keep = inside | outside
    n = int(keep.sum())
    return x[keep], np.full(n, 0.003), inside[keep], np.full(n, 0.01)


def test_an_edge_is_placed_between_its_samples() -> None:
    m, sd = _edge(*_samples(0.17), GRID)
    assert abs(m - 0.17) < 0.006 and 0.0 < sd < 0.006, (m, sd)


def test_no_ray_past_the_edge_is_no_usable_edge() -> None:
    m, sd = _edge(*_samples(0.17, outside=False), GRID)
    assert np.isnan(m) and np.isnan(sd)


def test_an_axis_contradicts_only_when_both_sides_say_so() -> None:
    sig = np.full(4, 0.003)
    wider = MarginFit(np.array([0.17, 0.17, 0.17, 0.17]), sig, (0.07, 0.07), 0.03)
    assert wider.contradicts and wider.board(Board(7, 9, 0.1, 0.07, 0.07)).margin_long == 0.17
    off_centre = MarginFit(np.array([0.12, 0.02, 0.07, 0.07]), sig, (0.07, 0.07), 0.03)  # print 50 mm off
    assert not off_centre.contradicts
    one_side = MarginFit(np.array([0.17, np.nan, 0.17, 0.17]), sig, (0.07, 0.07), 0.03)
    assert one_side.contradicts and one_side.board(Board(7, 9, 0.1, 0.07, 0.07)) is None
    assert "margin_long_mm" not in one_side.diagnostics() and "margin_x0_mm" in one_side.diagnostics()


def test_the_run_reports_a_margin_most_boards_contradict() -> None:
    board = Board(7, 9, 0.1, 0.07, 0.07)
    bad = {"margin_long_mm": 170.0, "margin_short_mm": 168.0, "margin_contradicted": 1.0}
    good = {"margin_long_mm": 72.0, "margin_short_mm": 69.0, "margin_contradicted": 0.0}
    assert margin_summary([bad, good, good, {}], board) == {}
    s = margin_summary([bad, bad, good, {}], board)
    assert s["lidar_margin_boards"] == 3 and s["lidar_margin_contradicted_boards"] == 2
    assert s["lidar_margin_long_mm"] == 170.0 and s["lidar_margin_configured_short_mm"] == 70.0
    assert "set board.margin: [0.170" in margin_words(s)
