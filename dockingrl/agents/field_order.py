"""The order of a training config's fields: the order of a ``config.json``'s keys and of
``--help``'s options, and the dataclass that imposes it on a config composed of field
groups."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import field, fields

#: the order of :class:`TrainConfig`'s group fields: the order of a config.json's keys and of
#: ``--help``'s options, which predates the groups (each field came where it fitted then)
TRAIN_FIELDS = (
    "scenario",
    "total_steps",
    "num_envs",
    "seed",
    "eval_every",
    "eval_episodes",
    "final_eval_episodes",
    "checkpoint_every",
    "logger",
    "wandb_online",
    "out",
    "run_name",
    "threads",
    "device",
    "compile",
    "compile_update",
    "normalize_observation",
    "hidden",
    "range_noise_scale",
    "bearing_noise_scale",
    "filter_params",
    "contact_speed_penalty",
    "contact_speed_target",
    "success_bonus",
    "contact_speed_penalty_cap",
    "following_current_fraction",
    "lateral_current_fraction",
    "near_start_fraction",
    "train_level",
    "train_curriculum",
    "miss_penalty_floor",
    "passed_station_penalty",
    "time_budget_s",
    "keep_best",
    "keep_candidates",
    "select_episodes",
    "actor_average",
    "observe_current",
    "observe_command",
    "observe_filter_std",
    "mirror_symmetric",
    "action_repeat",
    "fast_update",
    "compensate_latency",
    "estimate_current",
    "filter_gate",
    "init_from",
    "init_replay",
)


def in_order(names: Sequence[str], groups: Sequence[type]) -> type:
    """A dataclass holding the fields of ``groups`` in the order ``names``. A dataclass's
    fields come in the order of its bases' fields, the last base's first, and keep their place
    when a later base declares them again: composed of ``groups`` and then this one (last), a
    config lists the groups' fields in ``names``' order."""
    by_name = {f.name: f for group in groups for f in fields(group)}
    if sorted(names) != sorted(by_name):
        missing, extra = sorted(set(by_name) - set(names)), sorted(set(names) - set(by_name))
        raise TypeError(f"field order: fields not listed {missing}, listed but in no group {extra}")
    copies = [
        (
            f.name,
            f.type,
            field(default=f.default, default_factory=f.default_factory, metadata=f.metadata),
        )
        for f in (by_name[n] for n in names)
    ]
    return dataclasses.make_dataclass("FieldOrder", copies, namespace={"__module__": __name__})
