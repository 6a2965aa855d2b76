"""Two-sided honesty through the command line (test_cli_honesty.py's test and numbers) for the other
kinds of LiDAR under a pinhole camera: a ring-less one (the HDL-32E's scans written without their
ring field: the stage recovers the scanlines) and a solid-state one (Livox Mid-70: a rosette without
scanlines, the ring-less board search). A file of its own so that the two spread over the workers."""

from __future__ import annotations

import pytest
from accuracy import assert_two_sided, cli_nees

LIDARS = {
    "ringless-hdl32": ("--no-ring-field",),  # measured NEES 5.44, 6.26, 2.05 (as with the ring field)
    "solid-state-mid70": ("--lidar", "livox-mid70"),  # measured 4.02, 3.90, 1.69
}


@pytest.mark.parametrize("lidar", list(LIDARS))
def test_the_covariance_is_neither_too_small_nor_too_large_for_this_lidar(lidar, simulated, calibrated):
    assert_two_sided(cli_nees(simulated, calibrated, "pinhole", *LIDARS[lidar]), lidar)
