"""All file reading and writing: scans, images, YAML, data-set layout, results.

Readers raise ``InputError`` naming the file and the problem; writers are atomic.
"""

from __future__ import annotations

from .files import atomic_write, dump_yaml, read_yaml, to_plain, write_yaml
from .frame_pairs import FramePaths, data_folders, list_frames, natural_key
from .images import IMAGE_SUFFIXES, read_image, write_image
from .lzf import lzf_compress, lzf_decompress
from .pcd import PCD_STYLES, read_pcd, write_pcd
from .ply import read_ply, write_ply
from .results import (
    GroundTruth,
    calibration_to_dict,
    read_calibration,
    read_calibration_with_camera,
    read_ground_truth,
    write_calibration,
    write_ground_truth,
)
from .scans import FIELD_ALIASES, read_scan, reader, supported_scan_suffixes

__all__ = [
    "FIELD_ALIASES",
    "IMAGE_SUFFIXES",
    "PCD_STYLES",
    "FramePaths",
    "GroundTruth",
    "atomic_write",
    "calibration_to_dict",
    "data_folders",
    "dump_yaml",
    "list_frames",
    "lzf_compress",
    "lzf_decompress",
    "natural_key",
    "read_calibration",
    "read_calibration_with_camera",
    "read_ground_truth",
    "read_image",
    "read_pcd",
    "read_ply",
    "read_scan",
    "read_yaml",
    "reader",
    "supported_scan_suffixes",
    "to_plain",
    "write_calibration",
    "write_ground_truth",
    "write_image",
    "write_pcd",
    "write_ply",
    "write_yaml",
]
