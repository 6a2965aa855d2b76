"""A lab's first recording in its own folder names: KITTI's ``velodyne/`` + ``image_2/`` (and KITTI
raw's ``velodyne_points/data``), ``lidar/`` + ``camera/``, ... are taken where ``pcd/`` and ``img/``
are not there (``io.data_folders``); two folders that could hold the same kind are refused with
both named and the way to choose; scans and images named by their times (recorders, bag_to_pcd)
pair by those times when no name is shared (docs/datasets.md)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.datasets import open_source
from ilcc_graph.datasets.watch import GrowingFolder
from ilcc_graph.errors import InputError
from ilcc_graph.io import data_folders, list_frames, read_ground_truth, read_scan


def _renamed(src: Path, dst: Path, scans: str, images: str) -> Path:
    """A copy of the data set ``src`` with its pcd/ and img/ moved to ``scans`` and ``images``."""
    dst.mkdir(parents=True)
    shutil.copy(src / "config.yaml", dst / "config.yaml")
    shutil.copytree(src / "pcd", dst / scans)
    shutil.copytree(src / "img", dst / images)
    return dst


def test_kitti_folder_names_calibrate_as_pcd_and_img(simulated, calibrated, tmp_path, capsys) -> None:
    src = simulated("pinhole")
    data = _renamed(src, tmp_path / "kitti", "velodyne", "image_2")
    out = tmp_path / "out"
    assert main(["calibrate", str(data), "--out", str(out), "--jobs", "1", "--no-report"]) == 0
    capsys.readouterr()
    got = yaml.safe_load((out / "calibration.yaml").read_text())
    want = yaml.safe_load((calibrated(src) / "calibration.yaml").read_text())
    np.testing.assert_array_equal(np.array(got["T_cam_lidar"]), np.array(want["T_cam_lidar"]))
    assert [f["used"] for f in got["frames"]] == [f["used"] for f in want["frames"]]
    # the same set opened as the rig of one pair reads the same folders
    rig = open_source(data, rig=True)
    assert len(rig.moments()) == len(want["frames"])


def test_a_kitti_style_recording_calibrates(simulated, tmp_path, capsys) -> None:
    """velodyne/<stem>.bin (float32 x y z reflectance in [0, 1], no ring) + image_2/<stem>.png:
    KITTI's layout and scan format, through the command line, near the truth."""
    src = simulated("pinhole")
    data = tmp_path / "kitti"
    (data / "velodyne").mkdir(parents=True)
    shutil.copytree(src / "img", data / "image_2")
    shutil.copy(src / "config.yaml", data / "config.yaml")
    for p in sorted((src / "pcd").iterdir()):
        scan = read_scan(p)
        rec = np.column_stack([scan.points, scan.intensity / scan.intensity.max()]).astype("<f4")
        rec.tofile(data / "velodyne" / f"{p.stem}.bin")
    out = tmp_path / "out"
    assert main(["calibrate", str(data), "--out", str(out), "--jobs", "1", "--no-report"]) == 0
    capsys.readouterr()
    got = yaml.safe_load((out / "calibration.yaml").read_text())
    E = np.linalg.inv(read_ground_truth(src).T_cam_lidar) @ np.array(got["T_cam_lidar"])
    rot_deg = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1.0, 1.0)))
    assert sum(f["used"] for f in got["frames"]) >= 4
    assert rot_deg < 0.1 and np.linalg.norm(E[:3, 3]) < 0.005, (rot_deg, E[:3, 3])


def test_kitti_raw_nesting_and_other_names(simulated, tmp_path) -> None:
    src = simulated("pinhole")
    raw = _renamed(src, tmp_path / "raw", "velodyne_points/data", "image_02/data")
    (raw / "velodyne_points" / "timestamps.txt").write_text("2011-09-26 13:02:25.9\n")
    assert data_folders(raw) == ("velodyne_points/data", "image_02/data")
    frames, skipped = list_frames(raw)
    assert [f.name for f in frames] == [p.stem for p in sorted((src / "pcd").iterdir())] and skipped == []
    mine = _renamed(src, tmp_path / "mine", "lidar", "images")
    (mine / "camera").mkdir()  # a folder of that name holding no image: not a candidate
    (mine / "camera" / "intrinsics.yaml").write_text("K: []\n")
    assert data_folders(mine) == ("lidar", "images")
    # the layout's own names win over any other
    both = _renamed(src, tmp_path / "both", "pcd", "img")
    shutil.copytree(src / "img", both / "camera")
    assert data_folders(both) == ("pcd", "img")


def test_two_folders_of_images_are_refused_naming_both(simulated, tmp_path, capsys) -> None:
    src = simulated("pinhole")
    data = _renamed(src, tmp_path / "two", "velodyne", "image_2")
    shutil.copytree(src / "img", data / "image_3")
    with pytest.raises(InputError, match=r"images could be in any of image_2/, image_3/: name the one"):
        list_frames(data)
    assert main(["calibrate", str(data), "--out", str(tmp_path / "out"), "--jobs", "1"]) == 2
    err = capsys.readouterr().err
    assert str(data) in err and "ln -s image_2" in err and not (tmp_path / "out").exists()
    shutil.rmtree(data / "image_3")
    shutil.rmtree(data / "velodyne")
    with pytest.raises(InputError, match=r"no 'pcd' folder .*also taken: lidar/, velodyne/"):
        list_frames(data)


