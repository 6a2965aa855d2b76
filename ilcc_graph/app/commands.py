"""The registry of commands: one line per command, in the order ``ilcc-graph --help`` lists them.

A command is a module ``cmd_<name>.py`` with ``HELP``, ``add_arguments(parser)`` (its flags, from the
shared groups of ``arguments``) and ``run(args) -> exit code``; a new command is that file and one
line here. The modules import the package's working parts when they run, so building the parser
stays light.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass

from ilcc_graph.app import (
    cmd_calibrate,
    cmd_check,
    cmd_corners,
    cmd_demo,
    cmd_evaluate,
    cmd_export,
    cmd_simulate,
    cmd_simulate_rig,
    cmd_verify,
)

__all__ = ["COMMANDS", "Command"]


@dataclass(frozen=True)
class Command:
    """One command: its name, its one-line help (also its description), its arguments, its run."""

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


COMMANDS: tuple[Command, ...] = (
    Command("calibrate", cmd_calibrate.HELP, cmd_calibrate.add_arguments, cmd_calibrate.run),
    Command("demo", cmd_demo.HELP, cmd_demo.add_arguments, cmd_demo.run),
    Command("simulate", cmd_simulate.HELP, cmd_simulate.add_arguments, cmd_simulate.run),
    Command("simulate-rig", cmd_simulate_rig.HELP, cmd_simulate_rig.add_arguments, cmd_simulate_rig.run),
    Command("lidar-corners", cmd_corners.LIDAR_HELP, cmd_corners.add_arguments, cmd_corners.run_lidar),
    Command("image-corners", cmd_corners.IMAGE_HELP, cmd_corners.add_arguments, cmd_corners.run_image),
    Command("evaluate", cmd_evaluate.HELP, cmd_evaluate.add_arguments, cmd_evaluate.run),
    Command("check", cmd_check.HELP, cmd_check.add_arguments, cmd_check.run),
    Command("export", cmd_export.HELP, cmd_export.add_arguments, cmd_export.run),
    Command("verify", cmd_verify.HELP, cmd_verify.add_arguments, cmd_verify.run),
)
