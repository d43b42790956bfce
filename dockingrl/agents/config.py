"""Typed training configurations, composed of field groups, each with its checks:
:class:`~dockingrl.agents.world_options.WorldOptions` (the env and its training draws),
:class:`~dockingrl.agents.reward_shaping.RewardShaping`,
:class:`~dockingrl.agents.network_options.NetworkOptions`,
:class:`~dockingrl.agents.run_options.RunOptions` (steps, evaluations, checkpoints, logging),
and each algorithm's own (:mod:`~dockingrl.agents.off_policy_options`,
:mod:`~dockingrl.agents.ppo_options`); this module keeps the checks that need two groups, the
presets and the parsing. The defaults of each algorithm are the paper's ``paper`` preset
(Tables 3-5); ``fast`` presets use vectorised collection for a 2-core CPU. Every field is a
command-line option of ``dockingrl train`` / ``train/train.py`` (``--help`` lists them with the
doc below)."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any, get_type_hints

from dockingrl.agents.network_options import MIRROR_SYMMETRIC, NetworkOptions
from dockingrl.agents.off_policy_options import OffPolicyOptions, SACOptions, TD3Options
from dockingrl.agents.option_fields import LR_SCHEDULES, documented, refuse
from dockingrl.agents.ppo_options import ACTIVATIONS, PPOOptions
from dockingrl.agents.reward_shaping import RewardShaping
from dockingrl.agents.run_options import LOGGERS, RunOptions
from dockingrl.agents.world_options import WorldOptions, curriculum_levels

__all__ = [
    "ACTIVATIONS",
    "CONFIGS",
    "CONFIG_FIELDS",
    "LOGGERS",
    "LR_SCHEDULES",
    "MIRROR_SYMMETRIC",
    "PRESETS",
    "OffPolicyConfig",
    "PPOConfig",
    "SACConfig",
    "TD3Config",
    "TrainConfig",
    "add_config_arguments",
    "check_types",
    "config_from_args",
    "make_config",
    "overrides_from_args",
    "parse_overrides",
    "saved_fields",
]

#: config fields that are not command-line options: the algorithm is chosen by ``--algo`` or the
#: recipe, and the recipe's name by ``--recipe``
_NOT_OPTIONS = frozenset({"algo", "recipe"})

#: the groups every config is composed of
TRAIN_GROUPS = (RunOptions, WorldOptions, RewardShaping, NetworkOptions)


@dataclass
class TrainConfig(*TRAIN_GROUPS):
    """What every training run shares: its world, reward shaping, networks and run."""

    algo: str = ""  # set by the subclasses
    recipe: str = ""  # the name of the recipe the config was made from (dockingrl.recipes)

    def validate(self) -> None:
        """Refuse a field out of its range, or fields that cannot train together (a one-line
        ``ValueError`` naming the field and its value). A config is checked once: validating
        it again while its fields hold the values it was checked with does nothing."""
        values = tuple(getattr(self, f.name) for f in fields(self))
        if self.__dict__.get("_checked") == values:
            return
        self._check_config()
        self.__dict__["_checked"] = values

    def _check_config(self) -> None:
        """The checks of :meth:`validate`; each config class extends them."""
        options = {f.name: getattr(self, f.name) for f in fields(self)}
        check_types(self.algo, {k: v for k, v in options.items() if k not in _NOT_OPTIONS})
        for name, value in options.items():
            if isinstance(value, float) and not (value == value and abs(value) != float("inf")):
                refuse(self, name, "must be finite")
        self._check_world()
        self._check_run()
        self._check_reward()
        self._check_network()
        self._check_curriculum()
        if self.compile and self.estimate_current:
            refuse(self, "compile", "not with estimate_current (its filter does not compile)")

    def collected_transitions(self) -> int:
        """The transitions of one collected batch (all envs; each ``action_repeat`` env
        steps)."""
        raise NotImplementedError(f"{type(self).__name__} has no batch")

    def _check_curriculum(self) -> None:
        """Refuse a ``train_curriculum`` with a stage shorter than one collected batch (it
        would be skipped) or with a time budget (the run could end before ``train_level``)."""
        stages = len(curriculum_levels(self.train_curriculum)) + 1
        if stages == 1:
            return
        batch = self.collected_transitions() * self.action_repeat
        if self.total_steps // stages < batch:
            refuse(
                self,
                "train_curriculum",
                f"{stages} stages of total_steps // {stages} = {self.total_steps // stages} "
                f"env steps, shorter than a collected batch of {batch}",
            )
        if self.time_budget_s > 0:
            refuse(self, "train_curriculum", "not with time_budget_s (it shares out total_steps)")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class OffPolicyConfig(OffPolicyOptions, TrainConfig):
    """What SAC and TD3 share: a replay buffer, soft target updates, the update-to-data
    ratio."""

    def _check_config(self) -> None:
        super()._check_config()
        self._check_off_policy()
        if self.reset_every and self.actor_average:
            refuse(
                self,
                "reset_every",
                "cannot go with actor_average (an average across a reset mixes two networks)",
            )
        name = type(self).__name__
        if self.frames_per_batch < self.num_envs:
            raise ValueError(f"{name}.frames_per_batch: must be >= num_envs")
        per_env = self.collected_transitions() // self.num_envs
        if self.n_steps > per_env:
            raise ValueError(
                f"{name}.n_steps: at most the transitions per env of one collection, "
                f"frames_per_batch // action_repeat // num_envs = {per_env} "
                f"(got {self.n_steps})"
            )

    def collected_transitions(self) -> int:
        """``frames_per_batch`` env steps, in whole transitions of every env (one at least)."""
        per_env = self.frames_per_batch // self.action_repeat // self.num_envs
        return max(self.num_envs, per_env * self.num_envs)


@dataclass
class SACConfig(SACOptions, OffPolicyConfig):
    """SAC, Table 3."""

    algo: str = "sac"

    def _check_config(self) -> None:
        super()._check_config()
        if self.privileged_critic and self.mirror_symmetric == "all":
            refuse(
                self,
                "mirror_symmetric",
                "'all' not with privileged_critic (its features are not mirrored)",
            )
        if self.privileged_critic and self.mirror_augment:
            raise ValueError(
                f"{type(self).__name__}.mirror_augment: not with privileged_critic (its "
                "features are not mirrored)"
            )


@dataclass
class TD3Config(TD3Options, OffPolicyConfig):
    """TD3, Table 4."""

    algo: str = "td3"
    total_steps: int = documented(
        "env steps (frames) to train for, all envs counted", default=2_500_000
    )
    eval_every: int = documented("env steps between periodic evaluations", default=50_000)
    hidden: tuple[int, ...] = documented(
        "hidden layer sizes of actor and critic", default=(400, 300)
    )
    lr: float = documented("Adam learning rate, actor and critics", default=5e-4)
    start_steps: int = documented(
        "uniformly random env steps before learning (learning_starts)", default=100
    )

    def _check_config(self) -> None:
        super()._check_config()
        self._check_td3()


@dataclass
class PPOConfig(PPOOptions, TrainConfig):
    """PPO, Table 5 (stable-baselines3 defaults otherwise)."""

    algo: str = "ppo"
    total_steps: int = documented(
        "env steps (frames) to train for, all envs counted", default=2_500_000
    )
    eval_every: int = documented("env steps between periodic evaluations", default=50_000)

    def _check_config(self) -> None:
        super()._check_config()
        self._check_ppo()
        frames = self.steps_per_env * self.num_envs
        if not 1 <= self.minibatch_size <= frames:
            raise ValueError(
                f"PPOConfig.minibatch_size: must be in [1, num_envs * steps_per_env = {frames}] "
                f"(got {self.minibatch_size})"
            )

    def collected_transitions(self) -> int:
        """A rollout: ``steps_per_env`` transitions of every env."""
        return self.num_envs * self.steps_per_env


CONFIGS = {"sac": SACConfig, "td3": TD3Config, "ppo": PPOConfig}

#: Presets beyond the paper's: vectorised collection sized for a 2-core CPU, and the
#: contact-speed penalty (``docs/fidelity.md``: the paper's reward alone teaches too-fast
#: entries) plus, for PPO, rewards scaled by 0.1 inside the value loss.
PRESETS: dict[str, dict[str, dict[str, Any]]] = {
    "paper": {"sac": {}, "td3": {}, "ppo": {}},
    "fast": {
        "sac": {
            "num_envs": 16,
            "updates_per_step": 0.5,
            "frames_per_batch": 1_000,
            "normalize_observation": True,
            "contact_speed_penalty": 2000.0,
        },
        "td3": {
            "num_envs": 16,
            "updates_per_step": 0.5,
            "frames_per_batch": 1_000,
            "normalize_observation": True,
            "contact_speed_penalty": 2000.0,
            "total_steps": 1_000_000,
        },
        "ppo": {
            "num_envs": 256,
            "steps_per_env": 64,
            "minibatch_size": 2048,
            "epochs": 10,
            "lr": 3e-4,
            "normalize_observation": True,
            "reward_scale": 0.1,
            "contact_speed_penalty": 2000.0,
            "total_steps": 4_200_000,
        },
    },
}


def config_class(algo: str) -> type[TrainConfig]:
    """The config class of ``algo``; a one-line ``ValueError`` for an unknown algorithm."""
    if algo not in CONFIGS:
        raise ValueError(f"unknown algorithm {algo!r}; valid: {', '.join(CONFIGS)}")
    return CONFIGS[algo]


def option_names(algo: str) -> frozenset[str]:
    """The fields of ``algo``'s config that a user sets (all but ``algo`` and ``recipe``)."""
    return frozenset(f.name for f in fields(config_class(algo))) - _NOT_OPTIONS


