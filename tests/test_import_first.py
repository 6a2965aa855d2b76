"""Every module of the orchestration imports first in a fresh interpreter: an import cycle that only
bites when a module is the first imported (``run.after`` from a script that imports ``run.pipeline``
first, say) fails here, whatever order the rest of the suite imports them in."""

from __future__ import annotations

import json
import os
import subprocess
import sys
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


#: Imports every module given (argv[1], JSON; one that fails is left to the forked children to name),
#: then prints, as JSON, the modules that are not the package's, in the order they were imported.
_OTHERS = r"""
import importlib, json, sys
for name in json.loads(sys.argv[1]):
    try:
        importlib.import_module(name)
    except Exception:
        pass
print(json.dumps([m for m in sys.modules if m.split(".")[0] not in ("ilcc_graph", "factors", "__main__")]))
"""

#: Loads the other modules (argv[2]) once, then imports each of the package's modules (argv[1]) in a
#: child forked from that state, where none of the package is loaded yet; prints {module: error}.
_FIRST = r"""
import importlib, json, os, sys, traceback
for name in json.loads(sys.argv[2]):
    try:
        importlib.import_module(name)
    except Exception:  # a module that loads only inside its own package's import: the child loads it
        pass
assert not [m for m in sys.modules if m.split(".")[0] in ("ilcc_graph", "factors")]
failed = {}
for module in json.loads(sys.argv[1]):
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        code = 0
        try:
            importlib.import_module(module)
        except BaseException:
            os.write(w, traceback.format_exc()[-600:].encode())
            code = 1
        os._exit(code)
    os.close(w)
    with os.fdopen(r, "rb") as fh:
        err = fh.read().decode()
    if os.waitpid(pid, 0)[1]:
        failed[module] = err or "the child died"
print(json.dumps(failed))
"""


def test_each_module_imports_first() -> None:
    """Each module is the first of the package imported into an interpreter: a child forked from one
    that has loaded only the other libraries the package uses (numpy, gtsam, OpenCV, ...), so no
    module of the package is loaded before it and the libraries load once, not once per module."""
    names = _modules()
    modules = json.dumps(names)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    others = subprocess.run([sys.executable, "-c", _OTHERS, modules], cwd=ROOT, capture_output=True,
                            text=True, env=env, timeout=300)  # fmt: skip
    assert others.returncode == 0, others.stderr[-2000:]
    done = subprocess.run([sys.executable, "-c", _FIRST, modules, others.stdout], cwd=ROOT,
                          capture_output=True, text=True, env=env, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    failed = json.loads(done.stdout)
    assert len(names) > 40 and not failed, failed


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
