"""Output folders through the command line: a run writes only into a folder that is new, empty or an
earlier result of ours, refuses anything else before any work (exit 2, naming the path), and what
it writes follows the umask (docs/faults.md, "Output folders").

Every refusal is checked the way a user meets it: the real command, the real folder, every file in
it byte-identical afterwards, and the command's work never started (the function doing it raises).
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from ilcc_graph.app import main
from ilcc_graph.io.output_folders import MARKER


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    """A small simulated panoramic set (4 frames, 1200 px): it calibrates."""
    out = tmp_path_factory.mktemp("folders") / "sim"
    assert main(["simulate", str(out), "--frames", "4", "--seed", "1", "--width", "1200"]) == 0
    return out


@pytest.fixture(scope="module")
def earlier(sim, tmp_path_factory) -> Path:
    """An earlier result of ours (calibrate --no-report), copied by the tests that change it."""
    out = tmp_path_factory.mktemp("earlier") / "run"
    assert main(["calibrate", str(sim), "--out", str(out), "--no-report", "--jobs", "1"]) == 0
    return out


def snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry under ``folder``: (kind, mode, bytes or link target)."""
    got = {}
    for p in sorted(folder.rglob("*")):
        st = os.lstat(p)
        if stat.S_ISLNK(st.st_mode):
            got[str(p.relative_to(folder))] = ("link", os.readlink(p))
        elif p.is_dir():
            got[str(p.relative_to(folder))] = ("dir", stat.S_IMODE(st.st_mode))
        else:
            got[str(p.relative_to(folder))] = ("file", stat.S_IMODE(st.st_mode), p.read_bytes())
    return got


