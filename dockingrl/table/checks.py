"""What the table reads of a run's files, checked: the types and ranges of the fields of its
``config.json``, ``summary.json`` and ``eval.json`` that the table computes with."""

from __future__ import annotations

import math

from dockingrl.scenarios import SCENARIOS


def _count(v, least: int = 0) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= least


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _stats(v) -> bool:
    """``{"n", "mean", "std"}`` over ``n`` episodes (mean and std None over none)."""
    if not isinstance(v, dict) or not _count(v.get("n")):
        return False
    if v["n"] == 0:
        return all(v.get(k) is None or _number(v.get(k)) for k in ("mean", "std"))
    return _number(v.get("mean")) and _number(v.get("std")) and v["std"] >= 0


_STATS = "{n, mean, std} with n an integer >= 0, mean and std finite"

#: per file, each field the table reads and what it must be
_FIELDS = {
    "config": {
        "algo": ("a name", lambda v: isinstance(v, str) and v != ""),
        "scenario": (f"one of {', '.join(SCENARIOS)}", lambda v: v in SCENARIOS),
        "seed": ("an integer >= 0", _count),
    },
    "summary": {
        "frames": ("an integer >= 0", _count),
        "train_wall_clock_s": ("a finite number >= 0", lambda v: _number(v) and v >= 0),
    },
    "eval": {
        "episodes": ("an integer >= 1", lambda v: _count(v, 1)),
        "success_rate": ("a number in [0, 100]", lambda v: _number(v) and 0 <= v <= 100),
        "time_s": (_STATS, _stats),
        "total_reward": (_STATS, _stats),
        "time_success_s": (_STATS, lambda v: v is None or _stats(v)),
    },
}


def field_problem(name: str, value: dict) -> str:
    """The first field of the run file ``name`` (``config``, ``summary``, ``eval``) that is
    not what a run writes, as ``"seed must be an integer >= 0 (got '1')"``; "" if none."""
    for key, (what, ok) in _FIELDS[name].items():
        if key in value and not ok(value[key]):
            return f"{key} must be {what} (got {value[key]!r})"
    return ""
