"""A single pair's data written as a rig of two (rig.yaml and a folder per sensor), shared by the
tests that compare a pair's door with its rig's."""

from __future__ import annotations

from pathlib import Path

import yaml


def rig_of_two(where: Path, config: dict, scans: Path, images: Path, camera: str = "camera") -> Path:
    """``where`` made a rig folder: rig.yaml with ``config``'s board, the LiDAR ``lidar`` (the
    reference; its folder a link to ``scans``) and the camera ``camera`` (a link to ``images``)."""
    where.mkdir()
    (where / "lidar").symlink_to(scans.resolve())
    (where / camera).symlink_to(images.resolve())
    sensors = {"lidar": {"lidar": config["lidar"]}, camera: {"camera": config["camera"]}}
    spec = {"reference": "lidar", "board": config["board"], "sensors": sensors}
    (where / "rig.yaml").write_text(yaml.safe_dump(spec))
    return where
