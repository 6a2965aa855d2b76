"""ruff on the whole repository, with the rules of pyproject.toml (``[tool.ruff]``), as a developer
runs it from the repository root: CI runs the tests, so this puts the linter on the main path."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_finds_nothing() -> None:
    pytest.importorskip("ruff", reason="ruff is not installed (it is in the test extras: scripts/setup.sh)")
    run = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--no-cache", "."], cwd=ROOT, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    out = (run.stdout + run.stderr).strip()
    assert run.returncode == 0, f"ruff found problems (exit {run.returncode}):\n{out}"
