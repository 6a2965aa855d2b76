"""The print's colour is checked from the run's own image results (no frame waits for it)."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import pytest
import yaml

from ilcc_graph.datasets import FolderSource
from ilcc_graph.run.live import CheckOptions, run_check
from ilcc_graph.run.observe import observe
from ilcc_graph.run.stages import StageOptions
from ilcc_graph.simulate import simulate_dataset, standard_spec


@pytest.fixture(scope="module")
def wrong_colour(tmp_path_factory) -> Path:
    """Four small frames whose config.yaml states the other colour than the print's."""
    spec = standard_spec(lidar="hdl32", camera="pinhole", width=800, frames=4, seed=5)
    data = simulate_dataset(tmp_path_factory.mktemp("colour") / "sim", spec)
    cfg = yaml.safe_load((data / "config.yaml").read_text())
    assert cfg["board"]["lower_left"] == "black"
    cfg["board"]["lower_left"] = "white"
    (data / "config.yaml").write_text(yaml.safe_dump(cfg))
    return data


@pytest.mark.parametrize("jobs", [1, 2])
def test_observe_turns_a_mistyped_print_colour_and_keeps_every_frame(
    wrong_colour: Path, jobs: int, caplog
) -> None:
    with caplog.at_level(logging.WARNING, logger="ilcc_graph"):
        obs = observe(FolderSource(wrong_colour), StageOptions(jobs=jobs))
    assert obs.config.board.lower_left == "black"
    assert "board.lower_left is white" in caplog.text
    assert [f.name for f in obs.frames] == ["0001", "0002", "0003", "0004"]
    assert all(f.used and f.corners is not None and f.corners.views for f in obs.frames)


def test_check_turns_it_too(wrong_colour: Path, tmp_path: Path) -> None:
    shutil.copytree(wrong_colour, tmp_path / "d")
    result = run_check(FolderSource(tmp_path / "d"), CheckOptions())
    assert result.config.board.lower_left == "black"
    assert all(v.found for v in result.verdicts)
