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
    """The closing lines of a rig's calibration: poses T_ref_sensor (position in mm in the
    reference's axes with its 1-sigma; rotation as roll/pitch/yaw about the reference's x, y, z in
    degrees, its 1-sigma about the sensor's own axes), unsolved sensors, moments used."""
    ref = res.reference
    lines = [f"every sensor in the frame of {ref} (the reference), +- 1 sigma:"]
    for s in res.sensors:
        if s == ref:
            continue
        e = res.pose(s)
        T, C = np.asarray(e.T), np.asarray(e.covariance)
        R = T[:3, :3]
        # position sigmas in the reference's axes (the tangent's translation is in the sensor's:
        # t_true = t + R dt); rotation sigmas about the sensor's own axes (the right tangent)
        sd_t = np.sqrt(np.clip(np.diag(R @ C[3:, 3:] @ R.T), 0.0, None))
        sd_r = np.degrees(np.sqrt(np.clip(np.diag(C[:3, :3]), 0.0, None)))
        rpy = Rotation.from_matrix(R).as_euler("xyz", degrees=True)
        lines.append(f"  {s}")
        pos = [f"{a} {v:+8.1f} +- {1e3 * d:.1f}" for a, v, d in zip("xyz", 1e3 * T[:3, 3], sd_t, strict=True)]
        lines.append("    position mm  " + "  ".join(pos))
        lines.append("    roll pitch yaw deg  " + "  ".join(f"{v:+8.3f}" for v in rpy))
        lines.append("    sigma deg about its own x y z  " + "  ".join(f"{d:.3f}" for d in sd_r))
    for s, why in res.unsolved.items():
        lines += textwrap.wrap(f"no pose for {s}: {why}", WIDTH, subsequent_indent="  ")
    used = ", ".join(f"{s} {len(res.used(s))}" for s in res.sensors)
    lines += textwrap.wrap(f"moments in the graph per sensor: {used}", WIDTH, subsequent_indent="  ")
    return lines
