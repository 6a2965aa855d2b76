"""The rig (``rig``): every sensor of a rig in one graph, with the joint covariance (issue 24).

Its own observation pass (``observe``: the stages on every sensor's data at every moment,
``rig_observe.observe_rig``, kept as ``Observation.data``) and its solve (``rig_calibrate.solve_observed``:
the start, the joint graph). The ``Result`` holds every sensor's pose in the reference frame
(``Result.poses``), the rig's calibration typed (``Result.rig``: ``io.rig_results.RigCalibration``,
which the writer serialises as its ``calibration.yaml``), and as its
headline ``Calibration`` the pair of the rig's first camera and first LiDAR (``T_cam_lidar`` with
its covariance from the joint one; its frames are the moments), so that a rig of one camera and one
LiDAR reads like a single pair's run.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence

import numpy as np

from ilcc_graph.datasets.rig_source import RigSource
from ilcc_graph.errors import CalibrationImpossible
from ilcc_graph.estimation.gate import far_above
from ilcc_graph.estimation.rig_solve import RigOptions
from ilcc_graph.evaluation.causes import causes_without_extrinsic
from ilcc_graph.run import rig_calibrate
from ilcc_graph.run.finish import require_supported
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.result import Result, RunOptions, SessionResult
from ilcc_graph.run.rig_calibrate import RigResult, RigRunOptions, solve_observed, to_calibration
from ilcc_graph.run.rig_observe import RigObservation, observe_rig
from ilcc_graph.run.stages import StageOptions
from ilcc_graph.run.strategies import Reporter, Strategy, one, register
from ilcc_graph.types import Calibration, FrameResult

__all__ = [
    "headline", "observe", "pair_frames", "require_cameras", "solve", "with_unsolved_causes",
]  # fmt: skip

log = logging.getLogger(__name__)


def observe(
    source: RigSource,
    options: StageOptions = StageOptions(),
    progress: Callable[[int, int], None] | None = None,
) -> Observation:
    """Every moment of a rig source through the stages (``Observation.data``: the ``RigObservation``;
    ``config``: the rig's ``RigConfig``; no single-pair frames)."""
    seen = observe_rig(source, options, progress)
    return Observation(source, seen.rig, [], data=seen)


def headline(res: RigResult) -> Calibration:
    """The pair of the rig's first solved camera and first solved LiDAR as a single pair's
    ``Calibration`` (``T_cam_lidar``, its covariance from the joint one; one frame per moment, used
    when both sensors' observations entered the graph). A rig without both kinds: the reference and
    the next solved sensor (``T_cam_lidar`` then holds ``T_ref_sensor``). ``camera``: the camera's
    config section when the first sensor is a camera; ``sensors``: the base LiDAR's errors and the
    camera's refined intrinsics, when estimated."""
    rig = res.rig
    cams = [s for s in rig.cameras if s in res.sensors]
    lidars = [s for s in rig.lidars if s in res.sensors]
    if cams and lidars:
        a, b = cams[0], lidars[0]
    else:
        a, b = res.reference, next(s for s in res.sensors if s != res.reference)
    e = res.relative(a, b)
    frames = pair_frames(res, a, b)
    cam = rig.sensor(a).camera
    diagnostics = {"variance_factor": float(res.variance_factor)}
    errors = rig_calibrate.lidar_errors(res)  # the base LiDAR's: the boards on corrected ranges read them
    sensors = {"lidar_errors": errors} if errors else {}
    if refined := res.solution.intrinsics(a):
        sensors["camera_intrinsics"] = refined.entry()
    return Calibration(
        np.asarray(e.T), np.asarray(e.covariance), tuple(frames), f"rig {a}/{b}", diagnostics,
        None if cam is None else cam.to_dict(), sensors,
    )  # fmt: skip


def pair_frames(res: RigResult, a: str, b: str, camera_only: bool = False) -> list[FrameResult]:
    """One ``FrameResult`` per moment of sensors ``a`` (a camera: its corners) and ``b`` (a LiDAR: its
    board), used when both observations entered the graph, the reason of each that did not
    otherwise (``camera_only``: used when ``a``'s did, its reason as it is)."""
    fates = {(f.moment, f.sensor): f for f in res.fates}
    observed = {m.name: m for m in res.observation.moments} if res.observation is not None else {}
    frames = []
    for moment in dict.fromkeys(f.moment for f in res.fates):
        fa, fb = fates[(moment, a)], fates[(moment, b)]
        if camera_only:
            why = None if fa.used else fa.reason
        else:
            why = "; ".join(f"{f.sensor}: {f.reason}" for f in (fa, fb) if not f.used) or None
        m = observed.get(moment)
        board = m.boards.get(b) if m is not None else None
        corners = m.corners.get(a) if m is not None else None
        frames.append(FrameResult(moment, why is None, why, board, corners))
    return frames


def require_cameras(res: RigResult) -> None:
    """Raise ``CalibrationImpossible`` where a pair's run would for a solved camera (each with the base
    LiDAR, whose boards and the camera's pose give the advice's residuals; a rig without a LiDAR is
    not judged so; ``_camera_rules``). In a rig of more than two sensors the message also says that
    leaving the camera out calibrates the others."""
    lidar = _base_lidar(res)
    if lidar is None:
        return
    for camera in (s for s in res.rig.cameras if s in res.sensors):
        try:
            _camera_rules(res, camera, lidar)
        except CalibrationImpossible as err:
            if len(res.rig.sensors) <= 2:
                raise
            others = f"leave camera '{camera}' out of rig.yaml to calibrate the other sensors"
            raise CalibrationImpossible(f"{err}; or {others}", err.frames, err.advice) from None


def _base_lidar(res: RigResult) -> str | None:
    """The rig's first LiDAR with a pose (a camera's rules and causes are judged with it), or None."""
    return next((s for s in res.rig.lidars if s in res.sensors), None)


def _camera_rules(res: RigResult, camera: str, lidar: str) -> None:
    """The pair's refusals for ``camera`` with ``lidar`` (``run.finish.require_supported``): its
    moments as frames, the joint solve's ``failing`` among them, the far components of the LiDAR's
    boards and the camera's views."""
    frames = pair_frames(res, camera, lidar, camera_only=True)
    joint = res.solution.solution
    used = {f.name for f in frames if f.used}
    failing = [] if joint is None else [(n, why) for n, why in joint.failing if n in used]
    far = {} if joint is None else far_above((joint.components(lidar)[0], joint.components(camera)[1]))
    T = np.asarray(res.relative(camera, lidar).T)
    refined = res.solution.intrinsics(camera) is not None
    require_supported(frames, failing, far, res.rig.pair_config(camera, lidar), T, camera, refined)


def with_unsolved_causes(res: RigResult) -> RigResult:
    """``res`` with the reason of each camera left without a pose extended by the likely cause its
    moments seen with the base LiDAR show without an extrinsic (``evaluation.causes
    .causes_without_extrinsic``: the intrinsics or lens model, the board's size, boards cut off),
    as a pair's exit 3 names it when its corner order fits no frame."""
    lidar = _base_lidar(res)
    if lidar is None:
        return res
    unsolved = dict(res.unsolved)
    for camera in (s for s in res.rig.cameras if s in unsolved):
        config = res.rig.pair_config(camera, lidar)
        frames = pair_frames(res, camera, lidar, camera_only=True)
        if causes := causes_without_extrinsic(frames, config.board, config.camera, False, camera):
            unsolved[camera] = f"{unsolved[camera]}; likely: {causes[0]}"
    if unsolved == res.unsolved:
        return res
    return dataclasses.replace(res, solution=dataclasses.replace(res.solution, unsolved=unsolved))


def solve(observations: Sequence[Observation], options: RunOptions, report: Reporter | None = None) -> Result:
    """The rig's joint answer from its observation (``observe``), solved under a pair's options (the
    sensor model, the LiDAR's errors, the camera's intrinsics, the noise policy). Raises
    CalibrationImpossible, IndeterminateSystem."""
    obs = one(observations, "rig")
    if not isinstance(obs.data, RigObservation):
        raise ValueError("rig mode: the observation holds no rig (observe it with this strategy's observe)")
    o = options
    how = RigOptions(o.noise, o.models, lidar_errors=o.lidar_errors, intrinsics=o.intrinsics,
                     intrinsics_choice=o.intrinsics_choice)  # fmt: skip
    res = with_unsolved_causes(solve_observed(obs.data, RigRunOptions(o.stages, solve=how)))
    require_cameras(res)
    cal = headline(res)
    poses = {s: res.pose(s) for s in res.sensors}
    session = SessionResult(obs.name, obs, cal)
    return Result("rig", cal, (session,), options, cal.covariance, poses=poses, rig=to_calibration(res))


register(Strategy("rig", solve, second_pass=True, observe=observe))
