"""A simulated rig's truth, ``rig_ground_truth.yaml``: every sensor's pose and every board's.

Keys: ``reference`` (the sensor name); ``T_ref_sensor`` {sensor: 4x4} with
``p_ref = T_ref_sensor @ p_sensor``; ``T_ref_board`` {moment: 4x4} with ``p_ref = T_ref_board @ p_board``;
``seen_by`` {moment: [sensors]} the sensors that see the whole board (printed face towards them);
then any further keys (``moved``, ``cameras``, ``simulation``, ...) kept in ``extra``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, quote
from .files import read_yaml, write_yaml
from .results import _matrix

__all__ = ["RIG_GROUND_TRUTH_FILE", "RigGroundTruth", "read_rig_ground_truth", "write_rig_ground_truth"]

RIG_GROUND_TRUTH_FILE = "rig_ground_truth.yaml"
_KEYS = ("reference", "T_ref_sensor", "T_ref_board", "seen_by")


@dataclass(frozen=True)
class RigGroundTruth:
    """reference: the reference sensor's name; T_ref_sensor {sensor: (4, 4)}; T_ref_board
    {moment: (4, 4)}; seen_by {moment: sensors that see the whole board}; extra: the other keys."""

    reference: str
    T_ref_sensor: dict[str, np.ndarray]
    T_ref_board: dict[str, np.ndarray]
    seen_by: dict[str, tuple[str, ...]] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def T_a_b(self, a: str, b: str) -> np.ndarray:
        """(4, 4) sensor b's pose in sensor a's frame: ``p_a = T_a_b @ p_b``."""
        return np.linalg.solve(self.T_ref_sensor[a], self.T_ref_sensor[b])

    def T_sensor_board(self, sensor: str, moment: str) -> np.ndarray:
        """(4, 4) the board of ``moment`` in ``sensor``'s frame: ``p_sensor = T @ p_board``."""
        return np.linalg.solve(self.T_ref_sensor[sensor], self.T_ref_board[moment])


def write_rig_ground_truth(path: str | Path, truth: RigGroundTruth) -> Path:
    """Write ``truth`` (path: the file, or a folder for ``<folder>/rig_ground_truth.yaml``), atomically."""
    p = Path(path)
    if p.suffix.lower() not in (".yaml", ".yml"):
        p = p / RIG_GROUND_TRUTH_FILE
    if clash := set(_KEYS) & truth.extra.keys():
        raise ValueError(f"extra must not repeat {sorted(clash)}")
    return write_yaml(
        p,
        {
            "reference": truth.reference,
            "T_ref_sensor": {k: np.asarray(v, dtype=np.float64) for k, v in truth.T_ref_sensor.items()},
            "T_ref_board": {k: np.asarray(v, dtype=np.float64) for k, v in truth.T_ref_board.items()},
            "seen_by": {k: list(v) for k, v in truth.seen_by.items()},
            **truth.extra,
        },
    )


def read_rig_ground_truth(path: str | Path) -> RigGroundTruth:
    """Read ``rig_ground_truth.yaml`` (the file, or the folder holding it); InputError when malformed."""
    p = Path(path)
    if p.is_dir():
        p = p / RIG_GROUND_TRUTH_FILE
    src, d = str(p), read_yaml(p, "rig ground truth")
    if not isinstance(d, dict) or not {"reference", "T_ref_sensor", "T_ref_board"} <= d.keys():
        raise InputError(f"{src}: expected a mapping with reference, T_ref_sensor and T_ref_board")
    poses = {}
    for key in ("T_ref_sensor", "T_ref_board"):
        if not isinstance(d[key], dict):
            raise InputError(f"{src}: {key} must map names to 4x4 matrices")
        poses[key] = {str(k): _matrix(src, v, f"{key}.{k}", (4, 4), pose=True) for k, v in d[key].items()}
    if str(d["reference"]) not in poses["T_ref_sensor"]:
        raise InputError(
            f"{src}: reference = {quote(d['reference'])}: expected one of T_ref_sensor's sensors"
        )
    seen = d.get("seen_by") or {}
    if not isinstance(seen, dict) or not all(isinstance(v, list) for v in seen.values()):
        raise InputError(f"{src}: seen_by must map moments to lists of sensor names")
    return RigGroundTruth(
        str(d["reference"]),
        poses["T_ref_sensor"],
        poses["T_ref_board"],
        {str(k): tuple(str(s) for s in v) for k, v in seen.items()},
        {k: v for k, v in d.items() if k not in _KEYS},
    )
