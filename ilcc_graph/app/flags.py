"""The flags' meaning as options: the only mapping from parsed arguments to the package's options.

``run_options(args) -> run.result.RunOptions`` (calibrate, demo), ``stage_options(args) ->
run.stages.StageOptions``, ``bag_options(args)`` (keywords of ``datasets.open_source``) and
``check_options(args) -> run.live.CheckOptions``. A contradiction between flags is an ``InputError``
(exit 2). The package's modules are imported when a command runs, not when the parser is built.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ilcc_graph.app.arguments import BAG_OPTIONS
from ilcc_graph.errors import InputError

if TYPE_CHECKING:
    from ilcc_graph.estimation.lidar_errors import LidarErrorOptions
    from ilcc_graph.run.live import CheckOptions
    from ilcc_graph.run.result import RunOptions
    from ilcc_graph.run.stages import StageOptions

__all__ = ["bag_options", "check_options", "run_options", "stage_options"]


def run_options(args: argparse.Namespace) -> RunOptions:
    """The run's options from the arguments of ``calibrate`` or ``demo``."""
    from ilcc_graph.estimation import NoiseOptions
    from ilcc_graph.estimation.intrinsics import IntrinsicsOptions
    from ilcc_graph.estimation.sessions import JointOptions
    from ilcc_graph.run.result import RunOptions

    joint: dict = {
        "mode": getattr(args, "mode", "rigid"),
        "alpha": getattr(args, "alpha", 0.01),
        "range_offset": getattr(args, "range_offset", False),
    }
    if (drift := getattr(args, "drift_sigma", None)) is not None:
        joint["drift_sigma_deg"], joint["drift_sigma_mm"] = drift
    if (rep := getattr(args, "repeatability", None)) is not None:
        joint["repeatability_deg"], joint["repeatability_mm"] = rep
    target = getattr(args, "target_sigma", None)
    stop = bool(getattr(args, "stop_at_target", False))
    mode = "incremental" if target is not None or stop else getattr(args, "refine", "graph")
    if mode != "graph" and (len(getattr(args, "data", [None])) > 1 or joint["range_offset"]):
        raise InputError("--refine paper and --target-sigma calibrate one data set without a range offset")
    model = getattr(args, "sensor_model", "auto")
    if getattr(args, "lidar_errors", False) and model not in ("auto", "beams"):
        raise InputError(f"--lidar-errors is the beams model; it contradicts --sensor-model {model}")
    return RunOptions(
        sensor_model=model,
        lidar_errors=_lidar_errors(args),
        intrinsics=IntrinsicsOptions(refine=bool(getattr(args, "refine_intrinsics", False))),
        mode=mode,
        noise=NoiseOptions(robust=getattr(args, "robust", None)),
        stages=stage_options(args),
        joint=JointOptions(**joint),
        target_sigma=target,
        stop_at_target=stop,
    )


def _lidar_errors(args: argparse.Namespace) -> LidarErrorOptions | None:
    """``--lidar-errors`` (and ``--board-plane``) as options, or None without them."""
    from ilcc_graph.estimation.lidar_errors import LidarErrorOptions

    plane = getattr(args, "board_plane", None)
    if not getattr(args, "lidar_errors", False):
        if plane is not None:
            raise InputError("--board-plane applies to --lidar-errors only")
        return None
    if plane is None:
        return LidarErrorOptions()
    return LidarErrorOptions(board_plane_estimate=plane == "estimated")


def stage_options(args: argparse.Namespace) -> StageOptions:
    """``--jobs``, ``--strict`` and ``--stage-cache`` as the per-frame stages' options."""
    from ilcc_graph.run.stages import StageOptions

    strict = bool(getattr(args, "strict", False))
    return StageOptions(jobs=getattr(args, "jobs", 1), strict=strict, cache=_cache(args))


def _cache(args: argparse.Namespace) -> Path | None:
    """The stage results' folder of ``--stage-cache`` (made when missing), or None."""
    from ilcc_graph.io.result_store import open_store

    folder = getattr(args, "stage_cache", None)
    return None if not folder else open_store(folder, "--stage-cache")


def bag_options(args: argparse.Namespace) -> dict[str, Any]:
    """The bag options (``arguments.BAG_OPTIONS``) as keywords of ``datasets.open_source``."""
    return {k: getattr(args, k, None) for k in BAG_OPTIONS}


def check_options(args: argparse.Namespace) -> CheckOptions:
    """``check``'s options: the target, when to stop, the folder followed, the sensor models tried
    (``auto``: those ``estimation.selection`` chooses among), the stages on one process."""
    from ilcc_graph.run.live import CheckOptions
    from ilcc_graph.run.stages import StageOptions

    target = args.target_sigma
    return CheckOptions(
        target_sigma=target,
        until=args.until,
        watch=args.watch,
        stop_at_target=target is not None,
        stages=StageOptions(jobs=1, cache=_cache(args)),
        sensor_model=args.sensor_model,
    )
