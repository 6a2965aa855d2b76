"""Every module of the package has a file name of its own (issue 23: "clear, unique names"): a name
seen in a traceback, an import or a review says which module it is without its folder."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# names still used twice while their modules move (the test fails when one listed is no longer
# used twice: then delete it here); none now (issue 34 renamed the rig's three rig.py)
PENDING: set[str] = set()


def duplicates() -> dict[str, list[str]]:
    """File names used by more than one module of ilcc_graph/ and factors/ (``__init__.py`` aside)."""
    where: dict[str, list[str]] = defaultdict(list)
    for pkg in ("ilcc_graph", "factors"):
        for p in sorted((ROOT / pkg).rglob("*.py")):
            if p.name != "__init__.py":
                where[p.name].append(p.relative_to(ROOT).as_posix())
    return {name: paths for name, paths in where.items() if len(paths) > 1}


def test_module_file_names_are_unique() -> None:
    twice = {name: paths for name, paths in duplicates().items() if name not in PENDING}
    assert not twice, f"file names used by more than one module (rename one): {twice}"


def test_the_pending_names_are_still_pending() -> None:
    stale = sorted(PENDING - set(duplicates()))
    assert not stale, f"no longer used twice: remove {stale} from PENDING in this test"
