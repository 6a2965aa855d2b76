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


def test_no_module_of_the_package_imports_scipy_stats() -> None:
    """``scipy.stats`` takes most of a second to import, paid by every process of a run (the command,
    each worker): no module of the package imports it (chi-square figures come from
    ``scipy.special``: ``estimation.chi2``, ``lidar.outline.shape_gate``). Names the first module
    that does."""
    code = (
        "import importlib, pkgutil, sys\n"
        "import factors, ilcc_graph\n"
        "names = [i.name for p in (ilcc_graph, factors)\n"
        "         for i in pkgutil.walk_packages(p.__path__, p.__name__ + '.')\n"
        "         if not i.name.endswith('__main__')]\n"
        "first = next((m for m in names\n"
        "              if importlib.import_module(m) and 'scipy.stats' in sys.modules), '')\n"
        "print(len(names), first)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    count, first = (run.stdout.split() + [""])[:2]
    assert int(count) > 200 and first == "", f"{first} imports scipy.stats"
