"""``ilcc-graph simulate-rig``: a simulated rig data set with its ground truth (docs/rig.md).

A preset rig (``simulate.rig_spec.RIG_PRESETS``) written as a folder per sensor or as one ROS bag
(``simulate.rig_export``), with ``rig.yaml`` and ``rig_ground_truth.yaml``; ``--moved`` turns and
shifts one sensor's mount (a capture for ``verify``: same boards as the unmoved rig of that seed).
"""

from __future__ import annotations

import argparse

from ilcc_graph.app.console import COUNT, PIXELS, RIG_SEED_HELP, SEED, Progress, lazy_choices

__all__ = ["HELP", "add_arguments", "run"]

HELP = "write a simulated rig (several cameras and LiDARs) with ground truth"


def _triple(text: str) -> tuple[float, float, float]:
    """'X,Y,Z' -> three numbers (an argparse type)."""
    try:
        x = tuple(float(v) for v in text.split(","))
    except ValueError:
        x = ()
    if len(x) != 3:
        raise argparse.ArgumentTypeError(f"expected three numbers X,Y,Z, got {text!r}")
    return x[0], x[1], x[2]


def _presets() -> tuple[str, ...]:
    from ilcc_graph.simulate.rig_spec import RIG_PRESETS

    return tuple(RIG_PRESETS)


def add_arguments(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("out", metavar="OUT")
    help = "%(choices)s (default ring-fisheye; docs/rig.md)"
    lazy_choices(sp.add_argument("--rig", default="ring-fisheye", metavar="PRESET", help=help), _presets)
    sp.add_argument("--moments", type=COUNT, default=12, help="board placements (default 12)")
    sp.add_argument("--seed", type=SEED, default=0, help="the simulation's seed (default 0)")
    sp.add_argument("--rig-seed", type=SEED, default=None, metavar="SEED", help=RIG_SEED_HELP)
    sp.add_argument("--width", type=PIXELS, default=None, help="image width (default: the preset's)")
    help = "folders: a folder per sensor (default); bag: one ROS bag with a topic per sensor"
    sp.add_argument("--as", dest="layout", choices=("folders", "bag"), default="folders", help=help)
    help = "the bag's storage (default ros1)"
    sp.add_argument("--storage", choices=("ros1", "sqlite3", "mcap"), default="ros1", help=help)
    g = sp.add_argument_group("a moved mount (a capture for verify)")
    g.add_argument("--moved", metavar="SENSOR", help="the sensor whose mount moved")
    help = "its turn, a rotation vector in its own frame, degrees (default 0,0,0)"
    g.add_argument("--rotation-deg", type=_triple, default=(0.0, 0.0, 0.0), metavar="RX,RY,RZ", help=help)
    help = "its shift in its own frame, mm (default 0,0,0)"
    g.add_argument("--translation-mm", type=_triple, default=(0.0, 0.0, 0.0), metavar="TX,TY,TZ", help=help)


def run(args: argparse.Namespace) -> int:
    from ilcc_graph.errors import InputError
    from ilcc_graph.simulate.rig_export import write_rig_bag, write_rig_set
    from ilcc_graph.simulate.rig_spec import RIG_PRESETS, Mount

    kw = {"n_moments": args.moments, "seed": args.seed}
    if args.width is not None:
        kw["width"] = args.width
    spec = RIG_PRESETS[args.rig](**kw).with_(unit_seed=args.rig_seed)
    if args.moved is not None:
        if args.moved not in spec.names:
            raise InputError(f"--moved {args.moved}: not a sensor of {args.rig} ({', '.join(spec.names)})")
        spec = spec.with_(moved=Mount(args.moved, args.rotation_deg, args.translation_mm))
    progress = Progress("simulate")
    if args.layout == "bag":
        out = write_rig_bag(args.out, spec, progress, storage=args.storage, command=args.command_line)
    else:
        out = write_rig_set(args.out, spec, progress, command=args.command_line)
    print(f"wrote a {args.rig} rig ({', '.join(spec.names)}), {spec.n_moments} moments, to {out}")
    return 0
