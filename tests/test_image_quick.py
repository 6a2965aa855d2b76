"""The image stage's cheap search (issue 37): the board found on a reduced copy, every corner refined at
full resolution by the fine pass, the coarse cascade only where the cheap search fails."""

from __future__ import annotations

import numpy as np
import pytest

from ilcc_graph.image import ImageOptions, detect_corners, detectors
from ilcc_graph.image.coarse import downscaled
from ilcc_graph.simulate import simulate_frames, standard_spec

PLAIN = ImageOptions(quick=())  # the search as before issue 37: the coarse cascade first


@pytest.fixture(scope="module")
def pinhole_1920():
    """Two 1920 x 1200 pinhole images: wider than the cheap search's 1000 columns."""
    spec = standard_spec(camera="pinhole", width=1920, frames=2, seed=4)
    return spec, list(simulate_frames(spec))


def _same_up_to_half_turn(a, b, board) -> float:
    """Largest corner distance (px) between two results, the half turn allowed when ambiguous."""
    d = np.linalg.norm(a.uv - b.uv, axis=1).max()
    if a.half_turn_ambiguous:
        d = min(d, np.linalg.norm(a.uv - b.uv[board.half_turn_permutation()], axis=1).max())
    return float(d)


def _counting(monkeypatch, calls: list[tuple[str, int]], name: str, found: bool = True) -> None:
    """Wrap detector ``name`` to record (name, columns searched); ``found`` False: it finds nothing."""
    real = detectors.DETECTORS[name]

    def wrapped(gray, board):
        calls.append((name, gray.shape[1]))
        return real(gray, board) if found else None

    monkeypatch.setitem(detectors.DETECTORS, name, wrapped)


def test_cheap_search_refines_to_the_full_search(pinhole_1920, monkeypatch):
    """The classic detector on a 1000-column copy (or SB on a 1500-column one) finds the board; the
    fine pass refines every corner at full resolution to the full search's corners (within 0.001 px)
    with the same measured noise and covariance; SB on the full image is not run at all."""
    spec, frames = pinhole_1920
    found_by = []
    for f in frames:
        full = detect_corners(f.image, spec.camera, spec.board, PLAIN)
        calls: list[tuple[str, int]] = []
        for name in ("sb", "classic"):
            _counting(monkeypatch, calls, name)
        cheap = detect_corners(f.image, spec.camera, spec.board)
        monkeypatch.undo()
        found_by.append((cheap.detector, cheap.diagnostics["coarse_width_px"]))
        assert calls[0] == ("classic", 1000) and calls[1:] in ([], [("sb", 1500)])
        assert found_by[-1] == (calls[-1][0], float(calls[-1][1]))
        assert full.detector == "sb" and full.diagnostics["coarse_width_px"] == 1920.0
        assert _same_up_to_half_turn(cheap, full, spec.board) < 1e-3
        sigma = full.diagnostics["sigma_view_px"]
        assert cheap.diagnostics["sigma_view_px"] == pytest.approx(sigma, rel=0.01)
        cov, cov_full = np.sort(cheap.cov_px.ravel()), np.sort(full.cov_px.ravel())
        np.testing.assert_allclose(cov, cov_full, rtol=0.02, atol=1e-6)
    assert ("classic", 1000.0) in found_by  # the cheapest attempt does find boards


def test_escalation_when_the_cheap_search_finds_nothing(pinhole_1920, monkeypatch):
    """Classic finds nothing: SB on the 1500-column copy (the cheap search's second attempt); SB
    finds nothing there either: the coarse cascade on the full-width image, whose SB then finds it."""
    spec, frames = pinhole_1920
    f = frames[0]
    full = detect_corners(f.image, spec.camera, spec.board, PLAIN)
    calls: list[tuple[str, int]] = []
    _counting(monkeypatch, calls, "classic", found=False)
    res = detect_corners(f.image, spec.camera, spec.board)
    assert calls == [("classic", 1000)]
    assert res.detector == "sb" and res.diagnostics["coarse_width_px"] == 1500.0
    assert _same_up_to_half_turn(res, full, spec.board) < 1e-3

    real_sb = detectors.DETECTORS["sb"]
    seen: list[int] = []

    def sb_blind_on_copies(gray, board):
        seen.append(gray.shape[1])
        return real_sb(gray, board) if gray.shape[1] == 1920 else None

    monkeypatch.setitem(detectors.DETECTORS, "sb", sb_blind_on_copies)
    res = detect_corners(f.image, spec.camera, spec.board)
    assert seen == [1500, 1920]
    assert res.detector == "sb" and res.diagnostics["coarse_width_px"] == 1920.0
    assert _same_up_to_half_turn(res, full, spec.board) < 1e-3


def test_a_cheap_find_that_fails_the_fine_pass_escalates(pinhole_1920, monkeypatch):
    """The cheap search's grid is a false one (corners moved by 0.3 square at random): the fine pass
    rejects it and the coarse cascade finds the real board."""
    spec, frames = pinhole_1920
    real = detectors.DETECTORS["classic"]
    rng = np.random.default_rng(2)

    def spoiled(gray, board):
        xy = real(gray, board)
        return None if xy is None else xy + rng.normal(0.0, 0.3 * detectors.grid_spacing(xy, board), xy.shape)

    monkeypatch.setitem(detectors.DETECTORS, "classic", spoiled)
    opts = ImageOptions(quick=(("classic", 1000),))
    res = detect_corners(frames[1].image, spec.camera, spec.board, opts)
    assert res.detector == "sb" and res.diagnostics["coarse_width_px"] == 1920.0
    monkeypatch.undo()
    full = detect_corners(frames[1].image, spec.camera, spec.board, PLAIN)
    assert _same_up_to_half_turn(res, full, spec.board) < 1e-3


def test_downscaled_copies():
    """Never upscaled; a reduction by 2 or more is by a whole factor (OpenCV's fast area average)."""
    g = np.zeros((400, 800), np.uint8)
    assert downscaled(g, 1000) is g and downscaled(g, 800) is g
    assert downscaled(g, 600).shape == (300, 600)
    assert downscaled(g, 300).shape == (133, 267)  # 800 / 300 = 2.67 -> 3
    assert downscaled(g, 380).shape == (200, 400)  # 2.1 -> 2


@pytest.mark.parametrize(
    "quick", ["classic", (("classic",),), (("classic", 100),), (("harris", 1000),)], ids=str
)
def test_quick_options_are_checked(quick):
    with pytest.raises(ValueError, match="quick|unknown detector"):
        ImageOptions(quick=quick)
