"""The command line's choices are their registries' (issue 34): a strategy registered as a refinement,
a sensor model or an export format appears in ``--refine``, ``--sensor-model`` and ``export --format``
without an edit to the parser, and a value outside them is refused by argparse naming them."""

from __future__ import annotations

import argparse
import subprocess
import sys

from ilcc_graph.app.parser import build_parser


def _choices(command: str, flag: str) -> tuple[str, ...]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    action = next(a for a in sub.choices[command]._actions if flag in a.option_strings)
    return tuple(action.choices)


def test_the_choices_are_the_registries() -> None:
    from ilcc_graph.estimation.selection import MODELS
    from ilcc_graph.exports import FORMATS
    from ilcc_graph.exports_rig import RIG_FORMATS
    from ilcc_graph.run.strategies import modes, strategy

    assert _choices("calibrate", "--sensor-model") == ("auto", *MODELS)
    assert _choices("check", "--sensor-model") == ("auto", *MODELS)
    assert _choices("calibrate", "--refine") == tuple(m for m in modes() if strategy(m).refinement)
    assert {"graph", "paper"} <= set(_choices("calibrate", "--refine"))
    assert set(_choices("export", "--format")) == set(FORMATS) | set(RIG_FORMATS)


def test_a_value_outside_a_registry_is_refused_naming_the_registry(tmp_path) -> None:  # noqa: ANN001
    run = subprocess.run(
        [sys.executable, "-m", "ilcc_graph.app", "calibrate", str(tmp_path), "--refine", "isam"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 2, run.stderr
    assert "invalid choice: 'isam'" in run.stderr and "'graph', 'paper'" in run.stderr, run.stderr


def test_building_the_parser_reads_no_registry_until_asked() -> None:
    """The registries import the solvers and the simulator (seconds): building the parser, which every
    command does before its first worker can start, imports none of them; the help lists them."""
    code = (
        "import sys\n"
        "from ilcc_graph.app.parser import build_parser\n"
        "p = build_parser()\n"
        "heavy = [m for m in ('ilcc_graph.run.strategies', 'ilcc_graph.estimation',\n"
        "                     'ilcc_graph.simulate.rig_spec', 'ilcc_graph.simulate.frames',\n"
        "                     'ilcc_graph.exports', 'gtsam', 'scipy.spatial') if m in sys.modules]\n"
        "print(heavy)\n"
        "p.parse_args(['simulate-rig', '--help'])\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    first, help_text = run.stdout.split("\n", 1)
    assert first == "[]", first
    assert "ring-fisheye" in help_text and "backpack" in help_text, help_text
