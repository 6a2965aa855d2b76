"""Shared test fixtures: only what several test modules need."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "acfr-vlp16-fisheye"


@pytest.fixture(scope="session")
def acfr_data() -> Path:
    """The recorded VLP-16 + fisheye set that ships in ../shared; skip where it is absent."""
    if not (SHARED_DATA / "config.yaml").is_file():
        pytest.skip(f"recorded data set not found at {SHARED_DATA} (only in the project's own workspace)")
    return SHARED_DATA


def _shared_set(name: str) -> Path:
    path = SHARED_DATA.parent / name
    if not (path / "config.yaml").is_file():
        pytest.skip(f"recorded data set not found at {path} (only in the project's own workspace)")
    return path


@pytest.fixture(scope="session")
def acfr_os1_fisheye() -> Path:
    """The recorded Ouster OS1-64 + fisheye set (11 frames) in ../shared; skip where it is absent."""
    return _shared_set("acfr-os1-fisheye")


@pytest.fixture(scope="session")
def acfr_os1_pinhole() -> Path:
    """The recorded Ouster + pinhole set (6 frames) in ../shared; skip where it is absent."""
    return _shared_set("acfr-os1-pinhole")


@pytest.fixture
def readonly_dir(tmp_path) -> Path:
    """A folder nobody can write into: a read-only tmpfs as root (permission bits do not stop root)."""
    d = tmp_path / "ro"
    d.mkdir()
    if os.geteuid() != 0:
        d.chmod(0o555)
        yield d
        d.chmod(0o755)
        return
    if subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(d)], capture_output=True
    ).returncode:
        pytest.skip("cannot mount a read-only tmpfs here")
    yield d
    subprocess.run(["umount", str(d)], check=False)