@pytest.fixture
def no_work(monkeypatch):
    """Every command's work raises: a refusal must come before it."""
    import ilcc_graph.app.check_view
    import ilcc_graph.run.evaluate
    import ilcc_graph.run.observe
    import ilcc_graph.run.pipeline
    import ilcc_graph.simulate.write_set

    def started(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        raise AssertionError("the command's work started before its output folder was checked")

    monkeypatch.setattr(ilcc_graph.run.pipeline, "run", started)
    monkeypatch.setattr(ilcc_graph.run.observe, "stage_alone", started)
    monkeypatch.setattr(ilcc_graph.app.check_view, "check_command", started)
    monkeypatch.setattr(ilcc_graph.run.evaluate, "evaluate_on", started)
    monkeypatch.setattr(ilcc_graph.simulate.write_set, "simulate_frames", started)


def _commands(data: Path, out: Path, cal: Path, cache: Path) -> list[list[str]]:
    """Every command that writes a folder, with ``out`` as that folder."""
    return [
        ["calibrate", str(data), "--out", str(out)],
        ["lidar-corners", str(data), "--out", str(out)],
        ["image-corners", str(data), "--out", str(out)],
        ["check", str(data), "--out", str(out)],
        ["evaluate", str(data), str(cal), "--out", str(out)],
        ["verify", str(cal), str(data), "--out", str(out)],
        ["demo", "--cache", str(cache), "--out", str(out)],
    ]


def _refused(argv: list[str], capsys, *said: str) -> str:
    assert main(argv) == 2, argv
    err = capsys.readouterr().err
    assert "Traceback" not in err and all(s in err for s in said), (argv, err)
    return err


def test_out_at_the_data_folder_is_refused_and_nothing_touched(sim, earlier, tmp_path, no_work, capsys):
    data = tmp_path / "data"
    shutil.copytree(sim, data)
    before = snapshot(data)
    for argv in _commands(data, data, earlier / "calibration.yaml", tmp_path / "cache")[:6]:
        _refused(argv, capsys, f"--out {data}", "holds the data set this run reads")
    assert snapshot(data) == before
    # the simulated set is ours, but a data set: no run replaces it, whatever reads it
    _refused(["calibrate", str(sim), "--out", str(data)], capsys, "is a data set written by")
    assert snapshot(data) == before
    assert not (tmp_path / "cache").exists()


def test_out_at_a_folder_of_the_users_is_refused_and_every_file_kept(sim, earlier, tmp_path, no_work, capsys):
    home = tmp_path / "home"
    (home / "projects").mkdir(parents=True)
    (home / "projects" / "thesis.tex").write_text("\\chapter{LiDAR}\n")
    (home / ".bashrc").write_text("alias ll='ls -l'\n")
    (home / "calibration.yaml").write_text("mine: true\n")  # a name we write, but not ours
    os.chmod(home / ".bashrc", 0o600)
    before = snapshot(home)
    for argv in _commands(sim, home, earlier / "calibration.yaml", tmp_path / "cache"):
        _refused(
            argv, capsys, f"--out {home}", "holds files ilcc-graph did not write", ".bashrc", "projects/"
        )
    _refused(["simulate", str(home)], capsys, f"simulate {home}", "holds files ilcc-graph did not write")
    _refused(["simulate-rig", str(home)], capsys, f"simulate {home}", "holds files ilcc-graph did not write")
    assert snapshot(home) == before
    assert not (tmp_path / "cache").exists()  # the demo refused before simulating


def test_an_earlier_result_holding_a_users_file_is_refused(sim, earlier, tmp_path, no_work, capsys):
    run = tmp_path / "run"
    shutil.copytree(earlier, run)
    (run / "notes.txt").write_text("frame 3 was blurry\n")
    before = snapshot(run)
    _refused(["calibrate", str(sim), "--out", str(run)], capsys, "notes.txt", "would lose")
    _refused(["lidar-corners", str(sim), "--out", str(run)], capsys, "notes.txt")
    assert snapshot(run) == before
    data = tmp_path / "data"  # an earlier simulated set with a file of the user's in a subfolder
    shutil.copytree(sim, data)
    (data / "img" / "notes.txt").write_text("0003 is blurred\n")
    before = snapshot(data)
    _refused(["simulate", str(data)], capsys, "img/notes.txt", "would lose")
    assert snapshot(data) == before


def test_an_earlier_result_is_replaced_whole(sim, earlier, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(earlier, run)
    inode = run.stat().st_ino
    assert main(["lidar-corners", str(sim), "--out", str(run)]) == 0
    names = sorted(p.name for p in run.iterdir())
    assert "calibration.yaml" not in names and "0001_board.pcd" in names and MARKER in names
    marker = yaml.safe_load((run / MARKER).read_text())
    assert marker["kind"] == "result" and "lidar-corners" in marker["command"]
    assert sorted(marker["names"]) == sorted(n for n in names if n != MARKER)
    assert run.stat().st_ino != inode  # a new folder swapped in, not the old one edited
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no staging left
    # evaluate --out adds its file to an earlier result and keeps the rest
    shutil.rmtree(run)
    shutil.copytree(earlier, run)
    assert main(["evaluate", str(sim), str(run / "calibration.yaml"), "--out", str(run)]) == 0
    assert (run / "evaluation.yaml").is_file() and (run / "calibration.yaml").is_file()
    assert "evaluation.yaml" in yaml.safe_load((run / MARKER).read_text())["names"]
    capsys.readouterr()


def test_an_empty_folder_is_taken(sim, tmp_path, capsys):
    run = tmp_path / "empty"
    run.mkdir()
    assert main(["image-corners", str(sim), "--out", str(run)]) == 0
    assert (run / "0001.yaml").is_file() and (run / MARKER).is_file()
    capsys.readouterr()


def test_an_unwritable_place_is_refused_before_any_work(
    sim, earlier, tmp_path, readonly_dir, no_work, capsys
):
    for argv in _commands(sim, readonly_dir / "run", earlier / "calibration.yaml", tmp_path / "cache"):
        _refused(argv, capsys, str(readonly_dir / "run"), "cannot write")
    _refused(["simulate", str(readonly_dir / "sim")], capsys, "cannot write")
    assert list(readonly_dir.iterdir()) == [] and not (tmp_path / "cache").exists()


def test_the_current_folder_is_refused(sim, earlier, tmp_path, no_work, capsys, monkeypatch):
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    _refused(["calibrate", str(sim), "--out", "."], capsys, "--out .: is the current folder")
    run = tmp_path / "run"
    shutil.copytree(earlier, run)
    before = snapshot(run)
    monkeypatch.chdir(run)  # an earlier result, but the shell is in it
    _refused(["calibrate", str(sim), "--out", str(run)], capsys, "is the current folder or holds it")
    assert list(here.iterdir()) == [] and snapshot(run) == before


def test_a_link_to_a_folder_writes_the_target_and_stays(sim, tmp_path, capsys):
    target = tmp_path / "results" / "today"
    target.mkdir(parents=True)
    link = tmp_path / "link"
    link.symlink_to(target)
    # the target exists (empty): the run swaps its result in there, as over an earlier result
    assert main(["image-corners", str(sim), "--out", str(link)]) == 0
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert (target / "0001.yaml").is_file() and (target / MARKER).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "results"]
    assert sorted(p.name for p in target.parent.iterdir()) == ["today"]
    # a link whose target does not exist yet: the target is made
    dangling = tmp_path / "later"
    dangling.symlink_to(tmp_path / "results" / "tomorrow")
    assert main(["image-corners", str(sim), "--out", str(dangling)]) == 0
    assert dangling.is_symlink() and (tmp_path / "results" / "tomorrow" / "0001.yaml").is_file()
    # a link to a folder of the user's is refused like the folder
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "keep.txt").write_text("x")
    (tmp_path / "to-mine").symlink_to(mine)
    _refused(["image-corners", str(sim), "--out", str(tmp_path / "to-mine")], capsys, "keep.txt")
    assert [p.name for p in mine.iterdir()] == ["keep.txt"]


