"""``ilcc-graph simulate``: a simulated data set with its ground truth (``simulate.export``)."""

from __future__ import annotations

import argparse

from ilcc_graph.app.console import COUNT, NON_NEGATIVE, PIXELS, SEED, Progress

__all__ = ["HELP", "add_arguments", "run"]

HELP = "write a simulated data set with ground truth"


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


def run(args: argparse.Namespace) -> int:
    from ilcc_graph.simulate.export import write_standard_set

    names = (
        "lidar",
        "camera",
        "width",
        "frames",
        "seed",
        "noise_scale",
        "intrinsics_error",
        "pcd_style",
        "range_offset_mm",
    )
    spec = write_standard_set(
        args.out,
        Progress("simulate"),
        sensor_format=args.format,
        command=args.command_line,
        **{k: getattr(args, k) for k in names},
    )
    print(f"wrote {spec.n_frames} frames to {args.out}")
    return 0
