"""Argument groups that several commands share; each command picks the ones it takes.

- ``add_bag_arguments``: the ROS bag options (``BAG_OPTIONS``, handed to ``datasets.open_source``);
- ``add_frames_arguments``: ``--jobs``, ``--strict`` and ``--stage-cache`` (how the per-frame stages run);
- ``add_sensor_model_argument``: ``--sensor-model`` (``estimation.selection``);

The choices of ``--sensor-model`` and ``--refine`` are their registries' (``run.result.SENSOR_MODELS``,
``run.strategies.refinements``), read when first needed (``console.Choices``).
- ``add_solve_arguments``: the output folder, the solve and the report (``calibrate``, ``demo``).

Pure argparse; the value types are ``console``'s, the meaning of the flags as options ``flags``'.
"""

from __future__ import annotations

import argparse
import os

from ilcc_graph.app.console import COUNT, NON_NEGATIVE, POSITIVE, lazy_choices

__all__ = [
    "BAG_OPTIONS",
    "CACHE_VARIABLE",
    "SENSOR_MODEL_HELP",
    "add_bag_arguments",
    "add_cache_argument",
    "add_frames_arguments",
    "add_sensor_model_argument",
    "add_solve_arguments",
    "default_jobs",
]

#: the bag options' names as parsed (``flags.bag_options``)
BAG_OPTIONS = ("config", "lidar_topic", "image_topic", "sync_tolerance", "min_pause", "select")

SENSOR_MODEL_HELP = (
    "the model of the sensors' own errors: auto (default) chooses among none, range and beams by "
    "how well each predicts every board's image from the other boards; none: each board the LiDAR "
    "stage's pose; range: one range offset and the dark-print offset from the returns; beams: "
    "per-beam offsets (as --lidar-errors); offset: one range offset on the boards' poses"
)


def default_jobs() -> int:
    """Processes for the per-frame stages by default: two where the machine has them, else one."""
    return max(1, min(2, os.cpu_count() or 1))


def add_bag_arguments(sp: argparse.ArgumentParser) -> None:
    """The ROS 1 / ROS 2 bag options (docs/datasets.md), as a group."""
    g = sp.add_argument_group("ROS 1 / ROS 2 bags (docs/datasets.md)")
    g.add_argument("--config", help="the bag's config (default: <bag>.yaml or config.yaml beside it)")
    g.add_argument("--lidar-topic", help="PointCloud2 topic (default: the only one)")
    g.add_argument("--image-topic", help="Image or CompressedImage topic (default: the only one)")
    g.add_argument("--sync-tolerance", type=POSITIVE, metavar="S", help="scan-image stamp difference (0.05)")
    g.add_argument("--min-pause", type=NON_NEGATIVE, metavar="S", help="shortest pause giving a frame (1.0)")
    help = "frames: one per still pause, or every scan (default auto: pauses when the recording has them)"
    g.add_argument("--select", choices=("auto", "pauses", "all"), help=help)


def add_frames_arguments(sp: argparse.ArgumentParser) -> None:
    """--jobs, --strict and --stage-cache: how the per-frame stages run."""
    jobs = default_jobs()
    sp.add_argument("--jobs", type=COUNT, default=jobs, help=f"processes for the per-frame stages ({jobs})")
    help = "stop at the first frame file that cannot be read (default: skip that frame, say why)"
    sp.add_argument("--strict", action="store_true", help=help)
    add_cache_argument(sp)


#: the environment variable naming the stage results' folder when ``--stage-cache`` is not given
CACHE_VARIABLE = "ILCC_GRAPH_STAGE_CACHE"


def add_cache_argument(sp: argparse.ArgumentParser) -> None:
    """--stage-cache DIR / --no-stage-cache: where the per-frame stages keep their results
    (``io.result_store``)."""
    g = sp.add_mutually_exclusive_group()
    help = (
        "keep each scan's and image's stage results in DIR and reuse them when the same data is observed "
        f"with the same settings by the same program (default: ${CACHE_VARIABLE} when set, else none)"
    )
    default = os.environ.get(CACHE_VARIABLE) or None
    g.add_argument("--stage-cache", metavar="DIR", default=default, help=help)
    help = f"keep no stage results (ignore ${CACHE_VARIABLE})"
    g.add_argument("--no-stage-cache", dest="stage_cache", action="store_const", const=None, help=help)


def _sensor_models() -> tuple[str, ...]:
    from ilcc_graph.run.result import SENSOR_MODELS  # the registry: auto and estimation.selection.MODELS

    return SENSOR_MODELS


def _refinements() -> tuple[str, ...]:
    from ilcc_graph.run.strategies import refinements  # the strategies that refine one pair's frames

    return refinements()


def add_sensor_model_argument(sp: argparse.ArgumentParser) -> None:
    """--sensor-model (``estimation.selection``)."""
    lazy_choices(sp.add_argument("--sensor-model", default="auto", help=SENSOR_MODEL_HELP), _sensor_models)


def add_solve_arguments(sp: argparse.ArgumentParser, studies: bool = False) -> None:
    """The output folder, the solve (refinement, kernel, sensor model, intrinsics, LiDAR errors, range
    offset), the per-frame stages and the report; ``studies``: the report's studies by default."""
    sp.add_argument("--out", help="output folder (default: out/<timestamp>, linked as out/latest)")
    help = "graph: our factor graph with covariance (default); paper: the paper's refinement"
    lazy_choices(sp.add_argument("--refine", default="graph", help=help), _refinements)
    help = "robust kernel on the bearing factors (default: none, least squares with the chi-square gate)"
    sp.add_argument("--robust", choices=("huber", "cauchy"), help=help)
    add_sensor_model_argument(sp)
    help = "refine the camera's intrinsics (prior: the config's values and camera.intrinsics_sigma)"
    sp.add_argument("--refine-intrinsics", action="store_true", help=help)
    help = "estimate the LiDAR's per-beam and dark-print range offsets from the boards' returns"
    sp.add_argument("--lidar-errors", action="store_true", help=help)
    help = (
        "with --lidar-errors: each board's own plane and beam offsets' sigmas estimated (default), or "
        "fixed (5 mm / 0.4 deg, 2 mm)"
    )
    sp.add_argument("--board-plane", choices=("estimated", "fixed"), help=help)
    add_frames_arguments(sp)
    sp.add_argument(
        "--no-report", dest="report", action="store_false",
        help="skip the report and its pictures (next_pose.png too: the summary still says the next pose)",
    )  # fmt: skip
    sp.add_argument("--clouds", action="store_true", help="with the report: coloured clouds (coloured/)")
    sp.add_argument("--full-views", action="store_true", help="with the report: whole pictures at full size")
    help = (
        f"add frames-vs-accuracy and cross-validation to the report (default: {'on' if studies else 'off'})"
    )
    sp.add_argument("--studies", action=argparse.BooleanOptionalAction, default=studies, help=help)
    help = "also estimate the LiDAR's range offset, one per LiDAR (docs/joint.md)"
    sp.add_argument("--range-offset", action="store_true", help=help)
