"""The layout the project aims for: every module listed in docs/architecture.md, none oversized."""

from __future__ import annotations

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
