"""``ilcc-graph check``: verdicts per frame while a folder is filled, repeats, the growing folder."""

from __future__ import annotations

import dataclasses
import shutil
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from ilcc_graph.app import main
from ilcc_graph.app.check_view import WIDTH, format_verdict
from ilcc_graph.datasets.watch import GrowingFolder
from ilcc_graph.io import read_yaml
from ilcc_graph.run.live import CheckOptions, Verdict, run_check
from ilcc_graph.simulate import simulate_dataset, standard_spec


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    """Six small pinhole frames (fast stages)."""
    spec = standard_spec(lidar="hdl32", camera="pinhole", width=800, frames=6, seed=5)
    return simulate_dataset(tmp_path_factory.mktemp("live") / "sim", spec)


def _files(data: Path, stem: str) -> tuple[Path, Path]:
    return next((data / "pcd").glob(f"{stem}.*")), next((data / "img").glob(f"{stem}.*"))


def _fill(src: Path, dst: Path, plan: list[tuple[str, str]], gap_s: float) -> threading.Thread:
    """Copy frames of ``src`` into ``dst`` one by one: (source stem, new stem), ``gap_s`` apart."""

    def work() -> None:
        for stem, new in plan:
            time.sleep(gap_s)
            scan, image = _files(src, stem)
            shutil.copyfile(scan, dst / "pcd" / f"{new}{scan.suffix}")
            shutil.copyfile(image, dst / "img" / f"{new}{image.suffix}")

    t = threading.Thread(target=work, daemon=True)
    t.start()
    return t


def test_watch_gives_each_frame_its_verdict(sim: Path, tmp_path: Path) -> None:
    dst = tmp_path / "live"
    (dst / "pcd").mkdir(parents=True)
    (dst / "img").mkdir()
    shutil.copyfile(sim / "config.yaml", dst / "config.yaml")
    # frame 0004 repeats 0002's board pose (same files), so it is not a new observation
    plan = [("0001", "0001"), ("0002", "0002"), ("0003", "0003"), ("0002", "0004"), ("0004", "0005")]
    filler = _fill(sim, dst, plan, gap_s=0.4)
    seen = []
    opts = CheckOptions(watch=True, until=len(plan), idle_timeout_s=60, settle_s=0.2, poll_s=0.05)
    result = run_check(GrowingFolder(dst, settle_s=0.2), opts, on_verdict=lambda v, _: seen.append(v))
    filler.join()
    assert [v.name for v in result.verdicts] == ["0001", "0002", "0003", "0004", "0005"]
    assert seen == result.verdicts
    assert result.stopped == "5 frames checked"
    assert all(v.found for v in result.verdicts), [format_verdict(v) for v in result.verdicts]
    assert result.verdicts[3].repeat_of == "0002" and not result.verdicts[3].accepted
    assert [v.repeat_of for v in result.verdicts if v.name != "0004"] == [None] * 4
    assert result.verdicts[1].sigmas is None  # two distinct poses do not calibrate
    third, last = result.verdicts[2].sigmas, result.verdicts[4].sigmas
    assert third is not None and np.all(np.isfinite(third)) and last is not None
    assert np.all(last <= third + 1e-12)  # a new pose only adds information
    assert result.verdicts[4].n_distinct == 4
    for v in result.verdicts:
        assert v.latency is not None and v.latency >= v.seconds > 0
    assert result.final is not None and result.final.n_frames == 4


