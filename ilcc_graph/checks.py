"""Checks of configuration values with messages ``<file>: <key> = <value>: expected <what>``.

Shared by ``config/`` and the sections it hands to other modules (``cameras/``): every failure
is an ``InputError`` naming the file, the key path (``camera.K``), the value found and what was
expected.
"""

from __future__ import annotations

import math
from typing import Any, Literal, overload

import numpy as np

from .errors import InputError, quote

__all__ = ["MISSING", "Checker"]

#: A key that is absent (shown as ``missing`` in messages).
MISSING: Any = object()


class Checker:
    """Builds and raises ``InputError`` for one configuration file (``source``)."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, value: Any, expected: str) -> InputError:
        shown = "missing" if value is MISSING else quote(value)
        return InputError(f"{self.source}: {key} = {shown}: expected {expected}")

    def section(self, d: Any, key: str) -> dict:
        if d is MISSING:
            raise self.fail(key, d, "a mapping (section)")
        if not isinstance(d, dict):
            raise self.fail(key, d, "a mapping (section)")
        return d

    def unknown(self, d: dict, allowed: tuple[str, ...] | set[str], prefix: str) -> None:
        for k in d:
            if k not in allowed:
                path = f"{prefix}.{k}" if prefix else str(k)
                raise self.fail(path, d[k], f"no such key; allowed keys here: {sorted(allowed)}")

    @overload
    def number(
        self, v: Any, key: str, lo: float | None = None, hi: float | None = None,
        integer: Literal[False] = False, lo_open: bool = False,
    ) -> float: ...
    @overload
    def number(
        self, v: Any, key: str, lo: float | None = None, hi: float | None = None, *,
        integer: Literal[True], lo_open: bool = False,
    ) -> int: ...
    def number(
        self,
        v: Any,
        key: str,
        lo: float | None = None,
        hi: float | None = None,
        integer: bool = False,
        lo_open: bool = False,
    ) -> float:
        """``v`` checked to be a finite number in the range (an int with ``integer``); the error
        naming ``key`` otherwise."""
        what = "an integer" if integer else "a number"
        rng = ""
        if lo is not None or hi is not None:
            lb = "(" if lo_open else "["
            rng = f" in {lb}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise self.fail(key, v, what + rng)
        if integer and not float(v).is_integer():
            raise self.fail(key, v, what + rng)
        x = float(v)
        if not math.isfinite(x):
            raise self.fail(key, v, "a finite " + what[2:] + rng)
        if (lo is not None and (x < lo or (lo_open and x == lo))) or (hi is not None and x > hi):
            raise self.fail(key, v, what + rng)
        return int(x) if integer else x

    def numbers(self, v: Any, key: str, n: int | tuple[int, ...] | None, **kw: Any) -> list[float]:
        sizes = (n,) if isinstance(n, int) else n
        count = "" if sizes is None else f" of {' or '.join(map(str, sizes))}"
        if not isinstance(v, (list, tuple)) or (sizes is not None and len(v) not in sizes):
            raise self.fail(key, v, f"a list{count} numbers")
        return [self.number(x, f"{key}[{i}]", **kw) for i, x in enumerate(v)]

    def choice(self, v: Any, key: str, options: tuple[str, ...]) -> str:
        if not isinstance(v, str) or v.lower() not in options:
            raise self.fail(key, v, f"one of {list(options)}")
        return v.lower()

    def interval(self, v: Any, key: str, lo: float, hi: float, wrap: bool = False) -> tuple[float, float]:
        a, b = self.numbers(v, key, 2, lo=lo, hi=hi)
        if a == b or (a > b and not wrap):
            extra = " (min > max wraps through +-180)" if wrap else ""
            raise self.fail(key, v, f"[min, max] with min < max{extra}")
        return (a, b)
