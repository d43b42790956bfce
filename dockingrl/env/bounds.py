"""The accepted values of a config number: :class:`Bound`, and the check every field of
:class:`~dockingrl.env.DockingConfig` passes (its type, finite, within its bound)."""

from __future__ import annotations

import math
import numbers
from typing import NamedTuple

#: the largest seed a user gives (``--seed``, a config's ``seed``): every seed derived from it
#: (evaluation episodes, the realism draws) still fits the envs' 64-bit generators
MAX_SEED = 2**32 - 1
#: the most envs or evaluation episodes one batch may hold (``--episodes``, a config's
#: ``num_envs`` and ``*_episodes``): an evaluation's episode takes about 1 kB of memory, a
#: training env more (its rollout), so a mistyped count is refused rather than met by the
#: kernel's out-of-memory killer
MAX_BATCH = 1_000_000


def is_real(value) -> bool:
    """Whether ``value`` is a real number (a bool is not)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


class Bound(NamedTuple):
    """The physically sensible values of one config number: ``low`` to ``high`` (``low``
    itself excluded when ``open_low``), in ``unit``, for the reason ``why``."""

    low: float
    high: float
    unit: str
    why: str = ""
    open_low: bool = False

    def holds(self, value: float) -> bool:
        return (self.low < value if self.open_low else self.low <= value) and value <= self.high

    def describe(self) -> str:
        interval = f"{'(' if self.open_low else '['}{self.low:g}, {self.high:g}]"
        unit = f" {self.unit}" if self.unit else ""
        return f"must lie in {interval}{unit}" + (f": {self.why}" if self.why else "")


def field_problem(kind: str, value, bound: Bound | None) -> str:
    """Why ``value`` may not be a config field of annotation ``kind`` (``"bool"``, ``"int"``,
    ``"float"``, ``"str"`` or a ``"tuple..."`` pair) and accepted range ``bound``; ``""`` when it
    may (a string's accepted values are its field's own check)."""
    if kind == "str":
        return "" if isinstance(value, str) else "must be a string"
    if kind == "bool":
        if not isinstance(value, bool):
            return "must be True or False"
    elif kind == "int":
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            return "must be an integer"
    elif kind.startswith("tuple"):
        if not (isinstance(value, tuple) and len(value) == 2 and all(map(is_real, value))):
            return "must be a (low, high) tuple of two numbers"
    elif not is_real(value):
        return "must be a number"
    values = value if isinstance(value, tuple) else (value,)
    if not all(math.isfinite(v) for v in values):
        return "must be finite"
    if bound is not None and not all(bound.holds(v) for v in values):
        return ("each entry " if isinstance(value, tuple) else "") + bound.describe()
    return ""