def test_growing_folder_waits_for_files_to_stop_growing(sim: Path, tmp_path: Path) -> None:
    dst = tmp_path / "g"
    (dst / "pcd").mkdir(parents=True)
    (dst / "img").mkdir()
    scan, image = _files(sim, "0001")
    shutil.copyfile(image, dst / "img" / image.name)
    blob = scan.read_bytes()
    folder = GrowingFolder(dst, settle_s=0.3)
    with open(dst / "pcd" / scan.name, "wb") as f:
        f.write(blob[: len(blob) // 2])
        f.flush()
        assert folder.poll() == []  # half a scan: not complete
        time.sleep(0.1)
        f.write(blob[len(blob) // 2 :])
    (dst / "pcd" / ".0002.pcd.tmp").write_bytes(b"x")  # hidden: ignored
    (dst / "pcd" / "0003.pcd.part").write_bytes(b"x")  # not a scan suffix: ignored
    assert folder.poll() == []  # it grew: waits again
    time.sleep(0.35)
    got = folder.poll()
    assert [a.ref.name for a in got] == ["0001"]
    assert got[0].arrived <= got[0].seen
    assert folder.poll() == []  # each frame once


def test_check_reports_a_frame_without_the_board(sim: Path, tmp_path: Path) -> None:
    dst = tmp_path / "d"
    shutil.copytree(sim, dst)
    scan, image = _files(dst, "0002")
    cv2.imwrite(str(image), np.full_like(cv2.imread(str(image)), 128))  # grey: no chessboard
    result = run_check(GrowingFolder(dst), CheckOptions())
    v = {x.name: x for x in result.verdicts}
    assert v["0002"].lidar is None and v["0002"].image and not v["0002"].found
    assert "image" in format_verdict(v["0002"])
    assert sum(x.found for x in result.verdicts) == 5


def test_a_verdict_with_long_notes_fits_80_columns() -> None:
    reason = "no 6x8-square chessboard (5x7 inner corners) found in the image"
    sig = np.array([0.01, 0.02, 0.03, 1.0, 2.0, 3.0])
    v = Verdict("0002", "board plane fit: 12 points, fewer than the 30 needed", reason, latency=0.61)
    lines = format_verdict(v, (0.05, 1.0)).splitlines()
    assert lines[0].split() == ["0002", "no", "no", "-", "0", "0.61s"]
    assert " ".join(" ".join(lines[1:]).split()) == f"scan: {v.lidar}; image: {reason}"  # whole
    assert all(line.startswith(" " * 11) for line in lines[1:])
    # a very long note ends after three lines; a long name stands on its own line
    seen = Verdict(
        "frame_000012345", None, None, repeat_of="frame_000000001", note="gate: " + " ".join(["far"] * 40)
    )
    seen = dataclasses.replace(seen, n_frames=5, sigmas=100 * sig, worst=(3.0, 300.0), latency=12.5)
    lines = format_verdict(seen, (0.0001, 0.001)).splitlines()
    assert lines[0] == seen.name and lines[1].split()[:3] == ["ok", "ok", "repeat"]
    assert lines[1].split()[-3:] == ["x3e+04", "x3e+05", "12.50s"]  # the ratios in 13 columns
    assert len(lines) == 5 and lines[-1].endswith("[...]")
    for each in (v, seen):
        assert max(map(len, format_verdict(each, (0.0001, 0.001)).splitlines())) <= WIDTH == 80


def test_cli_check_writes_verdicts_and_next_pose(sim: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    assert main(["check", str(sim), "--out", str(out), "--target-sigma", "0.0001,0.001"]) == 0
    text = capsys.readouterr().out
    rows = [line for line in text.splitlines() if line[:4].isdigit()]
    assert len(rows) == 6 and all(" ok   ok " in r for r in rows)
    assert "their noise levels rest on few boards" in text  # frames with a note
    assert max(map(len, text.splitlines())) <= WIDTH == 80, text
    assert "next board pose:" in text
    doc = read_yaml(out / "check.yaml")
    assert [f["frame"] for f in doc["frames"]] == ["0001", "0002", "0003", "0004", "0005", "0006"]
    assert doc["final"]["n_frames"] == 6 and "advice" in doc["next_pose"]
    assert (out / "next_pose.png").read_bytes()[:4] == b"\x89PNG"


def test_ctrl_c_ends_the_check_cleanly_with_the_frames_so_far(sim: Path) -> None:
    def interrupt_after_four(v, _checker) -> None:  # noqa: ANN001
        if v.name == "0004":
            raise KeyboardInterrupt

    result = run_check(GrowingFolder(sim), CheckOptions(), on_verdict=interrupt_after_four)
    assert result.stopped == "interrupted"
    assert [v.name for v in result.verdicts] == ["0001", "0002", "0003", "0004"]
    assert result.final is not None and result.final.n_frames == 4  # the frames so far, solved together
    assert run_check(GrowingFolder(sim), CheckOptions(until=2)).stopped == "2 frames checked"


def _calibrate(data: Path):  # noqa: ANN202 - (used frame names, covariance) as calibrate gives them
    from ilcc_graph.datasets import open_source
    from ilcc_graph.run.pipeline import run
    from ilcc_graph.run.result import RunOptions
    from ilcc_graph.run.stages import StageOptions

    cal = run([open_source(data)], RunOptions(stages=StageOptions(jobs=1))).calibration
    return {f.name for f in cal.frames if f.used}, cal.covariance


def _agree(data: Path) -> None:
    """``check`` fed the frames in order accepts what ``calibrate`` uses and ends at its sigmas; each
    frame's verdict, once three poses calibrate, is the one ``calibrate`` gives it."""
    from ilcc_graph.datasets import open_source
    from ilcc_graph.types import sigmas_deg_mm

    result = run_check(open_source(data), CheckOptions())
    used, cov = _calibrate(data)
    final = result.final
    assert final is not None and set(final.solution.per_frame) == used
    judged = [v for v in result.verdicts if v.found and not v.repeat_of and v.sigmas is not None]
    assert {v.name for v in judged if v.accepted} <= used
    assert {v.name for v in judged if not v.accepted} <= {v.name for v in result.verdicts} - used
    np.testing.assert_allclose(sigmas_deg_mm(final.covariance), sigmas_deg_mm(cov), rtol=1e-9)


def test_check_accepts_what_calibrate_uses_and_ends_at_its_sigmas(sim: Path) -> None:
    _agree(sim)


@pytest.mark.slow
def test_check_agrees_with_calibrate_on_the_recorded_ouster_set(acfr_os1_fisheye: Path) -> None:
    _agree(acfr_os1_fisheye)
