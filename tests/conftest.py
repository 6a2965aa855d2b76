"""Shared test fixtures: only what several test modules need."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "acfr-vlp16-fisheye"


@pytest.fixture(scope="session")
def acfr_data() -> Path:
    """The recorded VLP-16 + fisheye set that ships in ../shared; skip where it is absent."""
    if not (SHARED_DATA / "config.yaml").is_file():
        pytest.skip(f"recorded data set not found at {SHARED_DATA} (only in the project's own workspace)")
    return SHARED_DATA