def unknown_options(algo: str, names) -> list[str]:
    """The names among ``names`` that are no option of ``algo``'s config (:func:`option_names`,
    the one list of them), sorted."""
    return sorted(set(names) - option_names(algo))


def make_config(algo: str, preset: str = "paper", **overrides) -> TrainConfig:
    """The config of ``algo`` from a preset, with field overrides, validated."""
    cls = config_class(algo)
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; valid: {', '.join(PRESETS)}")
    unknown = unknown_options(algo, overrides)
    if unknown:
        raise ValueError(f"unknown {algo} option(s): {', '.join(unknown)}")
    cfg = cls(**{**PRESETS[preset][algo], **overrides})
    cfg.validate()
    return cfg


def check_types(algo: str, values: dict[str, Any]) -> None:
    """Refuse (``ValueError``, one line) a field of ``algo``'s config that is unknown or whose
    value has the wrong type: booleans for bool fields, integers for int fields, numbers for
    float fields, strings for str fields, a list of integers for ``hidden``."""
    hints, known = get_type_hints(config_class(algo)), option_names(algo)
    for name, value in values.items():
        if name not in known:
            raise ValueError(f"unknown {algo} option {name!r}")
        kind = hints[name]
        if kind is bool:
            ok = isinstance(value, bool)
        elif kind is int:
            ok = isinstance(value, int) and not isinstance(value, bool)
        elif kind is float:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        elif kind is str:
            ok = isinstance(value, str)
        else:  # tuple[int, ...]
            ok = isinstance(value, (list, tuple)) and all(
                isinstance(v, int) and not isinstance(v, bool) for v in value
            )
        if not ok:
            raise ValueError(f"{algo} option {name}: expected {kind}, got {value!r}")


