"""The import arrows of docs/architecture.md, checked: layers that import only downwards, stage
packages that do not import each other, ``factors/`` on gtsam and numpy alone, stages that do not
reach for files, nothing importing ``app/``.

Each module of ``ilcc_graph`` belongs to a *unit*: its sub-package (``ilcc_graph/lidar/...`` ->
``lidar``) or, for a module at the package root, its own name (``ilcc_graph/exports.py`` ->
``exports``). ``LAYERS`` places every unit on a floor; a unit may import its own modules and units
on lower floors, never a unit on its own floor (units on one floor are independent) or above.
Below the orchestration each package is also held to the arrow the doc draws for it (``ARROWS``).
Every import counts, at module level or inside a function, except those under ``if
TYPE_CHECKING:`` (names for type hints that never run; ``factors/`` and ``app/`` count them too).

A floor lists the units the architecture places there whether or not they exist (only those that
do are checked). A unit that exists but is on no floor fails the
test, so a new package has to be placed here (and in docs/architecture.md) when it is added.
"""

from __future__ import annotations

import ast
import shutil
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Top floor first: (units, independent). Units on an independent floor do not import each other.
LAYERS: tuple[tuple[tuple[str, ...], bool], ...] = (
    (("app",), True),  # the command line: nothing imports it
    # the orchestration: the run over a source (run/: opening, observation pass, strategies,
    # evaluation, `check`), the exports and the hand-off into a user's GTSAM graph
    (("run", "exports", "handoff", "exports_rig", "handoff_rig"), False),
    (("report", "next_pose"), True),  # what the run shows and advises; the run hands them its results
    (("estimation", "evaluation"), True),  # the one estimation core; how right an answer is (no solve)
    (("datasets", "lidar", "image", "init", "simulate"), True),  # frame sources and the stages
    (("config",), True),  # the one reader of config.yaml
    (("cameras", "lidars", "io", "workers"), True),  # sensor models, files, worker processes
    (("board", "checks", "signals", "_forkserver_preload"), True),
    (("errors", "types"), True),  # no project imports
)

# The arrows of docs/architecture.md's drawing for the packages below the orchestration: what each
# may import besides itself and ``errors``, ``types`` (which every module may import). Stricter than
# the floors: a package that may not import a lower one is held to it here.
BASE = {"errors", "types"}
ARROWS: dict[str, set[str]] = {
    "errors": set(),
    "types": set(),
    "board": set(),
    "checks": set(),
    "signals": set(),
    "_forkserver_preload": set(),
    "cameras": {"checks"},
    "lidars": set(),
    "io": {"signals"},
    "workers": {"signals"},
    "config": {"board", "cameras", "checks", "lidars", "io"},
    "datasets": {"config", "cameras", "io"},
    "lidar": {"board", "lidars"},
    "image": {"board", "cameras"},
    "init": {"board"},  # the rig's start (init/rig_start.py) reads the board's corners
    "simulate": {"board", "cameras", "lidars", "io", "config"},
    "estimation": {"board", "cameras", "init"},
    "next_pose": {"estimation", "lidar", "lidars", "cameras", "board", "config"},
    "evaluation": {"board", "cameras", "image", "init"},  # causes.py: a board alone from its image (UPnP)
    "report": {"lidar", "image", "estimation", "evaluation", "board", "cameras", "config", "io"},
}

# The stage packages do no file I/O (docs/architecture.md: only datasets/, io/ and app/ touch the
# disk); simulate/ writes its data sets through io/ and is not held to this.
PURE = {"lidar", "image", "init", "estimation", "evaluation", "next_pose"}
FILE_UNITS = {"io", "datasets"}
# factors/ uses gtsam, numpy and the standard library; typing_extensions stands in for the typing
# names of Python 3.11 on 3.10 (a dependency only there: pyproject.toml)
FACTORS_MAY_USE = {"gtsam", "numpy", "typing_extensions"}


@dataclass(frozen=True)
class Import:
    module: str  # the importing module, dotted
    target: str  # what it imports, dotted (``from a import b`` gives ``a`` and ``a.b``)
    line: int
    type_only: bool  # under ``if TYPE_CHECKING:``


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def scan(root: Path) -> list[Import]:
    """Every import of the modules of ``ilcc_graph/`` and ``factors/`` under ``root``, relative
    imports resolved."""
    found: list[Import] = []
    for path in sorted([*(root / "ilcc_graph").rglob("*.py"), *(root / "factors").rglob("*.py")]):
        rel = path.relative_to(root)
        package = list(rel.parts[:-1])
        module = ".".join(package + ([] if rel.stem == "__init__" else [rel.stem]))

        def visit(node: ast.AST, type_only: bool, package: list[str] = package, module: str = module) -> None:
            if isinstance(node, ast.If) and _is_type_checking(node.test):
                for child in node.body:
                    visit(child, True)
                for child in node.orelse:
                    visit(child, type_only)
                return
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = package[: len(package) - node.level + 1] if node.level else []
                name = ".".join([*base, *([node.module] if node.module else [])])
                targets = [name, *(f"{name}.{a.name}" for a in node.names)]
            for t in targets:
                found.append(Import(module, t, getattr(node, "lineno", 0), type_only))
            for child in ast.iter_child_nodes(node):
                visit(child, type_only)

        visit(ast.parse(path.read_text(encoding="utf-8")), False)
    return found


