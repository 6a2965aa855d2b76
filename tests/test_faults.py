"""Fault injection: damaged files, user mistakes, unwritable and full disks, two runs into one folder.

Every case is what a user meets with real files: a damaged frame costs that frame (loudly), a mistake
gets one line and exit 2, an internal error exit 1 with the traceback in a log file, and the output
folder is complete or absent. Signals are in test_faults_signals.py, reader fuzzing in
test_faults_fuzz.py.
"""

from __future__ import annotations

import dataclasses
import errno
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

import ilcc_graph.io.files as io_files
from ilcc_graph.app import main
from ilcc_graph.app.write import write_run
from ilcc_graph.datasets import FolderSource, open_source
from ilcc_graph.errors import InputError, OutputError
from ilcc_graph.io import list_frames, read_scan, write_calibration, write_pcd, write_ply
from ilcc_graph.io.output_folders import MARKER, staged
from ilcc_graph.io.scans import write_csv
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.result import Result, RunOptions, SessionResult
from ilcc_graph.types import Calibration, FrameResult


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    """A small simulated panoramic set (6 frames, 2000 px)."""
    out = tmp_path_factory.mktemp("faults") / "sim"
    assert main(["simulate", str(out), "--frames", "6", "--seed", "1", "--width", "2000"]) == 0
    return out


@pytest.fixture
def result(sim):  # noqa: ANN201 - pipeline.RunResult
    """A run's result as write_run takes it, made by hand (no calibration): 100 frames' reasons."""
    source = open_source(sim)
    frames = tuple(FrameResult(f"{i:04d}", False, "no board " * 20) for i in range(100))
    cal = Calibration(np.eye(4), 1e-6 * np.eye(6), frames)
    obs = Observation(source, source.config(), list(frames))
    return Result("graph", cal, (SessionResult("sim", obs, cal),), RunOptions())


def _copy(sim: Path, dst: Path) -> Path:
    shutil.copytree(sim, dst)
    return dst


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".partial-" in p.name or ".old-" in p.name)


# ---------------------------------------------------------------------------------- damaged files