def saved_fields(algo: str, saved: dict[str, Any]) -> dict[str, Any]:
    """The fields of an ``algo`` config saved as a dict (a run's ``config.json``, a policy
    file's ``config``) as the config takes them: type-checked (:func:`check_types`, ``algo``
    and ``recipe`` aside) and ``hidden`` a tuple. Raises ``ValueError`` (one line)."""
    check_types(algo, {k: v for k, v in saved.items() if k not in _NOT_OPTIONS})
    return {k: (tuple(v) if k == "hidden" else v) for k, v in saved.items()}


def parse_overrides(algo: str, items: Sequence[str]) -> dict[str, Any]:
    """``FIELD=VALUE`` strings to typed overrides of ``algo``'s config (``true``/``false``
    for booleans, comma-separated integers for ``hidden``); raises ``ValueError`` on an
    unknown field or a value of the wrong type."""
    hints, known = get_type_hints(config_class(algo)), option_names(algo)
    booleans = {"true": True, "1": True, "false": False, "0": False}
    overrides: dict[str, Any] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or name not in known:
            raise ValueError(f"{item!r}: not FIELD=VALUE with a field of the {algo} config")
        kind = hints[name]
        try:
            if kind is bool:
                if value.lower() not in booleans:
                    raise ValueError(f"expected true or false, got {value!r}")
                overrides[name] = booleans[value.lower()]
            elif kind == tuple[int, ...]:
                overrides[name] = tuple(int(v) for v in value.split(","))
            else:
                overrides[name] = kind(value)
        except ValueError as exc:
            raise ValueError(f"{item!r}: {exc}") from exc
    return overrides


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    """One ``--option`` per field of every algorithm's config (documented in ``--help``); the
    value ``None`` means "keep the preset's"."""
    seen: dict[str, str] = {}
    group = parser.add_argument_group("config fields (defaults: the chosen preset)")
    for algo, cls in CONFIGS.items():
        hints = get_type_hints(cls)
        for f in fields(cls):
            if f.name in _NOT_OPTIONS:
                continue
            if f.name in seen:
                continue
            seen[f.name] = algo
            flag = "--" + f.name.replace("_", "-")
            doc = f.metadata.get("doc", "")
            owners = [a for a, c in CONFIGS.items() if f.name in {x.name for x in fields(c)}]
            default = {a: getattr(CONFIGS[a](), f.name) for a in owners}
            doc += (
                f" [{', '.join(owners)}; paper: "
                + ", ".join(f"{a}={v}" for a, v in default.items())
                + "]"
            )
            kind = hints[f.name]
            if kind is bool:
                group.add_argument(
                    flag, dest=f.name, default=None, action=argparse.BooleanOptionalAction, help=doc
                )
            elif kind == tuple[int, ...]:
                group.add_argument(flag, dest=f.name, default=None, type=int, nargs="+", help=doc)
            else:
                group.add_argument(flag, dest=f.name, default=None, type=kind, help=doc)


#: every config field that has a command-line option (of any algorithm)
CONFIG_FIELDS = frozenset(f.name for cls in CONFIGS.values() for f in fields(cls)) - _NOT_OPTIONS


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The config fields given on the command line (``--FIELD VALUE``) for ``args.algo``;
    ``ValueError`` for a field that does not apply to that algorithm."""
    overrides, known = {}, option_names(args.algo)
    for name, value in vars(args).items():
        if value is None or name not in CONFIG_FIELDS:
            continue
        if name not in known:
            raise ValueError(f"--{name.replace('_', '-')} does not apply to {args.algo}")
        overrides[name] = tuple(value) if isinstance(value, list) else value
    return overrides


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """The config of ``args.algo`` from ``args.preset`` and the fields on the command line."""
    return make_config(args.algo, args.preset or "paper", **overrides_from_args(args))