def _one_frame(sim: Path, dst: Path) -> Path:
    """A data set of one frame: calibration impossible (exit 3) at once."""
    for sub, name in (("pcd", "0001.pcd"), ("img", "0001.png")):
        (dst / sub).mkdir(parents=True)
        shutil.copy(sim / sub / name, dst / sub / name)
    shutil.copy(sim / "config.yaml", dst / "config.yaml")
    return dst


def test_a_failure_file_never_replaces_a_users_file(sim, earlier, tmp_path, capsys):
    one = _one_frame(sim, tmp_path / "one")
    fresh = tmp_path / "fresh"
    assert main(["calibrate", str(one), "--out", str(fresh)]) == 3
    assert "details: " + str(fresh / "failure.yaml") in capsys.readouterr().err
    assert (fresh / MARKER).is_file()  # a failed run's folder is ours too: the next run may replace it
    run = tmp_path / "run"
    shutil.copytree(earlier, run)
    before = snapshot(run)
    assert main(["calibrate", str(one), "--out", str(run)]) == 3  # beside the earlier result, kept
    beside = tmp_path / "run.failure.yaml"
    assert f"details: {beside}" in capsys.readouterr().err and "1 distinct board pose" in beside.read_text()
    assert main(["calibrate", str(one), "--out", str(run)]) == 3  # our own file: replaced
    assert f"details: {beside}" in capsys.readouterr().err
    beside.write_text("my notes on the failed run\n")  # now the user's
    assert main(["calibrate", str(one), "--out", str(run)]) == 3
    err = capsys.readouterr().err
    assert beside.read_text() == "my notes on the failed run\n" and "details: " in err
    assert str(beside) not in err and snapshot(run) == before


