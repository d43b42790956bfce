"""What the table reads of a run's files, checked: the types and ranges of the fields of its
``config.json``, ``summary.json`` and ``eval.json`` that the table computes with."""

from __future__ import annotations

from dockingrl.io import FieldRule, first_bad_field, is_count, is_finite_number
from dockingrl.scenarios import SCENARIOS


def _stats(v) -> bool:
    """``{"n", "mean", "std"}`` over ``n`` episodes (mean and std None over none)."""
    if not isinstance(v, dict) or not is_count(v.get("n")):
        return False
    if v["n"] == 0:
        return all(v.get(k) is None or is_finite_number(v.get(k)) for k in ("mean", "std"))
    return is_finite_number(v.get("mean")) and is_finite_number(v.get("std")) and v["std"] >= 0


_STATS = "{n, mean, std} with n an integer >= 0, mean and std finite"

#: per file, each field the table reads and what it must be
_FIELDS: dict[str, dict[str, FieldRule]] = {
    "config": {
        "algo": ("a name", lambda v: isinstance(v, str) and v != ""),
        "scenario": (f"one of {', '.join(SCENARIOS)}", lambda v: v in SCENARIOS),
        "seed": ("an integer >= 0", is_count),
    },
    "summary": {
        "frames": ("an integer >= 0", is_count),
        "train_wall_clock_s": ("a finite number >= 0", lambda v: is_finite_number(v) and v >= 0),
    },
    "eval": {
        "episodes": ("an integer >= 1", lambda v: is_count(v, 1)),
        "success_rate": ("a number in [0, 100]", lambda v: is_finite_number(v) and 0 <= v <= 100),
        "time_s": (_STATS, _stats),
        "total_reward": (_STATS, _stats),
        "time_success_s": (_STATS, lambda v: v is None or _stats(v)),
    },
}


def field_problem(name: str, value: dict) -> str:
    """The first field of the run file ``name`` (``config``, ``summary``, ``eval``) that is
    not what a run writes, as ``"seed must be an integer >= 0 (got '1')"``; "" if none."""
    return first_bad_field(_FIELDS[name], value)