def unit_of(dotted: str) -> str | None:
    """The unit of a dotted module name of this project (None outside ``ilcc_graph``)."""
    parts = dotted.split(".")
    if parts[0] != "ilcc_graph":
        return None
    return parts[1] if len(parts) > 1 else ""


def floors(present: Iterable[str]) -> dict[str, tuple[int, bool]]:
    """unit -> (its floor's height, whether the units of that floor are independent)."""
    where = {
        u: (len(LAYERS) - k, independent) for k, (units, independent) in enumerate(LAYERS) for u in units
    }
    return {u: where[u] for u in present if u in where}


def violations(imports: list[Import], present: set[str]) -> list[str]:
    """The broken contracts, one line each (``contract: module:line imports target``)."""
    placed = floors(present)
    out = [
        f"layers: ilcc_graph.{u} is on no floor of LAYERS (place it there and in the doc)"
        for u in sorted(present - set(placed) - {""})
    ]
    for imp in imports:
        src, dst = unit_of(imp.module), unit_of(imp.target)
        where = f"{imp.module}:{imp.line} imports {imp.target}"
        if imp.module.split(".")[0] == "factors":
            top = imp.target.split(".")[0]
            if top == "ilcc_graph":
                out.append(f"factors: {where} (factors/ never imports ilcc_graph)")
            elif top not in FACTORS_MAY_USE | set(sys.stdlib_module_names) | {"factors"}:
                out.append(f"factors: {where} (only gtsam, numpy and the standard library)")
            continue
        if dst is None or src is None or dst == "" or src == dst:
            continue
        if dst == "app":  # type-only imports of app/ count too: nothing below it may name it
            out.append(f"app: {where} (nothing imports the command line)")
            continue
        if src == "report" and dst == "run":  # type-only too: the report reads typed results, not the run
            out.append(f"pure report: {where} (report/ takes what it draws as data; it never names the run)")
        if src in PURE and dst in FILE_UNITS and not imp.type_only:
            out.append(f"pure stages: {where} ({src}/ does no file I/O)")
        if imp.type_only or src not in placed or dst not in placed:
            continue
        allowed = ARROWS.get(src)
        if allowed is not None and dst not in allowed | (set() if src in BASE else BASE):
            out.append(
                f"arrows: {where} (docs/architecture.md draws {src} -> {', '.join(sorted(allowed)) or '-'})"
            )
        (h_src, independent), (h_dst, _) = placed[src], placed[dst]
        if h_dst > h_src:
            out.append(f"layers: {where} ({src} is below {dst})")
        elif h_dst == h_src and independent:
            out.append(f"layers: {where} ({src} and {dst} are on one floor: independent)")
    return out


