"""What a run takes and gives in every mode: ``RunOptions`` and ``Result`` (plain data).

Every strategy (``run.strategies``) returns a ``Result``; the one writer (``app.write.write_run``)
and the report read only it: the headline ``Calibration``, each source's part (``SessionResult``),
a strategy's extra content as named YAML documents (``documents``: ``joint.yaml`` of joint
sessions, ``incremental.yaml`` of iSAM2's states), further named poses (``poses``: each session's
extrinsic; a rig: each sensor's) and a rig's whole calibration (``rig``, typed; serialised only
when written).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ilcc_graph.estimation import NoiseOptions
from ilcc_graph.estimation.batch import BatchSolution
from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
from ilcc_graph.estimation.next_board import SolvedGlobals
from ilcc_graph.estimation.selection import AUTO, MODELS
from ilcc_graph.estimation.sessions import JointOptions
from ilcc_graph.io.rig_results import RigCalibration
from ilcc_graph.run.observe import Observation
from ilcc_graph.run.stages import StageOptions
from ilcc_graph.types import Calibration, Estimate, GraphFrame

__all__ = ["SENSOR_MODELS", "Result", "RunOptions", "SessionResult"]

#: ``RunOptions.sensor_model``: auto or one of ``estimation.selection.MODELS``
SENSOR_MODELS = ("auto", *MODELS)


@dataclass(frozen=True)
class RunOptions:
    """Everything a run uses (written to config.resolved.yaml).

    mode: a registered strategy (``run.strategies.modes()``): ``graph`` (batch, default), ``paper``
        (the paper's refinement, no covariance), ``incremental`` (iSAM2, frame by frame),
        ``sessions`` (joint; chosen for several sources or a range offset) or ``rig`` (a rig source:
        every sensor in one graph; only ``stages`` applies).
    noise: the estimation core's noise policy. stages: the per-frame stages' options and processes.
    joint: sessions mode (rigid / drift, range offset, tests).
    target_sigma: incremental mode's (deg, mm) target; stop_at_target: read no frame after it.
    second_pass: once an extrinsic is known, search the boards the LiDAR stage missed (or found
        elsewhere than the image says) near where the image and the extrinsic put them, and solve again.
    range_refit: when the LiDAR's estimated range errors stretch some board's pattern by more than
        three of its in-plane sigmas (``lidar.stretch.REFIT_RATIO``), fit every board again on its
        ranges corrected by them and solve again.
    lidar_errors: the LiDAR's own errors the graph estimates from the boards' returns (None: none,
        the default: on the recorded sets the boards' 6-dof LiDAR priors gave halves that agree,
        the returns with these terms did not; docs/bench_real.md).
    lidar_errors_without_print: when ``lidar_errors`` is None and most boards were placed by their
        outline (the LiDAR shows no print), estimate the LiDAR's errors all the same
        (``LidarErrorOptions()``): the boards' planes then carry the translation, and every beam's
        range offset, common to all frames, biases them alike (docs/lidar_stage.md).
    intrinsics: refine the camera's intrinsics, or propagate their stated ``camera.intrinsics_sigma``.
    sensor_model: ``auto`` (the default: the model of the sensors' own errors the boards support,
        ``estimation.selection``, and the camera's intrinsics refined when the boards support it,
        ``estimation.camera_choice``; ``beams`` when ``lidar_errors`` is given) or one LiDAR model
        forced (``selection.MODELS``: ``none``, ``range``, ``beams``, ``offset``) with the intrinsics
        as ``intrinsics`` says.
    """

    mode: str = "graph"
    noise: NoiseOptions = NoiseOptions()
    stages: StageOptions = StageOptions()
    joint: JointOptions = JointOptions()
    target_sigma: tuple[float, float] | None = None
    stop_at_target: bool = False
    second_pass: bool = True
    range_refit: bool = True
    lidar_errors: LidarErrorOptions | None = None
    lidar_errors_without_print: bool = True
    intrinsics: IntrinsicsOptions = IntrinsicsOptions()
    sensor_model: str = "auto"

    def __post_init__(self) -> None:
        from ilcc_graph.run.strategies import modes  # the registry (its strategies import this module)

        if self.mode not in modes():
            raise ValueError(f"RunOptions.mode must be one of {modes()}, got {self.mode!r}")
        if self.sensor_model not in SENSOR_MODELS:
            raise ValueError(
                f"RunOptions.sensor_model must be one of {SENSOR_MODELS}, got {self.sensor_model!r}"
            )

    @property
    def models(self) -> tuple[str, ...]:
        """The sensor models the batch and the sessions choose among (one: forced)."""
        if self.sensor_model != "auto":
            return (self.sensor_model,)
        return ("beams",) if self.lidar_errors is not None else AUTO

    @property
    def intrinsics_choice(self) -> str:
        """``auto`` (the camera's intrinsics refined when the boards support it) or ``stated``."""
        return "auto" if self.sensor_model == "auto" and not self.intrinsics.refine else "stated"


@dataclass(frozen=True)
class SessionResult:
    """One source's part of a run: its observation and its calibration (its own frames); ``own``:
    with joint sessions, the source's own solve (under the sensor model chosen for all), which the
    boards on corrected ranges and the second look read (None: ``calibration``)."""

    name: str
    observation: Observation
    calibration: Calibration
    own: Calibration | None = None

    @property
    def alone(self) -> Calibration:
        """The calibration of this source alone: ``own``, else ``calibration``."""
        return self.own if self.own is not None else self.calibration


@dataclass(frozen=True)
class Result:
    """What a run gives, in every mode.

    mode: the strategy that solved. calibration: the headline extrinsic and every frame's fate
    (frames named ``session/frame`` when there are several sessions; calibration.yaml).
    sessions: per source its observation and calibration. options: the run's options.
    covariance: the headline extrinsic's (6, 6) covariance, None when the method gives none
    (the paper's refinement; calibration.yaml then holds NaN).
    documents: a strategy's further results as plain data, by file name relative to the output
    folder (``joint.yaml``, ``incremental.yaml``). poses: further named extrinsics with their
    covariance (each session's; a rig: each sensor's, named ``<sensor>`` in the reference's frame).
    per_session: each session's own calibration is written too (``sessions/<name>/``).
    solved: the batch solve's globals a new board would touch (``estimation.next_board``; the next
    pose's promise), None where the strategy gives none. batch: the batch strategy's solution (its
    model choice, noise levels, per-frame answers; None for other strategies); used_frames: the
    frames that solve used, in the corner order it chose (the next pose's boards so far).
    rig: a rig's calibration (every sensor's pose, the joint covariance, every pair; the rig
    strategy's), which ``app.write`` writes as the rig's calibration.yaml (``io.rig_results``) in
    place of ``calibration``'s; None for a single pair or sessions.
    """

    mode: str
    calibration: Calibration
    sessions: tuple[SessionResult, ...]
    options: RunOptions
    covariance: np.ndarray | None = None
    documents: dict[str, Any] = field(default_factory=dict)
    poses: dict[str, Estimate] = field(default_factory=dict)
    per_session: bool = False
    timings: dict[str, float] = field(default_factory=dict)
    solved: SolvedGlobals | None = None
    batch: BatchSolution | None = None
    used_frames: tuple[GraphFrame, ...] = ()
    rig: RigCalibration | None = None
