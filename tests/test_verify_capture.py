"""``verify`` accepts every capture ``calibrate`` accepts (issue 34): a pair's capture is observed and
solved as ``calibrate`` does it, so a capture whose config names the print's lower-left colour wrongly
is checked on all its boards (not "seen by one sensor only"), the very capture a calibration came
from shows no change at all, and the same capture with the LiDAR's mount knocked by 0.3 deg / 12 mm
fails. Through the command line, on a simulated set and on the recorded VLP-16 + fisheye set split
in two (there the verdict is calibrate's: the 6 frames' own calibration against the 14's)."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from ilcc_graph.app import main
from ilcc_graph.estimation.sessions import compare_estimates
from ilcc_graph.estimation.verify import StoredRig, net_of_terms
from ilcc_graph.io import read_calibration, read_pcd, write_pcd


def _verify(cal: Path, data: Path, out: Path) -> tuple[int, dict]:
    code = main(["verify", str(cal), str(data), "--out", str(out), "--jobs", "1"])
    return code, yaml.safe_load((out / "verify.yaml").read_text(encoding="utf-8"))


def _wrong_colour(data: Path, out: Path) -> Path:
    """A copy of ``data`` (scans and images linked) whose config names the other lower-left colour."""
    out.mkdir()
    for sub in ("pcd", "img"):
        (out / sub).mkdir()
        for f in sorted((data / sub).iterdir()):
            (out / sub / f.name).symlink_to(f.resolve())
    d = yaml.safe_load((data / "config.yaml").read_text(encoding="utf-8"))
    d["board"]["lower_left"] = "white" if d["board"]["lower_left"] == "black" else "black"
    (out / "config.yaml").write_text(yaml.safe_dump(d), encoding="utf-8")
    return out


def _knocked(data: Path, out: Path) -> Path:
    """A copy of ``data`` whose every cloud is turned 0.3 deg about the LiDAR's z axis and moved 12 mm
    along its x axis: the LiDAR's mount knocked."""
    shutil.copytree(data, out, symlinks=True)
    R = Rotation.from_euler("z", 0.3, degrees=True).as_matrix()
    for f in sorted((out / "pcd").iterdir()):
        scan = read_pcd(f)
        f.unlink()  # a link into the original: the moved scan is a new file
        write_pcd(f, dataclasses.replace(scan, points=scan.points @ R.T + np.array([0.012, 0.0, 0.0])))
    return out


def _check_capture(cal: Path, capture: Path, frames: int, tmp: Path) -> None:
    """The wrong-colour capture is checked on all its boards and not failed; knocked, it fails."""
    code, doc = _verify(cal, capture, tmp / "v-same")
    cam = doc["sensors"]["camera"]
    assert code in (0, 4) and cam["verdict"] in ("pass", "warn"), cam["reason"]
    assert "unchecked" not in cam["reason"] and cam["boards"] >= frames - 1, cam
    code, doc = _verify(cal, _knocked(capture, tmp / "knocked"), tmp / "v-knocked")
    cam = doc["sensors"]["camera"]
    assert code == 5 and cam["verdict"] == "fail", cam["reason"]
    assert cam["boards"] >= frames - 1 and 8 < cam["translation_mm"] < 20, cam


def test_verify_a_simulated_capture_named_with_the_wrong_colour(simulated, tmp_path: Path) -> None:
    """Calibrated on one simulated set, verified with another of the same rig (the same LiDAR's beam
    errors: ``--rig-seed``) whose config names the wrong lower-left colour: all its boards checked, no
    failure; its LiDAR knocked: fail."""
    cal = tmp_path / "cal"
    first = simulated("fisheye", "--lidar", "vlp16", frames=8, seed=21)
    assert main(["calibrate", str(first), "--out", str(cal), "--no-report", "--jobs", "1"]) == 0
    second = simulated("fisheye", "--lidar", "vlp16", "--rig-seed", "21", frames=6, seed=22)
    _check_capture(cal / "calibration.yaml", _wrong_colour(second, tmp_path / "second"), 6, tmp_path)


def test_verify_a_calibration_against_its_own_capture(simulated, calibrated, tmp_path: Path) -> None:
    """The capture a calibration came from: the same solve, so no change (to rounding) and not failed."""
    data = simulated("fisheye", "--lidar", "vlp16", frames=8, seed=21)
    cal = calibrated(data) / "calibration.yaml"
    code, doc = _verify(cal, data, tmp_path / "v")
    cam = doc["sensors"]["camera"]
    assert code in (0, 4) and cam["rotation_deg"] < 1e-9 and cam["translation_mm"] < 1e-6, cam


def _frames_column(html: str, header: str) -> list[float]:
    """The report's Frames table's column ``header``, one float per frame."""
    from html.parser import HTMLParser

    rows: list[list[str]] = []

    class Cells(HTMLParser):
        def handle_starttag(self, tag: str, attrs: object) -> None:
            if tag == "tr":
                rows.append([])
            elif tag in ("td", "th") and rows:
                rows[-1].append("")

        def handle_data(self, data: str) -> None:
            if rows and rows[-1]:
                rows[-1][-1] += data

    Cells().feed(html[html.index("<h2>Frames</h2>") :])
    k = rows[0].index(header)
    return [float(r[k]) for r in rows[1:] if len(r) == len(rows[0])]


