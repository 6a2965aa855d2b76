"""What ``calibrate`` prints for a rig (docs/rig.md): every sensor's pose in the reference sensor's
frame with its 1-sigma (from the joint covariance), the sensors without a pose and why, and how many
of each sensor's moments entered the graph. Plain strings for an 80-column terminal; no printing."""

from __future__ import annotations

import textwrap
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from ilcc_graph.lidar.margin import margin_words
from ilcc_graph.report.sensors import sensors_lines
from ilcc_graph.report.summary import lidar_in_camera

if TYPE_CHECKING:
    from ilcc_graph.io.rig_results import RigCalibration

__all__ = ["rig_lines"]

WIDTH = 80


def rig_lines(cal: RigCalibration) -> list[str]:
    """The closing lines of a rig's calibration as written (``calibration.yaml``): poses T_ref_sensor
    (position in mm in the reference's axes with its 1-sigma; rotation as roll/pitch/yaw about the
    reference's x, y, z in degrees, its 1-sigma about the reference's axes), unsolved sensors,
    moments used, a margin a LiDAR's boards contradict."""
    ref = cal.reference
    lines = [f"every sensor in the frame of {ref} (the reference), +- 1 sigma:"]
    for s in cal.sensors:
        if s == ref:
            continue
        T = cal.T_ref_sensor[s]
        # T_ref_sensor has T_cam_lidar's form (the child's pose in its parent's frame): the same
        # position, rotation and sigmas in the parent's axes as the pair's summary
        p_mm, p_sigma, _, _, r_sigma = lidar_in_camera(T, cal.block(s))
        rpy = Rotation.from_matrix(np.asarray(T)[:3, :3]).as_euler("xyz", degrees=True)
        lines.append(f"  {s}")
        pos = [f"{a} {v:+8.1f} +- {d:.1f}" for a, v, d in zip("xyz", p_mm, p_sigma, strict=True)]
        lines.append("    position mm  " + "  ".join(pos))
        lines.append("    roll pitch yaw deg  " + "  ".join(f"{v:+8.3f}" for v in rpy))
        lines.append("    sigma deg about the reference's x y z  " + "  ".join(f"{d:.3f}" for d in r_sigma))
    for s, why in (cal.extra.get("unsolved") or {}).items():
        lines += textwrap.wrap(f"no pose for {s}: {why}", WIDTH, subsequent_indent="  ")
    counts = cal.extra.get("used") or {}
    used = ", ".join(f"{s} {counts.get(s, 0)}" for s in cal.sensors)
    lines += textwrap.wrap(f"moments in the graph per sensor: {used}", WIDTH, subsequent_indent="  ")
    for lidar, summary in (cal.extra.get("lidar_margin") or {}).items():  # as a pair's summary says it
        lines += textwrap.wrap(f"{lidar}: {margin_words(summary, 'rig.yaml')}", WIDTH, subsequent_indent="  ")
    return lines + _base_lidar(cal)


def _base_lidar(cal: RigCalibration) -> list[str]:
    """The base LiDAR's sensor model and the errors it estimated, as a pair's summary says them."""
    sensors = {"model": cal.extra.get("sensor_model"), "lidar_errors": cal.extra.get("lidar_errors")}
    said = sensors_lines({k: v for k, v in sensors.items() if v}, {})
    if not said:
        return []
    base = (cal.extra.get("lidar_errors") or {}).get("lidar")
    lines = [f"the base LiDAR{f' ({base})' if base else ''}, the rig's first (its errors in the graph):"]
    for line in said:
        lines += textwrap.wrap(line, WIDTH, initial_indent="  ", subsequent_indent="    ")
    return lines