def _damaged_files(sim: Path, d: Path) -> dict[str, Path]:
    """One damaged file of every format the tool reads (made from a real simulated scan and image)."""
    scan = read_scan(sim / "pcd" / "0001.pcd")
    files = {}
    good = d / "good.pcd"
    write_pcd(good, scan)
    raw = good.read_bytes()
    files["pcd truncated"] = d / "truncated.pcd"
    files["pcd truncated"].write_bytes(raw[: len(raw) // 2])
    files["pcd header"] = d / "header.pcd"
    files["pcd header"].write_bytes(raw.replace(b"FIELDS", b"FEILDS", 1))
    write_pcd(d / "c.pcd", scan, data="binary_compressed")
    c = bytearray((d / "c.pcd").read_bytes())
    c[-200:-100] = bytes(100)  # an LZF block that no longer expands to its size
    files["pcd compressed"] = d / "compressed.pcd"
    files["pcd compressed"].write_bytes(bytes(c))
    write_pcd(d / "a.pcd", scan, data="ascii")
    files["pcd ascii"] = d / "ascii.pcd"
    files["pcd ascii"].write_text((d / "a.pcd").read_text().replace("\n", "\nnot a number\n", 20))
    write_csv(d / "g.csv", scan)
    files["csv"] = d / "bad.csv"
    files["csv"].write_text("\n".join((d / "g.csv").read_text().splitlines()[:50]) + "\n1,2\n")
    files["bin"] = d / "bad.bin"
    files["bin"].write_bytes(np.zeros(4 * 4 * 10 + 3, np.uint8).tobytes())
    write_ply(d / "g.ply", scan)
    files["ply"] = d / "truncated.ply"
    files["ply"].write_bytes((d / "g.ply").read_bytes()[:400])
    files["empty"] = d / "empty.pcd"
    files["empty"].write_bytes(b"")
    return files


def test_every_damaged_scan_format_names_the_file(sim, tmp_path):
    for what, path in _damaged_files(sim, tmp_path).items():
        with pytest.raises(InputError) as exc:
            read_scan(path)
        assert path.name in str(exc.value), what


def _image_damage(data: Path) -> None:
    (data / "img" / "0004.png").write_bytes(b"\x89PNG\r\n\x1a\n" + os.urandom(300))  # undecodable
    small = cv2.resize(cv2.imread(str(data / "img" / "0005.png")), (1000, 500))
    cv2.imwrite(str(data / "img" / "0005.png"), small)  # not the camera's size


def test_damaged_frames_cost_only_those_frames(sim, tmp_path, capsys, caplog):
    data = _copy(sim, tmp_path / "data")
    raw = (data / "pcd" / "0002.pcd").read_bytes()
    (data / "pcd" / "0002.pcd").write_bytes(raw[: len(raw) // 3])  # truncated
    _image_damage(data)
    out = tmp_path / "out"
    with caplog.at_level("WARNING"):
        assert main(["calibrate", str(data), "--out", str(out), "--jobs", "1"]) == 0
    assert "3 skipped for damaged files" in capsys.readouterr().out
    warned = [r.getMessage() for r in caplog.records if "skipped" in r.getMessage()]
    for name in ("0002.pcd", "0004.png", "0005.png"):
        assert sum(name in w for w in warned) == 1  # a warning per damaged frame
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    frames = {f["name"]: f for f in cal["frames"]}
    for name, file in (("0002", "0002.pcd"), ("0004", "0004.png"), ("0005", "0005.png")):
        assert frames[name]["damaged"] is True and not frames[name]["used"]
        assert file in frames[name]["reason"]
    assert "camera.width" in frames["0005"]["reason"] and "1000x500" in frames["0005"]["reason"]
    assert sum(f["used"] for f in cal["frames"]) == 3
    page = (out / "report" / "index.html").read_text()
    assert "0002.pcd" in page and "0004.png" in page  # the report's frame table gives the reasons

    assert main(["calibrate", str(data), "--out", str(tmp_path / "strict"), "--jobs", "1", "--strict"]) == 2
    err = capsys.readouterr().err
    assert "0002.pcd" in err or "0004.png" in err or "0005.png" in err
    assert "Traceback" not in err and not (tmp_path / "strict").exists()


def test_images_all_of_another_size_name_the_config_keys(sim, tmp_path, capsys):
    data = tmp_path / "data"
    shutil.copytree(sim / "pcd", data / "pcd")
    (data / "img").mkdir()
    shutil.copy(sim / "config.yaml", data / "config.yaml")
    for p in sorted((sim / "img").iterdir()):
        cv2.imwrite(str(data / "img" / p.name), cv2.resize(cv2.imread(str(p)), (960, 480)))
    assert main(["calibrate", str(data), "--out", str(tmp_path / "out"), "--jobs", "1"]) == 2
    err = capsys.readouterr().err
    assert "0001.png" in err and "960x480" in err and "camera.width" in err and "2000x1000" in err
    assert "Traceback" not in err


def test_a_frame_with_two_scans_is_said_once(tmp_path, caplog):
    for sub in ("pcd", "img"):
        (tmp_path / sub).mkdir()
    for name in ("pose21.pcd", "pose21.bin", "pose22.pcd"):
        (tmp_path / "pcd" / name).write_bytes(b"x")
    for name in ("pose21.png", "pose22.png"):
        (tmp_path / "img" / name).write_bytes(b"x")
    frames, skipped = list_frames(tmp_path)
    assert [f.name for f in frames] == ["pose21", "pose22"] and skipped == []
    assert frames[0].scan.name == "pose21.pcd"
    assert "pcd/pose21.bin" in frames[0].note and "using pose21.pcd" in frames[0].note
    (tmp_path / "config.yaml").write_text("")
    source = FolderSource(tmp_path)
    with caplog.at_level("WARNING"):
        source.frames()
        source.frames()
    said = [r for r in caplog.records if "pose21" in r.getMessage()]
    assert len(said) == 1 and "2 scans" in said[0].getMessage()


# ------------------------------------------------------------------------------- user mistakes


@pytest.mark.parametrize(
    "argv, flag",
    [
        (["simulate", "X", "--frames", "0"], "--frames"),
        (["simulate", "X", "--width", "-100"], "--width"),
        (["simulate", "X", "--noise-scale", "-1"], "--noise-scale"),
        (["calibrate", "X", "--jobs", "0"], "--jobs"),
        (["calibrate", "X", "--alpha", "1.5"], "--alpha"),
        (["calibrate", "X", "--target-sigma", "-1,2"], "--target-sigma"),
        (["demo", "--width", "10"], "--width"),
    ],
)
def test_bad_values_are_usage_errors_naming_the_flag(argv, flag, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert flag in err and "Traceback" not in err


def _calibration_file(path: Path) -> Path:
    camera = {"model": "equirectangular", "width": 2000, "height": 1000}  # kitti needs the camera's axes
    write_calibration(path, Calibration(np.eye(4), 1e-6 * np.eye(6), (), camera=camera))
    return path


def test_outputs_that_cannot_be_written_are_exit_2(sim, tmp_path, readonly_dir, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    cal = _calibration_file(tmp_path / "calibration.yaml")
    cases = [
        (["calibrate", str(sim), "--out", str(a_file)], "is an existing file"),
        (["calibrate", str(sim), "--out", str(a_file / "run")], "is a file"),
        (["calibrate", str(sim), "--out", str(readonly_dir / "run")], "cannot write"),
        (["lidar-corners", str(sim), "--out", str(a_file)], "is an existing file"),
        (["evaluate", str(sim), str(cal), "--out", str(a_file / "ev")], "is a file"),
        (["export", str(cal), "--format", "kitti", "--out", str(readonly_dir / "k.txt")], "cannot write"),
        (["export", str(cal), "--format", "kitti", "--out", str(a_file / "k.txt")], "is a file, so"),
        (["export", str(cal), "--format", "kitti", "--out", str(tmp_path)], "is a folder"),
        (["simulate", str(a_file / "sim")], "is a file"),
        (["simulate", str(a_file)], "is an existing file"),
    ]
    for argv, what in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert what in err and "Traceback" not in err, (argv, err)
    assert a_file.read_text() == "x"


def test_an_internal_error_is_one_line_and_a_log(sim, tmp_path, capsys, monkeypatch):
    import ilcc_graph.run.pipeline

    def broken(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        raise ZeroDivisionError("boom")

    monkeypatch.setattr(ilcc_graph.run.pipeline, "run", broken)
    out = tmp_path / "run"
    assert main(["calibrate", str(sim), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "internal error" in err[0] and "ZeroDivisionError: boom" in err[0]
    log = tmp_path / "run.error.log"
    assert str(log) in err[0] and "Traceback" in log.read_text() and "boom" in log.read_text()
    assert not out.exists()
    assert main(["calibrate", str(sim), "--out", str(out), "--debug"]) == 1
    assert "Traceback" in capsys.readouterr().err


# ----------------------------------------------------------------------------------- full disks


def test_a_write_that_fails_leaves_no_output(result, tmp_path, monkeypatch):
    calls = [0]
    real = os.fsync

    def full(fd: int) -> None:
        calls[0] += 1
        if calls[0] > 1:  # the first file goes through, the second finds the disk full
            raise OSError(errno.ENOSPC, "No space left on device")
        real(fd)

    monkeypatch.setattr(io_files.os, "fsync", full)
    out = tmp_path / "run"
    with pytest.raises(OutputError, match="No space left on device"):
        write_run(out, result, report=False)
    assert not out.exists() and _leftovers(tmp_path) == []


@pytest.fixture
def tiny_disk(tmp_path) -> Path:
    """A 16 KiB tmpfs (root only)."""
    d = tmp_path / "tiny"
    d.mkdir()
    if (
        os.geteuid() != 0
        or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=16k", "tmpfs", str(d)], capture_output=True
        ).returncode
    ):
        pytest.skip("cannot mount a tmpfs here (needs root)")
    yield d
    subprocess.run(["umount", str(d)], check=False)


def test_a_full_disk_leaves_nothing_half_written(result, tiny_disk, capsys):
    with pytest.raises(OutputError, match="No space left"):
        write_run(tiny_disk / "run", result, report=False)  # calibration.yaml alone is ~20 KB
    assert list(tiny_disk.iterdir()) == []
    assert main(["simulate", str(tiny_disk / "sim"), "--frames", "2", "--width", "1000"]) == 2
    err = capsys.readouterr().err
    assert "No space left" in err and "Traceback" not in err
    assert list(tiny_disk.iterdir()) == []


# ------------------------------------------------------------------------------------ concurrency


def test_two_writers_racing_for_one_folder_leave_one_complete_result(tmp_path):
    out = tmp_path / "run"

    def write(who: str, barrier: threading.Barrier, errors: list) -> None:
        try:
            with staged(out) as d:
                for i in range(20):
                    (d / f"{i}.txt").write_text(who)
                barrier.wait(timeout=10)  # both commit at the same moment
        except BaseException as err:  # noqa: BLE001 - reported below
            errors.append(err)

    for _ in range(10):
        barrier, errors = threading.Barrier(2), []
        threads = [threading.Thread(target=write, args=(w, barrier, errors)) for w in ("A", "B")]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert errors == []
        files = [p for p in out.iterdir() if p.name != MARKER]
        writers = {p.read_text() for p in files}
        assert len(writers) == 1 and len(files) == 20  # one writer's files, all of them
        assert _leftovers(tmp_path) == []


_WRITER = """
import sys, time
from pathlib import Path
from ilcc_graph.io.output_folders import staged
out, who, go = Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3])
with staged(out) as d:
    for i in range(50):
        (d / f"{i}.txt").write_text(who)
    (go.parent / f"ready-{who}").write_text("")
    while not go.exists():
        time.sleep(0.005)
"""


def test_two_processes_committing_one_folder_at_once(tmp_path):
    """Two processes stage their results, then commit into the same folder at the same moment."""
    out, go = tmp_path / "run", tmp_path / "go"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _WRITER, str(out), who, str(go)], env=env, stderr=subprocess.PIPE
        )
        for who in ("A", "B")
    ]
    for _ in range(6000):
        if all((tmp_path / f"ready-{w}").exists() for w in "AB") or any(p.poll() is not None for p in procs):
            break
        threading.Event().wait(0.01)
    go.write_text("")
    errs = [p.communicate(timeout=60)[1].decode() for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errs
    files = [p for p in out.iterdir() if p.name != MARKER]
    writers = {p.read_text() for p in files}
    assert len(writers) == 1 and len(files) == 50  # one writer's files, all of them
    assert _leftovers(tmp_path) == []


# ------------------------------------------------------------------------------ set-up mistakes


def _pose(rng: np.random.Generator) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()
    T[:3, 3] = [rng.uniform(-0.8, 0.8), rng.uniform(-0.3, 0.3), rng.uniform(1.5, 4.0)]  # OpenCV: z ahead
    return T


@pytest.mark.parametrize("configured", [0.075, 0.09, 0.0625])
def test_board_scale_is_the_square_size_ratio_without_an_extrinsic(configured):
    """Images of a 0.075 m print, read with another square size, against the scans' board poses."""
    from ilcc_graph.board import Board
    from ilcc_graph.evaluation.causes import board_scale
    from ilcc_graph.types import ImageCorners

    rng = np.random.default_rng(0)
    true, cfg = Board(6, 8, 0.075), Board(6, 8, configured)
    T_lidar_cam = _pose(rng)  # any extrinsic: the check does not use it
    pairs = []
    for _ in range(5):
        T_cam_board = _pose(rng)
        p = true.corners_board() @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
        corners = ImageCorners(
            np.zeros((len(p), 2)),
            p / np.linalg.norm(p, axis=1, keepdims=True),
            np.zeros((len(p), 2, 2)),
            False,
        )
        shift = np.eye(4)
        shift[:3, 3] = true.pattern_centre - cfg.pattern_centre  # the scans' fit centres the (wrong) pattern
        pairs.append((corners, T_lidar_cam @ T_cam_board @ shift))
    k, spread, n = board_scale(pairs, cfg)
    assert n >= 6 and abs(k - configured / 0.075) < 1e-6 and spread < 1e-6


def test_a_wrong_square_size_is_said_in_one_statement(sim, tmp_path, capsys):
    data = tmp_path / "data"
    data.mkdir()
    for sub in ("pcd", "img"):
        (data / sub).symlink_to(sim / sub)
    cfg = yaml.safe_load((sim / "config.yaml").read_text())
    cfg["board"]["square_size"] = 0.09  # the print's squares are 0.075 m
    (data / "config.yaml").write_text(yaml.safe_dump(cfg))
    assert main(["calibrate", str(data), "--out", str(tmp_path / "out"), "--no-report"]) == 3
    lines = capsys.readouterr().err.splitlines()
    starts = [k for k, ln in enumerate(lines) if ln.startswith("likely:")]
    assert len(starts) == 1, lines  # one statement, wrapped to the terminal's 80 columns
    k = starts[0] + 1
    while k < len(lines) and lines[k].startswith("  "):
        k += 1
    said = " ".join(ln.strip() for ln in lines[starts[0] : k])
    assert all(len(ln) <= 80 for ln in lines[starts[0] : k]), lines
    assert "board.square_size 0.09 m looks wrong" in said, said
    assert "a square of this print is about 0.07" in said, said


def test_a_part_of_a_bigger_print_is_seen(sim):
    """[5, 7] configured for the [6, 8] print: the image stage refuses the part of it a detector finds
    in frame 0001 (issue 38); beyond such a part (the [6, 8] corners without their last row and
    column) the checker pattern goes on by a row and a column."""
    from ilcc_graph.errors import PartialPattern
    from ilcc_graph.run.setup_mistakes import pattern_continues
    from ilcc_graph.run.stages import StageOptions, observe_image
    from ilcc_graph.types import ImageCorners

    source = open_source(sim)
    ref = source.frames()[0]
    right = source.config()
    wrong = dataclasses.replace(right, board=dataclasses.replace(right.board, rows=5, cols=7))
    image = source.read_image(ref)
    with pytest.raises(PartialPattern, match="the pattern continues beyond its .* board.squares \\[5, 7\\]"):
        observe_image(source, ref, wrong, StageOptions())
    whole = observe_image(source, ref, right, StageOptions())
    keep = (np.arange(5 * 7).reshape(5, 7)[:4, :6]).ravel()
    part = ImageCorners(whole.uv[keep], whole.bearings[keep], whole.cov_px[keep], False)
    assert pattern_continues(image, wrong.board, wrong.camera, part) == (1, 1)
    assert pattern_continues(image, right.board, right.camera, whole) == (0, 0)
