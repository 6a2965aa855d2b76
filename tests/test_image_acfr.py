"""Image stage on the recorded VLP-16 + fisheye set (skipped where the data are absent)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ilcc_graph.config import load_config
from ilcc_graph.errors import CornersNotFound
from ilcc_graph.image import detect_corners
from ilcc_graph.io import read_image

# a spread of poses, incl. pose05 where the detector needs its fallback flags (all 20: scripts/bench_image.py)
STEMS = ("pose01", "pose05", "pose23", "pose39")


@pytest.fixture(scope="module")
def acfr(acfr_data):
    cfg = load_config(acfr_data / "config.yaml")
    images = {s: read_image(acfr_data / "img" / f"{s}.png") for s in STEMS}
    return cfg, images


def test_acfr_corners_found(acfr):
    cfg, images = acfr
    # measured on all 20 images: with z towards the camera the print's origin square is white
    board = dataclasses.replace(cfg.board, lower_left="white")
    for stem, img in images.items():
        res = detect_corners(img, cfg.camera, board)
        assert res.uv.shape == (board.n_corners, 2), stem
        assert np.all(cfg.camera.in_image(res.uv)), stem
        assert res.half_turn_ambiguous  # 6 x 8 squares
        assert res.diagnostics["colour_score"] > 0.9, stem
        assert res.diagnostics["sigma_view_px"] < 0.3, stem
        # neighbouring corners about one square apart in the image, no folded grid
        g = res.uv.reshape(board.rows - 1, board.cols - 1, 2)
        d = np.linalg.norm(np.diff(g, axis=1), axis=-1)
        assert d.min() > 0.6 * np.median(d) and d.max() < 1.6 * np.median(d), stem


def test_acfr_configured_lower_left_contradicts_the_print(acfr):
    cfg, images = acfr
    assert cfg.board.lower_left == "white"  # as shipped since the print was checked
    wrong = dataclasses.replace(cfg.board, lower_left="black")
    with pytest.raises(CornersNotFound, match="set board.lower_left: white"):
        detect_corners(images["pose01"], cfg.camera, wrong)
