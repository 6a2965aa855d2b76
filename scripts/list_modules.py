"""Write the table of every module (path, lines, the first line of its docstring) into docs/architecture.md.

The table sits between the ``modules:begin`` / ``modules:end`` markers; ``tests/test_layout.py``
checks that it lists every module of ``ilcc_graph/`` and ``factors/`` and that none is over the
size the layout aims for. Usage: python3 scripts/list_modules.py
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "architecture.md"
BEGIN, END = "<!-- modules:begin -->", "<!-- modules:end -->"


def modules() -> list[Path]:
    """Every Python module of the two packages, relative to the repository root, sorted."""
    found = (p for pkg in ("factors", "ilcc_graph") for p in (ROOT / pkg).rglob("*.py"))
    return sorted(p.relative_to(ROOT) for p in found)


def summary(path: Path) -> str:
    """The first line of a module's docstring ('' without one)."""
    doc = ast.get_docstring(ast.parse((ROOT / path).read_text(encoding="utf-8"))) or ""
    return doc.strip().splitlines()[0] if doc.strip() else ""


#: the orchestration's packages (issue 34: together fewer lines than the 9.7k they had when it was filed)
ORCHESTRATION = ("ilcc_graph/run/", "ilcc_graph/app/", "ilcc_graph/report/")


def table() -> str:
    """The module table, then the lines per package and the orchestration's total."""
    rows = ["| module | lines | what it is |", "|---|---|---|"]
    per: dict[str, int] = {}
    for p in modules():
        n = len((ROOT / p).read_text(encoding="utf-8").splitlines())
        rows.append(f"| `{p.as_posix()}` | {n} | {summary(p).replace('|', '/')} |")
        package = "/".join(p.parts[:2]) + "/" if len(p.parts) > 2 else f"{p.parts[0]}/*.py"
        per[package] = per.get(package, 0) + n
    rows += ["", "| package | lines |", "|---|---|"] + [f"| `{k}` | {v} |" for k, v in sorted(per.items())]
    n = sum(v for k, v in per.items() if k in ORCHESTRATION)
    rows += ["", f"The orchestration (`run/`, `app/`, `report/`): {n:,} lines (issue 34: fewer than 9,700)."]
    return "\n".join(rows)


def main() -> int:
    text = DOC.read_text(encoding="utf-8")
    if BEGIN not in text or END not in text:
        print(f"{DOC}: no {BEGIN} ... {END} markers", file=sys.stderr)
        return 2
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    DOC.write_text(f"{head}{BEGIN}\n{table()}\n{END}{tail}", encoding="utf-8")
    print(f"wrote {len(modules())} modules into {DOC.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