def test_an_error_log_never_replaces_a_users_file(sim, tmp_path, capsys, monkeypatch):
    import ilcc_graph.run.pipeline

    def broken(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        raise ZeroDivisionError("boom")

    monkeypatch.setattr(ilcc_graph.run.pipeline, "run", broken)
    log = tmp_path / "run.error.log"
    log.write_text("my own log\n")
    assert main(["calibrate", str(sim), "--out", str(tmp_path / "run")]) == 1
    err = capsys.readouterr().err
    assert log.read_text() == "my own log\n" and str(log) not in err and "the traceback is in" in err
    other = Path(err.split("the traceback is in ")[1].strip())
    assert "boom" in other.read_text()
    other.unlink()


def test_export_replaces_the_file_named_as_cp_does(earlier, tmp_path, capsys):
    cal = earlier / "calibration.yaml"
    dst = tmp_path / "extrinsic.json"
    dst.write_text("old")
    os.chmod(dst, 0o640)
    assert main(["export", str(cal), "--format", "json", "--out", str(dst)]) == 0
    assert dst.read_text() != "old" and stat.S_IMODE(dst.stat().st_mode) == 0o640
    link = tmp_path / "current.json"
    link.symlink_to(dst)
    assert main(["export", str(cal), "--format", "kitti", "--out", str(link)]) == 0
    assert link.is_symlink() and "R:" in dst.read_text()  # written through the link
    _refused(["export", str(cal), "--format", "json", "--out", str(tmp_path)], capsys, "is a folder")
    _refused(["export", str(cal), "--format", "json", "--out", str(dst / "x.json")], capsys, "is a file, so")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["current.json", "extrinsic.json"]


_UMASK_RUN = """
set -e
umask {mask:03o}
cd {work}
{cli} simulate sim --frames 4 --seed 1 --width 1200 > /dev/null
{cli} calibrate sim --jobs 1 > /dev/null
{cli} export out/latest/calibration.yaml --format ros-tf --out out/tf.launch > /dev/null
{cli} evaluate sim out/latest/calibration.yaml --out out/latest > /dev/null
"""


def test_outputs_follow_the_umask(tmp_path):
    """Every file and folder the commands write has the mode the umask gives: 0640 / 0750 for 027.

    One umask tells both mistakes apart from the right modes: a file staged by ``mkstemp`` and moved
    in unchanged (0600) and a mode written by hand (0644, 0755); the common 022 would miss the second.
    """
    mask = 0o027
    cli = f"{sys.executable} -m ilcc_graph.app"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    script = _UMASK_RUN.format(mask=mask, work=tmp_path, cli=cli)
    done = subprocess.run(["bash", "-c", script], env=env, timeout=600, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    written = [p for p in tmp_path.rglob("*") if not p.is_symlink()]
    assert (tmp_path / "out" / "latest" / "report" / "index.html").is_file()
    assert any(p.suffix == ".png" for p in written) and len(written) > 30
    wrong = {
        str(p.relative_to(tmp_path)): oct(stat.S_IMODE(p.stat().st_mode))
        for p in written
        if stat.S_IMODE(p.stat().st_mode) != (0o777 if p.is_dir() else 0o666) & ~mask
    }
    assert wrong == {}


def test_simulate_bag_writes_new_files_only_and_all_at_once(tmp_path, capsys, monkeypatch):
    """``simulate --bag``: the bag and the two YAML files beside it appear together (staged beside,
    moved in at the end); a name in use, the bag's or a file's beside it, is refused before any work
    (exit 2) and left as it was; a stop while writing leaves nothing."""
    from ilcc_graph import signals
    from ilcc_graph.datasets import open_source
    from ilcc_graph.simulate import standard_spec, write_bag

    small = ["--bag", "--frames", "2", "--width", "400", "--camera", "pinhole"]
    bags = tmp_path / "bags"
    assert main(["simulate", str(bags / "run.bag"), *small]) == 0
    assert main(["simulate", str(bags / "run2"), *small, "--storage", "sqlite3"]) == 0  # a ROS 2 folder
    assert sorted(p.name for p in bags.iterdir()) == [
        "run.bag", "run.ground_truth.yaml", "run.yaml", "run2", "run2.ground_truth.yaml", "run2.yaml"
    ]  # fmt: skip
    assert (bags / "run2" / "run2.db3").is_file()
    assert [len(open_source(bags / n).frames()) for n in ("run.bag", "run2")] == [2, 2]

    import ilcc_graph.simulate.bag

    def started(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        raise AssertionError("simulated before the names were checked")

    with monkeypatch.context() as m:
        m.setattr(ilcc_graph.simulate.bag, "simulate_frames", started)
        before = snapshot(bags)
        _refused(["simulate", str(bags / "run.bag"), *small], capsys, f"simulate {bags / 'run.bag'}: exists")
        assert snapshot(bags) == before
        (bags / "mine.yaml").write_text("mine: true\n")  # the user's file where the bag's config would go
        before = snapshot(bags)
        err = _refused(["simulate", str(bags / "mine.bag"), *small], capsys, "mine.yaml exists beside it")
        assert "never writes over a file it did not write" in err
        assert snapshot(bags) == before

    def stop_after_one(done: int, total: int) -> None:
        raise signals.Stopped(15)

    spec = standard_spec(camera="pinhole", width=400, frames=2, seed=0)
    with pytest.raises(signals.Stopped):
        write_bag(bags / "stopped.bag", spec, progress=stop_after_one)
    assert snapshot(bags) == before  # no bag, no YAML, no staging folder