def present_units(root: Path) -> set[str]:
    pkg = root / "ilcc_graph"
    units = {p.name for p in pkg.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    units |= {p.stem for p in pkg.glob("*.py") if p.stem != "__init__"}
    return units


def test_the_import_contracts_hold() -> None:
    imports = scan(ROOT)
    present = present_units(ROOT)
    assert len(imports) > 500 and {"app", "estimation", "lidar", "report"} <= present
    bad = violations(imports, present)
    assert not bad, "imports against docs/architecture.md:\n" + "\n".join(bad)


def test_every_floor_names_units_the_doc_draws() -> None:
    """The floors and docs/architecture.md speak of the same units (a renamed package is renamed
    in both)."""
    doc = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    named = [u for units, _ in LAYERS for u in units if u != "_forkserver_preload"]
    missing = [u for u in named if u not in doc]
    assert not missing, f"units on a floor that docs/architecture.md does not name: {missing}"


# -- each contract can fail ----------------------------------------------------------------------


def _one(module: str, target: str, type_only: bool = False) -> list[Import]:
    return [Import(module, target, 1, type_only)]


PRESENT = present_units(ROOT) | {"run"}


@pytest.mark.parametrize(
    ("module", "target", "contract"),
    [
        ("ilcc_graph.lidar.fit", "ilcc_graph.image", "layers"),  # stages are independent
        ("ilcc_graph.image.detect", "ilcc_graph.init.upnp", "layers"),
        ("ilcc_graph.simulate.render", "ilcc_graph.lidar", "layers"),
        ("ilcc_graph.init.upnp", "ilcc_graph.datasets", "layers"),
        ("ilcc_graph.estimation.noise", "ilcc_graph.report", "layers"),  # a lower floor, an upper one
        ("ilcc_graph.cameras.base", "ilcc_graph.config", "layers"),
        ("ilcc_graph.types", "ilcc_graph.errors", "layers"),  # no project imports
        ("ilcc_graph.report.html", "ilcc_graph.run.pipeline", "layers"),  # the run hands report its results
        ("ilcc_graph.report.html", "ilcc_graph.run.pipeline", "layers"),  # ... also once run/ is there
        ("ilcc_graph.next_pose.advisor", "ilcc_graph.report.text", "layers"),
        ("ilcc_graph.run.pipeline", "ilcc_graph.app.write", "app"),
        ("ilcc_graph.report.html", "ilcc_graph.app", "app"),
        ("ilcc_graph.report.summary", "ilcc_graph.run.result", "pure report"),
        ("factors.bearing", "ilcc_graph.types", "factors"),
        ("factors.pixel", "scipy.optimize", "factors"),
        ("ilcc_graph.lidar.pose", "ilcc_graph.io.scans", "pure stages"),
        ("ilcc_graph.estimation.graphs", "ilcc_graph.lidars", "arrows"),  # lower, but not drawn
        ("ilcc_graph.cameras.registry", "ilcc_graph.board", "arrows"),
        ("ilcc_graph.report.html", "ilcc_graph.datasets", "arrows"),
        ("ilcc_graph.types", "ilcc_graph.errors", "arrows"),
        ("ilcc_graph.estimation.batch", "ilcc_graph.datasets", "pure stages"),
    ],
)
def test_a_broken_contract_is_caught(module: str, target: str, contract: str) -> None:
    bad = violations(_one(module, target), PRESENT)
    assert any(b.startswith(f"{contract}:") for b in bad), bad


def test_what_the_contracts_allow_passes() -> None:
    allowed = [
        ("ilcc_graph.app.write", "ilcc_graph.run"),
        ("ilcc_graph.run.observe", "ilcc_graph.lidar"),
        ("ilcc_graph.run.pipeline", "ilcc_graph.exports"),  # the orchestration's units import one another
        ("ilcc_graph.report.html", "ilcc_graph.estimation"),
        ("ilcc_graph.estimation.graphs", "factors"),
        ("ilcc_graph.estimation.graphs", "ilcc_graph.init"),
        ("factors.bearing", "gtsam"),
        ("factors.bearing", "dataclasses"),
        ("ilcc_graph.next_pose.advisor", "ilcc_graph.run.result"),
    ]
    for module, target in allowed[:-1]:
        assert not violations(_one(module, target), PRESENT), (module, target)
    # a type hint's import does not run: a lower floor may name an upper one's type for the checker
    assert not violations(_one(*allowed[-1], type_only=True), PRESENT)
    # ... but the report names no part of the run, not even for the checker (issue 34: a pure report)
    assert violations(_one("ilcc_graph.report.rig_report", "ilcc_graph.run.rig_observe", True), PRESENT)


def test_every_package_below_the_orchestration_has_its_arrow() -> None:
    """A package on the floors from ``report`` down is in ARROWS (its arrow drawn in the doc)."""
    lower = {u for units, _ in LAYERS[2:] for u in units}
    assert lower == set(ARROWS), sorted(lower ^ set(ARROWS))


def test_a_new_package_must_be_placed() -> None:
    bad = violations([], PRESENT | {"gui"})
    assert bad == ["layers: ilcc_graph.gui is on no floor of LAYERS (place it there and in the doc)"]


def test_a_violation_written_into_a_copy_is_found(tmp_path: Path) -> None:
    """End to end on files: a copy of the package with one stage importing another."""
    for name in ("ilcc_graph", "factors"):
        shutil.copytree(ROOT / name, tmp_path / name, ignore=shutil.ignore_patterns("__pycache__"))
    assert not violations(scan(tmp_path), present_units(tmp_path))
    fit = tmp_path / "ilcc_graph" / "lidar" / "fit.py"
    fit.write_text(fit.read_text(encoding="utf-8") + "\n\ndef _late():\n    from ..image import detect\n")
    (tmp_path / "factors" / "bad.py").write_text("import ilcc_graph.types\n")
    bad = violations(scan(tmp_path), present_units(tmp_path))
    assert sorted(b.split(":")[0] for b in bad) == ["arrows", "arrows", "factors", "layers", "layers"], bad
    assert any("ilcc_graph.lidar.fit" in b and "ilcc_graph.image" in b for b in bad), bad
