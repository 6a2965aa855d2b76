"""Every module of the orchestration imports first in a fresh interpreter: an import cycle that only
bites when a module is the first imported (``run.after`` from a script that imports ``run.pipeline``
first, say) fails here, whatever order the rest of the suite imports them in."""

from __future__ import annotations

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FLOORS = ("run", "app")  # the orchestration, where the modules import one another


def _modules() -> list[str]:
    out = []
    for floor in FLOORS:
        for path in sorted((ROOT / "ilcc_graph" / floor).rglob("*.py")):
            if path.stem == "__main__":  # runs the command line
                continue
            parts = path.relative_to(ROOT).with_suffix("").parts
            out.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return out


def _first(module: str) -> tuple[str, int, str]:
    argv = [sys.executable, "-c", f"import {module}"]
    done = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True)
    return module, done.returncode, done.stderr[-600:]


def test_each_module_imports_first() -> None:
    with ThreadPoolExecutor(max_workers=4) as pool:
        failed = [(m, err) for m, rc, err in pool.map(_first, _modules()) if rc != 0]
    assert not failed, failed
