"""No long functions in any package (issue 23: "no function over ~80 lines"; issue 34: every package).

A function's length is its lines from ``def`` to its last line, its docstring not counted (a
function is not made shorter by documenting it less). Nested functions count inside their parent
and on their own."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 80
# every package: ilcc_graph (its stages, the core, the orchestration and the command line) and factors
PACKAGES = ("ilcc_graph", "factors")


def lengths(path: Path) -> list[tuple[str, int, int]]:
    """(name, first line, length without the docstring) of every function in the module ``path``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            n = (node.end_lineno or node.lineno) - node.lineno + 1
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                if isinstance(first.value.value, str):
                    n -= (first.end_lineno or first.lineno) - first.lineno + 1
            out.append((node.name, node.lineno, n))
    return out


def test_no_function_in_any_package_is_long() -> None:
    files = [p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))]
    long = [
        f"{p.relative_to(ROOT).as_posix()}:{line} {name} ({n} lines)"
        for p in files
        for name, line, n in lengths(p)
        if n > MAX_LINES
    ]
    assert len(files) > 100, len(files)
    assert not long, f"functions over {MAX_LINES} lines (docstrings aside): split them\n" + "\n".join(long)


def test_the_measure_counts_code_and_not_docstrings(tmp_path: Path) -> None:
    body = "\n".join(f"    x{k} = {k}" for k in range(MAX_LINES))
    doc = '    """' + "\n".join(["one"] * 30) + '"""\n'
    (tmp_path / "m.py").write_text(f"def long():\n{body}\n\n\ndef documented():\n{doc}    return 1\n")
    got = {name: n for name, _, n in lengths(tmp_path / "m.py")}
    assert got == {"long": MAX_LINES + 1, "documented": 2}, got
