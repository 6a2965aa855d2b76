"""Shared test fixtures: only what several test modules need."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA_ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SHARED_DATA = DATA_ROOT / "acfr-vlp16-fisheye"


def _recorded(name: str) -> Path:
    path = DATA_ROOT / name
    if not (path / "config.yaml").is_file():
        pytest.skip(f"recorded data set not found at {path} (only in the project's own workspace)")
    return path


@pytest.fixture(scope="session")
def acfr_data() -> Path:
    """The recorded VLP-16 + fisheye set that ships in ../shared; skip where it is absent."""
    return _recorded("acfr-vlp16-fisheye")


@pytest.fixture(scope="session")
def acfr_os1_fisheye() -> Path:
    """The recorded Ouster OS1-64 + fisheye set (11 frames) in ../shared; skip where it is absent."""
    return _recorded("acfr-os1-fisheye")


@pytest.fixture(scope="session")
def acfr_os1_pinhole() -> Path:
    """The recorded Ouster OS1-64 + pinhole set (6 dark frames) in ../shared; skip where it is absent."""
    return _recorded("acfr-os1-pinhole")