def test_a_growing_folder_with_other_names(simulated, tmp_path) -> None:
    src = simulated("pinhole")
    dst = tmp_path / "g"
    (dst / "lidar").mkdir(parents=True)
    (dst / "camera").mkdir()
    stem = sorted((src / "pcd").iterdir())[0].stem
    image = next((src / "img").glob(f"{stem}.*"))
    shutil.copyfile(image, dst / "camera" / image.name)
    folder = GrowingFolder(dst, settle_s=0.0)
    assert folder.poll() == []  # the image alone
    shutil.copyfile(src / "pcd" / f"{stem}.pcd", dst / "lidar" / f"{stem}.pcd")
    got = folder.poll()
    assert [a.ref.name for a in got] == [stem] and got[0].ref.scan.parent.name == "lidar"


def _timed(
    src: Path, dst: Path, late_s: dict[int, float], digits: int | None = None, prefix: str = ""
) -> Path:
    """A copy of ``src`` whose files are named by times, as recorders and bag_to_pcd name them: scan
    k at 1700000000 + 2 k s, its image 12 ms later (``late_s``: other delays by k); ``digits``: whole
    microseconds (16 digits) instead of seconds with a fraction; ``prefix`` before every scan's name."""
    dst.mkdir(parents=True)
    shutil.copy(src / "config.yaml", dst / "config.yaml")
    (dst / "pcd").mkdir()
    (dst / "img").mkdir()

    def name(t: float) -> str:
        return f"{round(t * 1e6):d}" if digits == 16 else f"{t:.6f}"

    for k, scan in enumerate(sorted((src / "pcd").iterdir())):
        image = next((src / "img").glob(f"{scan.stem}.*"))
        t = 1700000000 + 2.0 * k
        shutil.copy(scan, dst / "pcd" / f"{prefix}{name(t)}{scan.suffix}")
        shutil.copy(image, dst / "img" / f"{name(t + late_s.get(k, 0.012))}{image.suffix}")
    return dst


def test_files_named_by_their_times_pair_by_time(simulated, calibrated, tmp_path, capsys, caplog) -> None:
    src = simulated("pinhole")
    data = _timed(src, tmp_path / "timed", {})
    out = tmp_path / "out"
    assert main(["calibrate", str(data), "--out", str(out), "--jobs", "1", "--no-report"]) == 0
    capsys.readouterr()
    got = yaml.safe_load((out / "calibration.yaml").read_text())
    want = yaml.safe_load((calibrated(src) / "calibration.yaml").read_text())
    n = len(want["frames"])
    assert f"{n} of {n} scans paired with an image of another name" in caplog.text
    np.testing.assert_allclose(
        np.array(got["T_cam_lidar"]), np.array(want["T_cam_lidar"]), rtol=0, atol=1e-12
    )
    assert [f["name"] for f in got["frames"]][0] == "1700000000.000000"
    # an image 0.3 s late pairs with nothing: its scan and it are skipped, saying how far
    late = open_source(_timed(src, tmp_path / "late", {1: 0.3}))
    frames, skipped = late.frames(), late.skipped()
    assert len(frames) == n - 1
    assert any("1700000002.000000" == s and "0.300 s away" in why for s, why in skipped), skipped
    # whole microseconds pair alike
    micro = _timed(src, tmp_path / "micro", {}, digits=16)
    assert len(open_source(micro).frames()) == n
    # names that happen to coincide (ms stamps of a 10 Hz and a 30 Hz sensor) pair as the rest do
    same = _timed(src, tmp_path / "same", {0: 0.0, 2: 0.0})
    frames = open_source(same).frames()
    assert len(frames) == n and [f.name for f in frames] == sorted(p.stem for p in (same / "pcd").iterdir())
    # a prefix every scan's name shares (a recorder's) is not part of the time
    frames = open_source(_timed(src, tmp_path / "prefixed", {}, prefix="cloud_")).frames()
    assert len(frames) == n and frames[0].name == "cloud_1700000000.000000"
    # a stray name that is no time among them is named and set aside, the rest pair by time (issue 36:
    # it turned pairing by time off for the whole folder, and the error named no file)
    first = sorted((micro / "img").iterdir())[0]
    first.rename(first.with_name("left" + first.suffix))
    stray = open_source(micro)
    assert len(stray.frames()) == n - 1
    assert any(s == "left" and "image left.png: its name is no time like the others'" in why
               for s, why in stray.skipped()), stray.skipped()  # fmt: skip


def test_a_warning_is_said_once_per_command() -> None:
    """The command line's log says each line once (``console.SaidOnce``), anew for each command (in a
    process of its own: the logging of this one stays as pytest set it)."""
    import subprocess
    import sys

    code = (
        "import logging; from ilcc_graph.app.console import setup_logging\n"
        "log = logging.getLogger('ilcc_graph.x')\n"
        "for verbose in (False, True):\n"
        "    setup_logging(verbose)\n"
        "    for _ in range(3): log.warning('only 3 usable frame(s)')\n"
        "    log.warning('another')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stderr.splitlines() == ["WARNING: only 3 usable frame(s)", "WARNING: another"] * 2
