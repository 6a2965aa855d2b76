"""What ``calibrate`` prints for a rig (docs/rig.md): every sensor's pose in the reference sensor's
frame with its 1-sigma (from the joint covariance), the sensors without a pose and why, and how many
of each sensor's moments entered the graph. Plain strings for an 80-column terminal; no printing."""

from __future__ import annotations

import textwrap
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

if TYPE_CHECKING:
    from ilcc_graph.run.rig_calibrate import RigResult

__all__ = ["rig_lines"]

WIDTH = 80


def rig_lines(res: RigResult) -> list[str]:
    """The closing lines of a rig's calibration: poses T_ref_sensor (position mm, rotation as
    roll/pitch/yaw about the reference's x, y, z in degrees) with 1-sigma, unsolved sensors, use."""
    ref = res.reference
    lines = [f"every sensor in the frame of {ref} (the reference), +- 1 sigma:"]
    for s in res.sensors:
        if s == ref:
            continue
        e = res.pose(s)
        t_mm = 1e3 * np.asarray(e.T)[:3, 3]
        rpy = Rotation.from_matrix(np.asarray(e.T)[:3, :3]).as_euler("xyz", degrees=True)
        sd = e.sigmas
        lines.append(f"  {s}")
        pos = [f"{a} {v:+8.1f} +- {1e3 * d:.1f}" for a, v, d in zip("xyz", t_mm, sd[3:], strict=True)]
        lines.append("    position mm  " + "  ".join(pos))
        rot = [f"{v:+8.3f} +- {np.degrees(d):.3f}" for v, d in zip(rpy, sd[:3], strict=True)]
        lines.append("    rpy deg      " + "  ".join(rot))
    for s, why in res.unsolved.items():
        lines += textwrap.wrap(f"no pose for {s}: {why}", WIDTH, subsequent_indent="  ")
    used = ", ".join(f"{s} {len(res.used(s))}" for s in res.sensors)
    lines += textwrap.wrap(f"moments in the graph per sensor: {used}", WIDTH, subsequent_indent="  ")
    return lines
