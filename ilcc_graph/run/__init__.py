"""The orchestration: a source opened, observed once, solved by the strategy of its mode, finished.

``run(sources, options) -> Result`` (``pipeline.py``); ``RunOptions``, ``Result``, ``SessionResult``
(``result.py``); the strategies by mode (``strategies/``); ``check`` while capturing (``live.py``);
``evaluate_on`` (``evaluate.py``). The names below are imported when first used, so that a worker
process that runs a per-frame stage (``stages.py``) does not import the estimation core.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["Observation", "Result", "RunOptions", "SessionResult", "StageOptions", "calibrate", "run",
           "solve_observations", "solve_observed"]  # fmt: skip

_WHERE = {
    "Observation": "observe",
    "StageOptions": "stages",
    "Result": "result",
    "RunOptions": "result",
    "SessionResult": "result",
    "calibrate": "pipeline",
    "run": "pipeline",
    "solve_observations": "pipeline",
    "solve_observed": "pipeline",
}


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
