"""Issue 36: a closed stdout (``ilcc-graph calibrate DATA | true``, a pager quit early) ends the run
quietly with its outputs written: exit 0, no "internal error: BrokenPipeError", no error log. Real
processes with a real pipe whose reading end is closed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from ilcc_graph.app import main


@pytest.fixture(scope="module")
def pair(simulated) -> Path:  # noqa: ANN001 - conftest's factory
    """A small simulated pinhole pair (5 frames, 640 px), the session's ``simulated`` set."""
    return simulated("pinhole", frames=5, seed=3)


def _closed_stdout(argv: list[str], cwd: Path, both: bool = False) -> tuple[int, str]:
    """Run ``ilcc-graph argv`` with its stdout a pipe closed at once (as ``| true``; ``both``: stderr
    into it too, as ``2>&1 | true``); (exit status, stderr, "" with ``both``)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    p = subprocess.Popen(
        [sys.executable, "-m", "ilcc_graph.app", *argv],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT if both else subprocess.PIPE,
        text=True,
    )
    assert p.stdout is not None
    p.stdout.close()
    try:
        err = "" if p.stderr is None else p.stderr.read()
        return p.wait(timeout=300), err
    finally:
        if p.poll() is None:  # still running: the test fails, and leaves no process behind
            p.kill()
            p.wait()


@pytest.mark.parametrize("both", [False, True])
def test_calibrate_into_a_closed_pipe_writes_its_outputs_and_exits_0(
    pair: Path, tmp_path: Path, both: bool
) -> None:
    """``| true`` and ``2>&1 | true`` (the progress bar and the log meet the closed pipe too)."""
    out = tmp_path / "out"
    argv = ["calibrate", str(pair), "--out", str(out), "--jobs", "1", "--no-report"]
    code, err = _closed_stdout(argv, tmp_path, both)
    assert code == 0, err
    assert "internal error" not in err and "BrokenPipe" not in err and "Exception ignored" not in err, err
    assert (out / "calibration.yaml").is_file() and not (tmp_path / "out.error.log").exists()


def test_export_into_a_closed_pipe_exits_0(pair: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    assert main(["calibrate", str(pair), "--out", str(out), "--jobs", "1", "--no-report"]) == 0
    code, err = _closed_stdout(["export", str(out / "calibration.yaml"), "--format", "json"], tmp_path)
    assert code == 0 and err == "", err


@pytest.mark.parametrize("watch", [False, True])
def test_check_into_a_closed_pipe(pair: Path, tmp_path: Path, watch: bool) -> None:
    """``check DATA | true`` goes on to its end and writes check.yaml (exit 0); ``check --watch`` would
    follow the folder until Ctrl-C printing into nothing, so it ends quietly with 141 and no output
    (before: exit 1 "internal error: BrokenPipeError" for both)."""
    out = tmp_path / "out"
    code, err = _closed_stdout(
        ["check", str(pair), "--out", str(out), *(["--watch"] if watch else [])], tmp_path
    )
    assert "internal error" not in err and "Traceback" not in err, err
    assert not (tmp_path / "out.error.log").exists()
    if watch:
        assert code == 141 and not out.exists(), err
    else:
        assert code == 0 and (out / "check.yaml").is_file(), err
