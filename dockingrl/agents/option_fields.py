"""What the field groups of the training config share: a field with its ``--help`` text, and
the one-line refusal of a field's value."""

from __future__ import annotations

from dataclasses import field
from typing import Any

#: the learning-rate schedules of ``lr_schedule``
LR_SCHEDULES = ("constant", "linear", "late-linear")


def documented(text: str, **kwargs) -> Any:
    """A config field whose ``text`` is its command-line option's help."""
    return field(metadata={"doc": text}, **kwargs)


def env_field(name: str) -> Any:
    """A training config's field that is the env's :class:`~dockingrl.env.DockingConfig` field
    ``name`` (a :func:`~dockingrl.env.task_options.training_draw`): its default and ``--help``
    text are the env's, declared there once."""
    from dockingrl.env.task_options import TaskOptions

    declared = TaskOptions.__dataclass_fields__[name]
    return field(default=declared.default, metadata=declared.metadata)


def lr_schedule_field() -> Any:
    """The ``lr_schedule`` field every algorithm has."""
    return documented(
        "constant; linear: the learning rate falls linearly to 0 at total_steps; late-linear: "
        "it holds over the first half of total_steps, then falls linearly to 0 at "
        "total_steps (not in the paper)",
        default="constant",
    )


def check_lr_schedule(cfg) -> None:
    """Refuse an ``lr_schedule`` that is not one of :data:`LR_SCHEDULES`."""
    if cfg.lr_schedule not in LR_SCHEDULES:
        refuse(cfg, "lr_schedule", f"valid: {', '.join(LR_SCHEDULES)}")


def refuse(cfg, name: str, why: str) -> None:
    """Raise the ``ValueError`` that names ``cfg``'s class, the field ``name``, ``why`` and
    the value."""
    raise ValueError(f"{type(cfg).__name__}.{name}: {why} (got {getattr(cfg, name)!r})")


def check_ranges(
    cfg, counts=(), positive=(), unit=(), fraction=(), non_negative=(), flags=()
) -> None:
    """Refuse, naming the field and its value: ``counts`` below 1, ``positive`` fields not
    > 0, ``unit`` fields outside (0, 1], ``fraction`` fields outside [0, 1], ``non_negative``
    ones below 0, ``flags`` that are not ``True`` or ``False``."""
    for names, ok, text in (
        (flags, lambda v: isinstance(v, bool), "must be true or false"),
        (counts, lambda v: v >= 1, "must be >= 1"),
        (positive, lambda v: v > 0, "must be > 0"),
        (unit, lambda v: 0 < v <= 1, "must lie in (0, 1]"),
        (fraction, lambda v: 0 <= v <= 1, "must lie in [0, 1]"),
        (non_negative, lambda v: v >= 0, "must be >= 0"),
    ):
        for field_name in names:
            if not ok(getattr(cfg, field_name)):
                refuse(cfg, field_name, text)
