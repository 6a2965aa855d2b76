"""Issue 36: files named by their times, as careless recorders name them, through the command line:
nanoseconds without zero padding (``1510868224_17000000`` is 0.017 s, not 0.17), a stray file whose
name is no time among them (named and set aside; the rest still pair by time), two scans whose names
give the same time (a conflict, both named), and a scan that lost its image to a nearer scan (the
reason says so instead of contradicting the tolerance)."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import pytest
import yaml

from ilcc_graph.app import main

SECS = 1510868224


def _timed(src: Path, dst: Path, padded: bool = False, first_ns: int = 17_000_000) -> list[tuple[str, str]]:
    """A copy of ``src`` whose scan k is named ``<secs>_<nanoseconds unpadded>`` (``first_ns`` + k ms
    past second SECS + 2 k; ``padded``: to 9 digits, as ROS writes them) and its image 12 ms later;
    [(scan stem, image stem)]."""
    (dst / "pcd").mkdir(parents=True)
    (dst / "img").mkdir()
    shutil.copy(src / "config.yaml", dst / "config.yaml")
    names = []
    for k, scan in enumerate(sorted((src / "pcd").iterdir())):
        image = next((src / "img").glob(f"{scan.stem}.*"))
        ns = first_ns + 1_000_000 * k
        width = 9 if padded else 0
        names.append((f"{SECS + 2 * k}_{ns:0{width}d}", f"{SECS + 2 * k}_{ns + 12_000_000:0{width}d}"))
        shutil.copy(scan, dst / "pcd" / f"{names[-1][0]}{scan.suffix}")
        shutil.copy(image, dst / "img" / f"{names[-1][1]}{image.suffix}")
    return names


def _calibrate(data: Path, out: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, dict]:
    code = main(["calibrate", str(data), "--out", str(out), "--jobs", "1", "--no-report"])
    assert code == 0, capsys.readouterr().err[-800:]
    capsys.readouterr()
    return {f["name"]: f for f in yaml.safe_load((out / "calibration.yaml").read_text())["frames"]}


@pytest.mark.parametrize(
    ("first_ns", "why"),
    [(17_000_000, "both readings possible): it pairs 5 scans, a decimal fraction 0"),
     (5_000_000, "their digits vary in number, as a recorder that does not pad writes them)")],
)  # fmt: skip
def test_unpadded_nanoseconds_pair_and_the_reading_is_said(
    simulated,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
    first_ns: int,
    why: str,
) -> None:
    """Before: ``1510868224_17000000`` read as 0.17 s, pairs 12 ms apart were "no image near its time
    (the nearest 0.120 s away)" and the run ended with exit 2. 8 digits in every name: both readings
    are possible, the one that pairs is used; 7 and 8 digits (5 ms, images at 17 ms): the digits say
    the recorder did not pad."""
    names = _timed(simulated("pinhole"), tmp_path / "data", first_ns=first_ns)
    with caplog.at_level(logging.WARNING):
        frames = _calibrate(tmp_path / "data", tmp_path / "out", capsys)
    assert all(frames[s]["used"] for s, _ in names), frames
    example = min(n for pair in names for n in pair if len(n.split("_")[1]) < 9)
    secs, ns = example.split("_")
    assert f"names like {example} read as unpadded nanoseconds ({secs}.{int(ns):09d} s; {why}" in caplog.text


def test_a_stray_file_is_named_and_set_aside(
    simulated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One ``board_check.png`` among the images (before: pairing by time was off for the whole folder,
    exit 2, the stray never named)."""
    data = tmp_path / "data"
    names = _timed(simulated("pinhole"), data, padded=True)
    shutil.copy(next((data / "img").iterdir()), data / "img" / "board_check.png")
    frames = _calibrate(data, tmp_path / "out", capsys)
    assert all(frames[s]["used"] for s, _ in names)
    assert not frames["board_check"]["used"]
    assert "image board_check.png: its name is no time like the others'" in frames["board_check"]["reason"]


def test_equal_times_are_a_conflict_and_a_lost_image_says_why(
    simulated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A copy of the last scan under a name of the same time (``.021000000`` against ``_021000000``), and
    a copy of the first 7 ms before it, nearer to no image than the first: before, one of the equal
    pair was dropped as "no image near its time (the nearest 0.012 s away)" under a 0.05 s tolerance;
    now both are named as a conflict, and the scan that lost its image says to which scan."""
    data = tmp_path / "data"
    names = _timed(simulated("pinhole"), data, padded=True)
    last, first = names[-1][0], names[0][0]
    secs, ns = last.split("_")
    shutil.copy(data / "pcd" / f"{last}.pcd", data / "pcd" / f"{secs}.{int(ns):09d}.pcd")
    shutil.copy(data / "pcd" / f"{first}.pcd", data / "pcd" / f"{SECS}_010000000.pcd")
    frames = _calibrate(data, tmp_path / "out", capsys)
    for a, b in ((last, f"{secs}.{int(ns):09d}"), (f"{secs}.{int(ns):09d}", last)):
        why = frames[a]["reason"]
        assert not frames[a]["used"] and f"the same time as {b}.pcd" in why and "a conflict" in why, why
    why = frames[f"{SECS}_010000000"]["reason"]
    assert f"its nearest image {names[0][1]}.png (0.019 s away) pairs with scan {first}.pcd" in why, why
    assert all(frames[s]["used"] for s, _ in names[:-1])


def test_padded_microseconds_stay_a_decimal_fraction(
    simulated, tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    """``<secs>_<microseconds padded to 6>`` (``1510868224_007000``): the leading zero says padded, so
    the field is a decimal fraction (7 ms), not 7000 unpadded nanoseconds, and the run says so."""
    src, data = simulated("pinhole"), tmp_path / "data"
    (data / "pcd").mkdir(parents=True)
    (data / "img").mkdir()
    shutil.copy(src / "config.yaml", data / "config.yaml")
    for k, scan in enumerate(sorted((src / "pcd").iterdir())):
        image = next((src / "img").glob(f"{scan.stem}.*"))
        us = 7_000 + 1_000 * k
        shutil.copy(scan, data / "pcd" / f"{SECS + 2 * k}_{us:06d}{scan.suffix}")
        shutil.copy(image, data / "img" / f"{SECS + 2 * k}_{us + 12_000:06d}{image.suffix}")
    with caplog.at_level(logging.WARNING):
        frames = _calibrate(data, tmp_path / "out", capsys)
    assert all(f["used"] for f in frames.values()) and len(frames) == 5
    assert (
        f"names like {SECS}_007000 read as a decimal fraction ({SECS}.007000 s; some begin with 0"
        in caplog.text
    )
