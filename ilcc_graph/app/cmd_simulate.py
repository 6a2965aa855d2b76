"""``ilcc-graph simulate``: a simulated data set with its ground truth (``simulate.write_set``), or
with ``--bag`` the same as a ROS bag (``simulate.bag.write_bag``: OUT, with ``<OUT>.yaml`` and
``<OUT>.ground_truth.yaml`` beside it; none may exist, since a run never writes over a file it did
not write)."""

from __future__ import annotations

import argparse
from typing import Any

from ilcc_graph.app.console import COUNT, NON_NEGATIVE, PIXELS, RIG_SEED_HELP, SEED, Progress, lazy_choices

__all__ = ["HELP", "add_arguments", "run"]

HELP = "write a simulated data set with ground truth"


def _intensity_fields() -> tuple[str, ...]:
    from ilcc_graph.simulate.spec import INTENSITY_FIELDS

    return tuple(INTENSITY_FIELDS)


def add_arguments(sp: argparse.ArgumentParser) -> None:
    from ilcc_graph.cameras import camera_kinds
    from ilcc_graph.io.pcd import PCD_STYLES
    from ilcc_graph.lidars.tables import MODEL_NAMES as LIDAR_NAMES

    sp.add_argument("out", metavar="OUT")
    lidars = [m for m in LIDAR_NAMES if m != "generic"]
    sp.add_argument(
        "--lidar",
        default="hdl32",
        choices=lidars,
        metavar="MODEL",
        help=f"{', '.join(lidars)} (default hdl32)",
    )
    help = "plain PCD (default); ouster: organised, ring 0 at the top, raw signal; velodyne-csv: laser_id"
    sp.add_argument("--format", default="plain", choices=("plain", "ouster", "velodyne-csv"), help=help)
    help = "PCD files as this tool writes them (default plain; matlab: pcwrite's header comment, no ring)"
    sp.add_argument("--pcd-style", default="plain", choices=PCD_STYLES, help=help)
    sp.add_argument(
        "--camera", default="equirectangular", choices=camera_kinds(), help="(default equirectangular)"
    )
    sp.add_argument("--frames", type=COUNT, default=20, help="board poses (default 20)")
    sp.add_argument("--seed", type=SEED, default=0, help="the simulation's seed (default 0)")
    sp.add_argument("--rig-seed", type=SEED, default=None, metavar="SEED", help=RIG_SEED_HELP)
    sp.add_argument(
        "--noise-scale",
        type=NON_NEGATIVE,
        default=1.0,
        help="multiplier on the baseline LiDAR noise (default 1)",
    )
    sp.add_argument(
        "--width",
        type=PIXELS,
        default=None,
        help="image width (default: the camera kind's, 8000 for a panorama)",
    )
    wrong_k = "config.yaml states intrinsics off by SCALE x a typical error (0.5%% f, 2 px c); 0 = the truth"
    sp.add_argument("--intrinsics-error", type=NON_NEGATIVE, default=0.0, metavar="SCALE", help=wrong_k)
    help = "every range reads MM long (a LiDAR's zero error), on top of the per-beam and dark-print offsets"
    sp.add_argument("--range-offset-mm", type=float, default=0.0, metavar="MM", help=help)
    help = (
        "what the scans' intensity holds: print (default), invisible (a print the LiDAR cannot see), "
        "zero, none (no intensity field: x y z only), ring (the ring number)"
    )
    lazy_choices(sp.add_argument("--intensity-field", default="print", help=help), _intensity_fields)
    sp.add_argument(
        "--no-ring-field", dest="ring_field", action="store_false", help="scans without a ring field"
    )
    g = sp.add_argument_group("as a ROS bag (docs/datasets.md)")
    help = "OUT is a new ROS bag (OUT.bag: ROS 1, else a ROS 2 folder); OUT.yaml, OUT.ground_truth.yaml by it"
    g.add_argument("--bag", action="store_true", help=help)
    help = "ros1 for OUT.bag, else sqlite3 (default); or mcap"
    g.add_argument("--storage", choices=("auto", "ros1", "sqlite3", "mcap"), default="auto", help=help)
    help = "Image bgr8 (default), or CompressedImage png or jpeg"
    g.add_argument("--bag-images", choices=("bgr8", "png", "jpeg"), default="bgr8", help=help)


#: the flags that are the standard set's spec, by their names there
SPEC_OPTIONS = (
    "lidar", "camera", "width", "frames", "seed", "noise_scale", "intrinsics_error", "pcd_style",
    "range_offset_mm", "intensity_field", "ring_field",
)  # fmt: skip


def _spec_options(args: argparse.Namespace) -> dict[str, Any]:
    return {k: getattr(args, k) for k in SPEC_OPTIONS}


def run(args: argparse.Namespace) -> int:
    from ilcc_graph.simulate.write_set import write_standard_set

    if args.bag:
        return _bag(args)

    spec = write_standard_set(
        args.out,
        Progress("simulate"),
        sensor_format=args.format,
        command=args.command_line,
        unit_seed=args.rig_seed,
        **_spec_options(args),
    )
    print(f"wrote {spec.n_frames} frames to {args.out}")
    return 0


def _bag(args: argparse.Namespace) -> int:
    """``simulate --bag``: the standard set as a ROS bag at ``args.out`` (new files only)."""
    from ilcc_graph.errors import InputError
    from ilcc_graph.simulate.bag import write_bag
    from ilcc_graph.simulate.write_set import standard_set_spec

    if args.format != "plain" or args.pcd_style != "plain":
        raise InputError(
            "simulate --bag: --format and --pcd-style are for PCD files; a bag holds PointCloud2"
        )
    spec = standard_set_spec(unit_seed=args.rig_seed, **_spec_options(args))
    kw = {"storage": args.storage, "image_format": args.bag_images, "flag": "simulate"}
    out = write_bag(args.out, spec, progress=Progress("simulate"), **kw)
    print(f"wrote {spec.n_frames} frames to the bag {out} (config and ground truth beside it)")
    return 0
