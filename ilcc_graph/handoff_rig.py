"""Hand a calibrated rig to a user's GTSAM problem: every sensor's pose as one prior with the joint
covariance (docs/rig.md, "A rig in your GTSAM graph").

The user's variables hold ``T_ref_sensor`` (``gtsam.Pose3``; ``p_ref = T p_sensor``) of the sensors
other than the reference (the frame they are given in, e.g. a vehicle's body frame placed at the
reference sensor). ``rig_prior`` is ONE factor on all of them, so the correlations between the
sensors' poses stay in: error ``(Logmap(T_s_est^-1 T_s))_s`` (each 6: rotation first, rad and m,
the calibration's right tangent), noise ``Gaussian.Covariance`` of the joint covariance (the
sub-block of the sensors asked for, which is their marginal). For one sensor it is GTSAM's
``PriorFactorPose3`` with that sensor's covariance.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import gtsam
import numpy as np

from ilcc_graph.errors import InputError
from ilcc_graph.io.rig_results import RigCalibration
from ilcc_graph.io.stored import read_stored

__all__ = ["add_rig_prior", "rig_prior"]


def rig_prior(
    keys: Mapping[str, int], calibration: RigCalibration | str | Path, inflate: float = 1.0
) -> gtsam.CustomFactor:
    """One factor on the variables ``keys`` {sensor: key} holding ``T_ref_sensor`` (module docstring).

    calibration: a rig's calibration (or its calibration.yaml). inflate: factor on the sigmas (e.g.
    for mounts that may have moved since). ValueError for the reference sensor (its pose is the
    frame), an unknown sensor or a bad ``inflate``."""
    cal = calibration if isinstance(calibration, RigCalibration) else _read(calibration)
    if not np.isfinite(inflate) or inflate <= 0.0:
        raise ValueError(f"inflate must be a positive number, got {inflate!r}")
    bad = [s for s in keys if s not in cal.sensors or s == cal.reference]
    if bad or not keys:
        raise ValueError(
            f"rig_prior: keys must name sensors of {list(cal.sensors)} other than the reference "
            f"{cal.reference!r} (its pose is the frame), got {list(keys) or 'none'}"
        )
    names = list(keys)
    idx = np.concatenate([np.arange(6 * cal.sensors.index(s), 6 * cal.sensors.index(s) + 6) for s in names])
    C = np.asarray(cal.covariance, dtype=np.float64)[np.ix_(idx, idx)] * float(inflate) ** 2
    means = [gtsam.Pose3(np.asarray(cal.T_ref_sensor[s], dtype=np.float64)) for s in names]
    key_list = [int(keys[s]) for s in names]

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list[np.ndarray] | None) -> np.ndarray:
        out = np.zeros(6 * len(names))
        for k, (key, mean) in enumerate(zip(key_list, means, strict=True)):
            H1, H2, HL = (np.zeros((6, 6), order="F") for _ in range(3))
            d = mean.between(values.atPose3(key), H1, H2)
            out[6 * k : 6 * k + 6] = gtsam.Pose3.Logmap(d, HL)
            if H is not None:
                J = np.zeros((6 * len(names), 6), order="F")
                J[6 * k : 6 * k + 6] = HL @ H2
                H[k] = J
        return out

    noise = gtsam.noiseModel.Gaussian.Covariance(0.5 * (C + C.T), False)
    return gtsam.CustomFactor(noise, key_list, error)


def add_rig_prior(
    graph: gtsam.NonlinearFactorGraph,
    keys: Mapping[str, int],
    calibration: RigCalibration | str | Path,
    initial: gtsam.Values | None = None,
    inflate: float = 1.0,
) -> gtsam.CustomFactor:
    """``rig_prior`` added to ``graph``; with ``initial``, each sensor's stored pose inserted where
    the key has no value yet. Returns the factor."""
    cal = calibration if isinstance(calibration, RigCalibration) else _read(calibration)
    factor = rig_prior(keys, cal, inflate)
    graph.add(factor)
    if initial is not None:
        for s, key in keys.items():
            if not initial.exists(int(key)):
                initial.insert(int(key), gtsam.Pose3(np.asarray(cal.T_ref_sensor[s], dtype=np.float64)))
    return factor


def _read(path: str | Path) -> RigCalibration:
    """A rig's calibration.yaml through the one reader and validation (``io.stored.read_stored``)."""
    cal = read_stored(path)
    if not isinstance(cal, RigCalibration):
        raise InputError(
            f"{path}: a single pair's calibration; its extrinsic goes into a graph with "
            "handoff.extrinsic_prior"
        )
    return cal
