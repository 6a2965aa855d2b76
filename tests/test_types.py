"""The type checker on the whole package: ``mypy`` with the configuration and the one list of checked
paths in pyproject.toml (``[tool.mypy]``), exactly as a developer runs it from the repository root."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_mypy_is_clean_on_the_checked_paths() -> None:
    pytest.importorskip("mypy", reason="mypy is not installed (it is in the test extras: scripts/setup.sh)")
    # the cache (.mypy_cache, untracked) makes a re-run take a second; a cold run takes ~10 s
    run = subprocess.run(
        [sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    out = (run.stdout + run.stderr).strip()
    assert run.returncode == 0, f"mypy found problems (exit {run.returncode}):\n{out}"
    assert "Success: no issues found" in out, out


def test_the_checked_paths_are_the_whole_package() -> None:
    tomllib = pytest.importorskip("tomllib", reason="reading pyproject.toml needs Python 3.11's tomllib")
    with open(ROOT / "pyproject.toml", "rb") as f:
        files = tomllib.load(f)["tool"]["mypy"]["files"]
    assert set(files) == {"factors", "ilcc_graph"}, files
    missing = [p for p in files if not (ROOT / p).exists()]
    assert not missing, f"[tool.mypy] files names paths that do not exist: {missing}"
