"""A rig's camera and LiDAR pairs seen as single pairs, for the solve's steps after its first answer
(issue 34: a pair is a rig of two).

Once a pair's run has an answer it fits the boards again on the ranges the LiDAR's estimated
errors correct (``range_refit.refit_pass``) and looks again for the boards the LiDAR stage missed
where the answer puts them (``second_look.second_pass``). A rig takes the same two steps, on a
pair's view of it: the view's frames are the rig's moments (the LiDAR's board, the camera's corners),
its source ``datasets.RigPair`` (the moment's files of the two sensors), its calibration the pair's
``T_cam_lidar`` from the joint answer with the LiDAR's fates. What a step changes goes back into the
rig's moments, and the rig is solved again (``pipeline.solve_observations``), as a pair is. The base
LiDAR (the rig's first, whose range errors the graph estimates) is refitted; every LiDAR gets the
second look, through each camera in the rig's order.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ilcc_graph.config import Config
from ilcc_graph.datasets import FrameRef, RigPair
from ilcc_graph.io.rig_results import RigCalibration
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.range_refit import refit_pass
from ilcc_graph.run.rig_calibrate import USED
from ilcc_graph.run.rig_observe import RigObservation
from ilcc_graph.run.second_look import second_pass
from ilcc_graph.run.stages import StageOptions
from ilcc_graph.types import Calibration, FrameResult, MomentResult

__all__ = ["look_rig", "pair_view", "put_back", "refit_rig"]


class _LidarMoments(RigPair):
    """A ``RigPair`` whose frames are every moment with the LiDAR's scan (the camera's image
    optional): the boards on corrected ranges are every board of the LiDAR."""

    def frames(self, require_scan: bool = True, require_image: bool = True) -> list[FrameRef]:
        return super().frames(require_scan, False)


def _seen(obs: Observation) -> RigObservation:
    if not isinstance(obs.data, RigObservation) or obs.rig_source is None:
        raise ValueError("a rig's view: the observation holds no rig and its source")
    return obs.data


def pair_view(
    obs: Observation,
    T_ref_sensor: Mapping[str, np.ndarray],
    camera: str,
    lidar: str,
    sensors: Mapping[str, Any] | None = None,
    fates: Mapping[str, Mapping[str, str]] | None = None,
    every_scan: bool = False,
) -> tuple[Observation, Calibration]:
    """The rig's ``camera`` and ``lidar`` as a single pair: the observation (one frame per moment:
    the LiDAR's board and the camera's corners, named as the moments; reasons as a pair's stages
    give them) and the calibration (``T_cam_lidar`` from the poses ``T_ref_sensor``; a frame used
    when ``fates[moment][lidar]`` says its observation entered the graph; ``sensors``: the LiDAR's
    estimated errors, as a pair's ``Calibration.sensors``). every_scan: the source gives every
    moment with the LiDAR's scan."""
    seen = _seen(obs)
    assert obs.rig_source is not None  # _seen checked it
    kind = _LidarMoments if every_scan else RigPair
    source = kind(obs.rig_source, camera, lidar)
    fates = fates or {}
    frames, fated = [], []
    for m in seen.moments:
        board, corners = m.boards.get(lidar), m.corners.get(camera)
        said = (("LiDAR", lidar), ("image", camera))  # as a pair's stages name their failures
        why = [f"{what}: {m.failures[s]}" for what, s in said if s in m.failures]
        frames.append(FrameResult(m.name, board is not None and corners is not None, "; ".join(why) or None,
                                  board, corners))  # fmt: skip
        fated.append(FrameResult(m.name, fates.get(m.name, {}).get(lidar) == USED))
    T = np.linalg.inv(T_ref_sensor[camera]) @ T_ref_sensor[lidar]
    config: Config = seen.rig.pair_config(camera, lidar)
    view = Observation(source, config, frames, f"{obs.name}:{camera}+{lidar}")
    return view, Calibration(T, np.full((6, 6), np.nan), tuple(fated), "rig", sensors=dict(sensors or {}))


def put_back(obs: Observation, lidar: str, before: Observation, after: Observation) -> Observation:
    """The rig's observation with ``lidar``'s boards that a step changed in its view (``after``
    against ``before``) at their moments (the stage's failure for it then gone)."""
    seen = _seen(obs)
    changed = {a.name: a.board for a, b in zip(after.frames, before.frames, strict=True) if a is not b}
    moments: list[MomentResult] = []
    for m in seen.moments:
        board = changed.get(m.name)
        if board is None:
            moments.append(m)
            continue
        failures = {s: r for s, r in m.failures.items() if s != lidar}
        moments.append(dataclasses.replace(m, boards={**m.boards, lidar: board}, failures=failures))
    return dataclasses.replace(obs, data=dataclasses.replace(seen, moments=moments))


def _solved(T_ref_sensor: Mapping[str, np.ndarray], names: Sequence[str]) -> list[str]:
    return [s for s in names if s in T_ref_sensor]


def refit_rig(
    obs: Observation, T_ref_sensor: Mapping[str, np.ndarray], sensors: Mapping[str, Any], stages: StageOptions
) -> Observation | None:
    """The rig's observation with its base LiDAR's boards fitted again on the ranges corrected by
    ``sensors['lidar_errors']`` (its errors as the graph estimated them), or None when the correction
    does not matter (``range_refit.refit_pass`` on the base LiDAR's view with the first camera
    ``T_ref_sensor`` places)."""
    rig = _seen(obs).rig
    cams = _solved(T_ref_sensor, rig.cameras)
    base = rig.lidars[0]
    if not cams or base not in T_ref_sensor:
        return None
    view, pair = pair_view(obs, T_ref_sensor, cams[0], base, sensors, every_scan=True)
    again = refit_pass(view, pair, stages)
    return None if again is None else put_back(obs, base, view, again)


def look_rig(
    obs: Observation, cal: RigCalibration, sensors: Mapping[str, Any], stages: StageOptions,
    refit: bool = True,
) -> Observation | None:  # fmt: skip
    """The rig's observation with the boards each LiDAR missed found where a camera and the answer
    put them (``second_look.second_pass`` on each solved LiDAR's view with each solved camera in
    turn; the base LiDAR's search on the ranges ``sensors`` corrects, as its refit), or None when
    none was found."""
    rig = _seen(obs).rig
    out, found = obs, False
    fates = cal.extra.get("moments", {})
    refined = cal.refined_intrinsics()  # each camera as solved, where the run refined its lens
    for lidar in _solved(cal.T_ref_sensor, rig.lidars):
        errors = sensors if lidar == rig.lidars[0] else {}
        for camera in _solved(cal.T_ref_sensor, rig.cameras):
            lens = {"camera_intrinsics": refined[camera]} if camera in refined else {}
            view, pair = pair_view(out, cal.T_ref_sensor, camera, lidar, {**errors, **lens}, fates)
            again = second_pass(view, pair, stages, refit=refit)
            if again is not None:
                out, found = put_back(out, lidar, view, again), True
    return out if found else None
