"""``--stage-cache DIR``: each scan's and image's stage results kept and found again
(``io.result_store``, ``run.stages.kept``), through the command line as a user runs it. Beside the
settings, a scan's key holds its file's name (the LiDAR stage's messages name it), an image's only
its pixels."""

from __future__ import annotations

import dataclasses
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.app.arguments import CACHE_VARIABLE
from ilcc_graph.errors import BoardNotFound
from ilcc_graph.io import read_pcd, write_pcd
from ilcc_graph.types import BoardFit


def _calibrate(data: Path, out: Path, *flags: str) -> int:
    return main(["calibrate", str(data), "--out", str(out), "--no-report", *flags])


def _kept(folder: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in sorted(folder.rglob("*.pickle"))}


@pytest.fixture(scope="module")
def plain(simulated, tmp_path_factory) -> tuple[Path, bytes]:
    """A small simulated set and its calibration.yaml computed without kept results."""
    data = simulated("pinhole", frames=4, seed=3)
    out = tmp_path_factory.mktemp("plain") / "out"
    assert _calibrate(data, out, "--no-stage-cache", "--jobs", "1") == 0
    return data, (out / "calibration.yaml").read_bytes()


def test_a_second_run_computes_nothing_and_writes_the_same_answer(plain, tmp_path: Path) -> None:
    data, answer = plain
    cache = tmp_path / "kept"
    assert _calibrate(data, tmp_path / "first", "--stage-cache", str(cache), "--jobs", "2") == 0
    first = _kept(cache)
    assert len(first) >= 8  # a LiDAR and an image result per frame at least
    assert _calibrate(data, tmp_path / "second", "--stage-cache", str(cache), "--jobs", "1") == 0
    assert _kept(cache) == first  # every result found: none computed again
    for run in ("first", "second"):
        assert (tmp_path / run / "calibration.yaml").read_bytes() == answer


def test_the_run_uses_what_it_finds(plain, tmp_path: Path) -> None:
    """Every kept LiDAR result replaced by a refusal: the next run refuses every frame with it."""
    data, _ = plain
    cache = tmp_path / "kept"
    assert _calibrate(data, tmp_path / "first", "--stage-cache", str(cache), "--jobs", "1") == 0
    planted = 0
    for path in cache.rglob("*.pickle"):
        if isinstance(pickle.loads(path.read_bytes()), BoardFit):
            path.write_bytes(pickle.dumps(BoardNotFound("a refusal planted in the kept results")))
            planted += 1
    assert planted >= 4
    code = _calibrate(data, tmp_path / "second", "--stage-cache", str(cache), "--jobs", "1")
    assert code == 3
    failure = yaml.safe_load((tmp_path / "second" / "failure.yaml").read_text())
    reasons = [f["reason"] for f in failure["frames"]]
    assert reasons and all("planted" in r for r in reasons), reasons


def test_a_changed_scan_is_computed_again(plain, tmp_path: Path) -> None:
    """One scan of the set moved by 20 mm: its LiDAR stage is computed again, nothing else, and the
    answer is the one a run without kept results gives."""
    data, answer = plain
    copy = tmp_path / "copy"
    shutil.copytree(data, copy)
    cache = tmp_path / "kept"
    assert _calibrate(copy, tmp_path / "first", "--stage-cache", str(cache), "--jobs", "1") == 0
    assert (tmp_path / "first" / "calibration.yaml").read_bytes() == answer
    first = _kept(cache)
    scan_file = sorted((copy / "pcd").iterdir())[-1]  # the first ones give the beam table
    scan = read_pcd(scan_file)
    write_pcd(scan_file, dataclasses.replace(scan, points=scan.points + np.array([0.02, 0.0, 0.0])))
    assert _calibrate(copy, tmp_path / "moved", "--stage-cache", str(cache), "--jobs", "1") == 0
    new = set(_kept(cache)) - set(first)
    assert 1 <= len(new) <= 2, len(new)  # that scan's LiDAR stage (and its fit on corrected ranges)
    assert _calibrate(copy, tmp_path / "moved-plain", "--no-stage-cache", "--jobs", "1") == 0
    moved_answer = (tmp_path / "moved-plain" / "calibration.yaml").read_bytes()
    assert (tmp_path / "moved" / "calibration.yaml").read_bytes() == moved_answer != answer


def test_results_that_cannot_be_read_are_computed_again(plain, tmp_path: Path) -> None:
    data, answer = plain
    cache = tmp_path / "kept"
    assert _calibrate(data, tmp_path / "first", "--stage-cache", str(cache), "--jobs", "1") == 0
    first = _kept(cache)
    for path in first:
        path.write_bytes(b"\x80\x05 cut short")
    assert _calibrate(data, tmp_path / "second", "--stage-cache", str(cache), "--jobs", "1") == 0
    again = _kept(cache)
    assert set(again) == set(first)  # each written again (its timings are the new computation's), whole
    assert all(pickle.loads(data) is not None for data in again.values())
    assert (tmp_path / "second" / "calibration.yaml").read_bytes() == answer


def test_the_environment_names_the_folder_and_the_flag_turns_it_off(
    plain, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    data, _ = plain
    cache = tmp_path / "from-env"
    monkeypatch.setenv(CACHE_VARIABLE, str(cache))
    assert _calibrate(data, tmp_path / "off", "--no-stage-cache", "--jobs", "1") == 0
    assert not cache.exists()
    assert _calibrate(data, tmp_path / "on", "--jobs", "1") == 0
    assert _kept(cache)


def test_a_file_named_as_the_folder_is_a_users_mistake(plain, tmp_path: Path, capsys) -> None:
    data, _ = plain
    taken = tmp_path / "notes.txt"
    taken.write_text("mine")
    assert _calibrate(data, tmp_path / "out", "--stage-cache", str(taken)) == 2
    err = capsys.readouterr().err
    assert f"--stage-cache {taken}: not a folder" in err, err
    assert taken.read_text() == "mine" and not (tmp_path / "out").exists()
