"""The layout the project aims for: every module listed in docs/architecture.md, none oversized."""

from __future__ import annotations

import ast
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 450  # "no module over ~400 lines" (issue 12), with a little room


def _lister():
    spec = importlib.util.spec_from_file_location("list_modules", ROOT / "scripts" / "list_modules.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


def test_every_module_is_listed_in_the_architecture_doc() -> None:
    lister = _lister()
    doc = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    listed = doc.split(lister.BEGIN, 1)[1].split(lister.END, 1)[0]
    missing = [p.as_posix() for p in lister.modules() if f"`{p.as_posix()}`" not in listed]
    assert not missing, f"not in docs/architecture.md (run scripts/list_modules.py): {missing}"


def test_no_module_is_oversized() -> None:
    big = {
        p.as_posix(): n
        for p in _lister().modules()
        if (n := len((ROOT / p).read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert not big, f"modules over {MAX_LINES} lines: {big}"


def _imported(path: Path) -> set[str]:
    """Every module ``path`` (a module of ilcc_graph) imports, relative imports resolved, with
    ``from a import b`` counted as ``a`` and ``a.b``."""
    rel = path.relative_to(ROOT)
    package = list(rel.parts[:-1])
    got: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            got.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            got.add(module)
            got.update(f"{module}.{a.name}" for a in node.names)
    return got


def test_nothing_below_the_command_line_imports_it() -> None:
    """Imports point one way (docs/architecture.md): ``ilcc_graph.app`` is the top floor."""
    below = [p for p in sorted((ROOT / "ilcc_graph").rglob("*.py")) if p.relative_to(ROOT).parts[1] != "app"]
    wrong = {}
    for p in below:
        if found := sorted(m for m in _imported(p) if (m + ".").startswith("ilcc_graph.app.")):
            wrong[p.relative_to(ROOT).as_posix()] = found
    assert len(below) > 100 and not wrong, f"modules below app/ that import it: {wrong}"