def test_a_calibration_whose_intrinsics_were_refined_is_seen_through_them(simulated, tmp_path: Path) -> None:
    """A pinhole stated twice a typical calibration's error off, calibrated with
    ``--refine-intrinsics``: its own capture is observed with the refined intrinsics the calibration
    stores (the same lens as stated then), so every board is checked and nothing changed (with the
    stated ones the capture's boards sat 9 of their sigmas from their images and it could not be
    calibrated: "unchecked", warn); its LiDAR knocked: fail. A capture that states other intrinsics
    keeps its own, said in a note. ``evaluate`` and the report take the refined ones too (with the
    stated ones the report drew the LiDAR's corners 4.7-5.5 px off the image's)."""
    data = simulated("pinhole", "--intrinsics-error", "2", frames=12, seed=3)
    cal = tmp_path / "cal"
    assert main(["calibrate", str(data), "--out", str(cal), "--jobs", "1", "--refine-intrinsics"]) == 0
    drawn = _frames_column((cal / "report" / "index.html").read_text(), "corner RMS (px)")
    assert len(drawn) == 12 and max(drawn) < 0.3, drawn
    refined = yaml.safe_load((cal / "calibration.yaml").read_text())["sensor_errors"]["camera_intrinsics"]
    assert any(abs(v["refined"] - v["stated"]) > 3 * v["sigma"] for v in refined.values()), refined
    code, doc = _verify(cal / "calibration.yaml", data, tmp_path / "v")
    cam = doc["sensors"]["camera"]
    assert code == 0 and cam["boards"] == 12 and cam["translation_mm"] < 1.0, cam
    code, doc = _verify(cal / "calibration.yaml", _knocked(data, tmp_path / "knocked"), tmp_path / "vk")
    cam = doc["sensors"]["camera"]
    assert code == 5 and cam["boards"] >= 11 and 8 < cam["translation_mm"] < 20, cam
    other = shutil.copytree(data, tmp_path / "other", symlinks=True)
    d = yaml.safe_load((other / "config.yaml").read_text())
    d["camera"]["K"][0][0] += 1.0
    (other / "config.yaml").write_text(yaml.safe_dump(d))
    _, doc = _verify(cal / "calibration.yaml", other, tmp_path / "vo")
    assert any("stated otherwise than calibrated" in n for n in doc["notes"]), doc["notes"]
    # evaluate judges the calibration through the same lens: its corners within 0.3 px (with the
    # stated intrinsics, 4.3 px on average: the extrinsic judged through the wrong lens)
    ev = tmp_path / "ev"
    assert main(["evaluate", str(data), str(cal / "calibration.yaml"), "--out", str(ev), "--jobs", "1"]) == 0
    overall = yaml.safe_load((ev / "evaluation.yaml").read_text())["overall"]
    assert overall["frames"] == 12 and overall["corner_px_mean"] < 0.3, overall


@pytest.mark.slow
def test_verify_the_recorded_set_split_in_two(acfr_data: Path, tmp_path: Path) -> None:
    """acfr-vlp16-fisheye: 14 frames calibrated, the last 6 verified with the colour named wrongly:
    every board checked, and the change and its test exactly those of ``calibrate`` run on the 6
    frames (verify solves the capture as calibrate does; the change net of the LiDAR's range terms
    both runs estimated); those 6 with the mount knocked fail."""
    frames = sorted(p.stem for p in (acfr_data / "pcd").iterdir())
    half = tmp_path / "half"
    for sub, suffix in (("pcd", ".pcd"), ("img", ".png")):
        (half / sub).mkdir(parents=True)
        for stem in frames[:-6]:
            (half / sub / f"{stem}{suffix}").symlink_to((acfr_data / sub / f"{stem}{suffix}").resolve())
    shutil.copy(acfr_data / "config.yaml", half / "config.yaml")
    rest = _wrong_colour(acfr_data, tmp_path / "rest")
    for sub in ("pcd", "img"):
        for f in (rest / sub).iterdir():
            if f.stem not in frames[-6:]:
                f.unlink()
    cal = tmp_path / "cal"
    assert main(["calibrate", str(half), "--out", str(cal), "--no-report", "--jobs", "1"]) == 0
    alone = tmp_path / "alone"
    assert main(["calibrate", str(rest), "--out", str(alone), "--no-report", "--jobs", "1"]) == 0
    stored, new = (read_calibration(d / "calibration.yaml") for d in (cal, alone))
    d, C = compare_estimates(
        *(StoredRig.pair(c.T_cam_lidar, c.covariance).pose("camera") for c in (stored, new))
    )
    if stored.with_terms is not None and new.with_terms is not None:  # the mount net of the terms
        net = net_of_terms(stored.with_terms.inverse(), new.with_terms.inverse(), 0.05)
        if net is not None and net[0] is not None and net[1] is not None:
            d, C = net[0], net[1]
    code, doc = _verify(cal / "calibration.yaml", rest, tmp_path / "v-same")
    cam = doc["sensors"]["camera"]
    assert "unchecked" not in cam["reason"] and cam["boards"] == sum(f.used for f in new.frames) >= 5, cam
    assert cam["chi2"] == pytest.approx(float(d @ np.linalg.solve(C, d)), rel=1e-6), cam
    code, doc = _verify(
        cal / "calibration.yaml", _knocked(rest, tmp_path / "knocked"), tmp_path / "v-knocked"
    )
    cam = doc["sensors"]["camera"]
    assert code == 5 and cam["verdict"] == "fail" and cam["boards"] >= 5, cam["reason"]
