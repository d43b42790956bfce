"""Typed training configurations. The defaults of each algorithm are the paper's ``paper``
preset (Tables 3-5); ``fast`` presets use vectorised collection for a 2-core CPU. Every field
is a command-line option of ``dockingrl train`` / ``train/train.py`` (``--help`` lists them with
the doc below)."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any, get_type_hints

from dockingrl.env.config import noise_scale_problem
from dockingrl.env.levels import LEVELS
from dockingrl.scenarios import FILTERED_OBSERVATION_KEYS, SCENARIOS

LOGGERS = ("wandb", "csv", "none")
LR_SCHEDULES = ("constant", "linear")
#: hidden-layer activations: option name -> ``torch.nn`` class name
ACTIVATIONS = {"relu": "ReLU", "tanh": "Tanh"}


def _doc(text: str, **kwargs) -> Any:
    return field(metadata={"doc": text}, **kwargs)


def _check_ranges(cfg, counts=(), positive=(), unit=(), fraction=(), non_negative=()) -> None:
    """Refuse, naming the field and its value: ``counts`` below 1, ``positive`` fields not
    > 0, ``unit`` fields outside (0, 1], ``fraction`` fields outside [0, 1], ``non_negative``
    ones below 0."""
    for names, ok, text in (
        (counts, lambda v: v >= 1, "must be >= 1"),
        (positive, lambda v: v > 0, "must be > 0"),
        (unit, lambda v: 0 < v <= 1, "must lie in (0, 1]"),
        (fraction, lambda v: 0 <= v <= 1, "must lie in [0, 1]"),
        (non_negative, lambda v: v >= 0, "must be >= 0"),
    ):
        for field_name in names:
            value = getattr(cfg, field_name)
            if not ok(value):
                raise ValueError(f"{type(cfg).__name__}.{field_name}: {text} (got {value!r})")


#: config fields that are not command-line options: the algorithm is chosen by ``--algo`` or the
#: recipe, and the recipe's name by ``--recipe``
_NOT_OPTIONS = frozenset({"algo", "recipe"})


#: ``mirror_symmetric``: which networks are made mirror-symmetric
MIRROR_SYMMETRIC = ("none", "actor", "all")


@dataclass
class TrainConfig:
    """What every training run shares."""

    scenario: str = _doc("observation scenario", default="compound")
    total_steps: int = _doc("env steps (frames) to train for, all envs counted", default=500_000)
    num_envs: int = _doc("envs stepped in parallel while collecting", default=1)
    seed: int = _doc("seed of networks, exploration and envs", default=0)
    eval_every: int = _doc("env steps between periodic evaluations", default=10_000)
    eval_episodes: int = _doc("episodes of each periodic evaluation (paper: 10)", default=10)
    final_eval_episodes: int = _doc("episodes of the final evaluation (paper: 500)", default=500)
    checkpoint_every: int = _doc("env steps between checkpoints (0: never)", default=50_000)
    logger: str = _doc("wandb (offline unless --wandb-online), csv or none", default="wandb")
    wandb_online: bool = _doc("let wandb sync to its servers", default=False)
    out: str = _doc("folder that holds the run folders", default="runs")
    run_name: str = _doc(
        "run folder name (default: dockingrl__algo__scenario__seed__time)", default=""
    )
    threads: int = _doc("torch CPU threads", default=2)
    device: str = _doc("torch device", default="cpu")
    compile: bool = _doc("torch.compile the env and filter steps", default=False)
    compile_update: bool = _doc("torch.compile the gradient step (~20 s to compile)", default=False)
    normalize_observation: bool = _doc(
        "scale the range by 1/max_dist inside the networks (not in the paper)", default=False
    )
    hidden: tuple[int, ...] = _doc("hidden layer sizes of actor and critic", default=(256, 256))
    range_noise_scale: float = _doc(
        "env's USBL range noise x this (filter keeps Table 2)", default=1.0
    )
    bearing_noise_scale: float = _doc(
        "env's USBL bearing noise x this (filter keeps Table 2)", default=1.0
    )
    filter_params: str = _doc("learned Q/R file for the EKF (dockingrl learn-filter)", default="")
    contact_speed_penalty: float = _doc(
        "training reward - this x (contact speed - contact_speed_target)+, per m/s "
        "(0: the paper's reward; not in the paper)",
        default=0.0,
    )
    contact_speed_target: float = _doc(
        "ground speed (m/s) above which contact_speed_penalty applies", default=0.27
    )
    success_bonus: float = _doc(
        "training reward + this on a successful contact (0: the paper's reward; not in the paper)",
        default=0.0,
    )
    contact_speed_penalty_cap: bool = _doc(
        "cap the contact-speed penalty at the contact reward 200 max(g, 0), so a too-fast "
        "contact never scores below a miss",
        default=False,
    )
    following_current_fraction: float = _doc(
        "training envs: probability that a reset draws oc_x from [0, 0.3] only (following "
        "currents); evaluation keeps the uniform draw (0: Sec. 4.1; not in the paper)",
        default=0.0,
    )
    lateral_current_fraction: float = _doc(
        "training envs: probability that a reset draws |oc_y| from [0.15, 0.3] only (strong "
        "lateral currents); evaluation keeps the uniform draw (0: Sec. 4.1; not in the paper)",
        default=0.0,
    )
    near_start_fraction: float = _doc(
        "training envs: probability that a reset starts 3-8 m before the station (|y| <= 3 m) "
        "instead of 25-30 m, to practise the final approach; evaluation keeps Sec. 4.1's starts "
        "(0: off; not in the paper)",
        default=0.0,
    )
    train_level: str = _doc(
        "stress-ladder level (L0-L5, docs/realism.md) whose realism options the run's world "
        "takes: its training env and all its evaluations (L0: the paper's task; not in the "
        "paper)",
        default="L0",
    )
    miss_penalty_floor: float = _doc(
        "training reward: a miss (g <= 0) costs at most this on contact instead of 200 |g| "
        "(0: off; not in the paper)",
        default=0.0,
    )
    passed_station_penalty: float = _doc(
        "training envs: an episode ends, with this penalty, when the AUV passes the "
        "station's entrance plane (x > 0) beside the funnel; evaluation keeps the paper's "
        "episodes (0: off; not in the paper)",
        default=0.0,
    )

    time_budget_s: float = _doc(
        "stop once training (periodic evaluations included) has run this many seconds, "
        "before total_steps if need be (0: no limit)",
        default=0.0,
    )
    keep_best: bool = _doc(
        "end with the actor of the best periodic evaluation (its episodes never overlap the "
        "final evaluation's) instead of the last one (not in the paper)",
        default=False,
    )
    keep_candidates: int = _doc(
        "with keep_best: keep the actors of this many best periodic evaluations; with more "
        "than one, each is evaluated again at the end on select_episodes validation episodes "
        "(one set for all of them, never overlapping the periodic or final evaluations' "
        "episodes) and the run ends with the best of them (not in the paper)",
        default=1,
    )
    select_episodes: int = _doc(
        "episodes of the validation that picks among keep_candidates actors", default=500
    )
    actor_average: float = _doc(
        "decay of an exponential moving average of the actor's weights, moved after every "
        "actor step; periodic evaluations, keep_best and the saved policy use the averaged "
        "actor, training explores with the live one (0: off; not in the paper)",
        default=0.0,
    )
    observe_current: bool = _doc(
        "append the ocean current (DS frame) to the policy's observation (not in the paper)",
        default=False,
    )
    observe_command: bool = _doc(
        "append the command applied at the previous step to the policy's observation, "
        "after the current's (zeros at an episode's start; not in the paper)",
        default=False,
    )
    mirror_symmetric: str = _doc(
        "mirror-symmetric networks (not in the paper): 'actor' makes the actor command the "
        "mirrored command in the mirrored situation (y -> -y), exactly, by averaging it over "
        "the observation and its mirror (dockingrl.agents.mirror.MirrorSymmetric); 'all' "
        "the critics too (they value a transition and its mirror alike). A SAC update costs about "
        "1.3x ('actor') and 1.8x ('all') the plain one on a 2-core CPU; 'none' neither",
        default="none",
    )
    action_repeat: int = _doc(
        "hold each action for this many env steps of 0.2 s (1: the paper's; not in the "
        "paper); total_steps, eval_every, start_steps and updates_per_step still count env "
        "steps, one transition per action_repeat of them",
        default=1,
    )
    fast_update: bool = _doc(
        "faster gradient updates that round differently from the default (same arithmetic, "
        "other kernels and order): fused Adam steps, and on a CPU SAC's and TD3's twin critics "
        "as two matrix products each instead of vmap's batched one (not in the paper)",
        default=False,
    )

    algo: str = ""  # set by the subclasses
    recipe: str = ""  # the name of the recipe the config was made from (dockingrl.recipes)

    def validate(self) -> None:
        def fail(name, why):
            raise ValueError(f"{type(self).__name__}.{name}: {why} (got {getattr(self, name)!r})")

        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not (value == value and abs(value) != float("inf")):
                fail(f.name, "must be finite")
        if self.scenario not in SCENARIOS:
            fail("scenario", f"unknown scenario; valid: {', '.join(SCENARIOS)}")
        if self.train_level not in LEVELS:
            fail("train_level", f"unknown stress level; valid: {', '.join(LEVELS)}")
        if self.logger not in LOGGERS:
            fail("logger", f"valid: {', '.join(LOGGERS)}")
        _check_ranges(
            self,
            counts=(
                "total_steps",
                "num_envs",
                "eval_episodes",
                "final_eval_episodes",
                "threads",
                "eval_every",
                "action_repeat",
                "keep_candidates",
                "select_episodes",
            ),
            positive=("contact_speed_target",),
            fraction=(
                "following_current_fraction",
                "lateral_current_fraction",
                "near_start_fraction",
            ),
            non_negative=(
                "checkpoint_every",
                "contact_speed_penalty",
                "success_bonus",
                "miss_penalty_floor",
                "passed_station_penalty",
                "time_budget_s",
            ),
        )
        for name, sigma in (
            ("range_noise_scale", "range_noise_fraction"),
            ("bearing_noise_scale", "bearing_noise"),
        ):
            problem = noise_scale_problem(getattr(self, name), sigma)
            if problem:
                raise ValueError(f"{type(self).__name__}.{name}: {problem}")
        if self.filter_params and self.scenario not in FILTERED_OBSERVATION_KEYS:
            fail("filter_params", f"scenario {self.scenario!r} has no filter")
        if not self.hidden or any(h < 1 for h in self.hidden):
            fail("hidden", "needs positive layer sizes")
        if self.keep_candidates > 1 and not self.keep_best:
            fail("keep_candidates", "chooses among the actors keep_best keeps: set keep_best")
        if not 0.0 <= self.actor_average < 1.0:
            fail("actor_average", "must lie in [0, 1)")
        if self.mirror_symmetric not in MIRROR_SYMMETRIC:
            fail(
                "mirror_symmetric",
                f"valid: {', '.join(MIRROR_SYMMETRIC)} (got {self.mirror_symmetric!r})",
            )
        if not isinstance(self.fast_update, bool):
            fail("fast_update", "must be true or false")
        if self.mirror_symmetric == "all" and getattr(self, "privileged_critic", False):
            fail(
                "mirror_symmetric",
                "'all' not with privileged_critic (its features are not mirrored)",
            )

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class OffPolicyConfig(TrainConfig):
    """What SAC and TD3 share: a replay buffer, soft target updates, the update-to-data
    ratio."""

    batch_size: int = _doc("minibatch size", default=256)
    gamma: float = _doc("discount", default=0.99)
    lr: float = _doc("Adam learning rate, actor and critics", default=3e-4)
    buffer_size: int = _doc("replay buffer capacity", default=1_000_000)
    start_steps: int = _doc("uniformly random env steps before learning", default=10_000)
    tau: float = _doc("target-network soft-update rate (every target update)", default=0.005)
    updates_per_step: float = _doc("gradient updates per env step (UTD ratio)", default=1.0)
    frames_per_batch: int = _doc("env steps collected between update rounds", default=1_000)
    n_steps: int = _doc(
        "n-step bootstrapped targets: rewards summed over up to n steps of the episode, then "
        "gamma^m times the target critic, m <= n the steps summed (1: the paper's one-step "
        "targets; not in the paper)",
        default=1,
    )
    critic_layer_norm: bool = _doc(
        "LayerNorm after each hidden layer of the critics, before the activation (not in "
        "the paper)",
        default=False,
    )
    mirror_augment: bool = _doc(
        "store each transition twice in the replay buffer: as collected and mirrored "
        "through the docking axis (y -> -y; the task is symmetric under it, see "
        "dockingrl.scenarios.mirror_signs; not in the paper); each takes two slots of "
        "buffer_size. Refused where the task is not symmetric (a learned Q with cross terms)",
        default=False,
    )

    def validate(self) -> None:
        super().validate()
        name = type(self).__name__
        _check_ranges(
            self,
            counts=("n_steps",),
            positive=("lr", "updates_per_step"),
            unit=("tau", "gamma"),
            non_negative=("start_steps",),
        )
        if self.frames_per_batch < self.num_envs:
            raise ValueError(f"{name}.frames_per_batch: must be >= num_envs")
        if self.n_steps > self.frames_per_batch // self.num_envs:
            raise ValueError(
                f"{name}.n_steps: at most the steps per env of one collection, "
                f"frames_per_batch // num_envs = {self.frames_per_batch // self.num_envs} "
                f"(got {self.n_steps})"
            )
        if self.mirror_augment and getattr(self, "privileged_critic", False):
            raise ValueError(
                f"{name}.mirror_augment: not with privileged_critic (its features are not mirrored)"
            )
        if self.batch_size < 1 or self.buffer_size < self.batch_size:
            raise ValueError(
                f"{name}.buffer_size: must hold at least one batch "
                f"({self.buffer_size} < {self.batch_size})"
            )


@dataclass
class SACConfig(OffPolicyConfig):
    """SAC, Table 3."""

    algo: str = "sac"
    alpha: float = _doc("entropy temperature (fixed)", default=0.2)
    learn_alpha: bool = _doc(
        "tune alpha to the target entropy instead (not in the paper)", default=False
    )
    target_entropy: float = _doc(
        "target entropy of learn_alpha, in the env's action units: -dim(action) = -2; "
        "stable-baselines3's 'auto' (-2 in its [-1, 1] action units) is -2 + log(0.6 * 0.3) "
        "= -3.71 here",
        default=-2.0,
    )
    privileged_critic: bool = _doc(
        "the critics also read the simulator's true state and ocean current (asymmetric "
        "actor-critic, training only: the policy's input is unchanged; SAC only: TD3Loss "
        "gives its target critics the actor's inputs alone; not in the paper)",
        default=False,
    )


@dataclass
class TD3Config(OffPolicyConfig):
    """TD3, Table 4."""

    algo: str = "td3"
    total_steps: int = _doc("env steps (frames) to train for, all envs counted", default=2_500_000)
    eval_every: int = _doc("env steps between periodic evaluations", default=50_000)
    hidden: tuple[int, ...] = _doc("hidden layer sizes of actor and critic", default=(400, 300))
    lr: float = _doc("Adam learning rate, actor and critics", default=5e-4)
    start_steps: int = _doc(
        "uniformly random env steps before learning (learning_starts)", default=100
    )
    policy_delay: int = _doc("critic updates per actor and target update", default=2)
    target_policy_noise: float = _doc("target policy smoothing noise sigma", default=0.2)
    target_noise_clip: float = _doc("target policy smoothing noise clip", default=0.5)
    exploration_sigma: float = _doc("Gaussian action-noise sigma while collecting", default=0.2)

    def validate(self) -> None:
        super().validate()
        _check_ranges(
            self,
            counts=("policy_delay",),
            non_negative=("target_policy_noise", "target_noise_clip", "exploration_sigma"),
        )


@dataclass
class PPOConfig(TrainConfig):
    """PPO, Table 5 (stable-baselines3 defaults otherwise)."""

    algo: str = "ppo"
    total_steps: int = _doc("env steps (frames) to train for, all envs counted", default=2_500_000)
    eval_every: int = _doc("env steps between periodic evaluations", default=50_000)
    lr: float = _doc("Adam learning rate", default=3e-4)
    lr_schedule: str = _doc(
        "constant, or linear: the learning rate falls linearly to 0 at total_steps "
        "(not in Table 5)",
        default="constant",
    )
    steps_per_env: int = _doc("rollout length per env and update (n_steps)", default=2048)
    minibatch_size: int = _doc("minibatch size", default=64)
    epochs: int = _doc("passes over each rollout", default=10)
    gamma: float = _doc("discount", default=0.99)
    gae_lambda: float = _doc("GAE lambda", default=0.95)
    clip: float = _doc("PPO clip range", default=0.2)
    normalize_advantage: bool = _doc("normalise advantages per minibatch", default=True)
    entropy_coef: float = _doc("entropy bonus coefficient", default=0.0)
    value_coef: float = _doc("value-loss coefficient", default=0.5)
    max_grad_norm: float = _doc("gradient-norm clip", default=0.5)
    reward_scale: float = _doc(
        "rewards x this inside GAE and the value loss (not in the paper; logs stay unscaled)",
        default=1.0,
    )
    activation: str = _doc(
        "hidden-layer activation of actor and critic: relu, or tanh (stable-baselines3's PPO "
        "default)",
        default="relu",
    )
    state_independent_scale: bool = _doc(
        "the policy's standard deviation is one learned parameter per action, not a network "
        "output (stable-baselines3's PPO)",
        default=False,
    )
    orthogonal_init: bool = _doc(
        "orthogonal weights, gain sqrt(2) in hidden layers, 0.01 on the policy's output and 1 "
        "on the value's, zero biases (stable-baselines3's PPO)",
        default=False,
    )

    def validate(self) -> None:
        super().validate()
        _check_ranges(
            self,
            positive=("lr", "clip", "max_grad_norm"),
            counts=("epochs",),
            unit=("gamma",),
            fraction=("gae_lambda",),
            non_negative=("entropy_coef", "value_coef"),
        )
        frames = self.steps_per_env * self.num_envs
        if self.steps_per_env < 2:
            raise ValueError("PPOConfig.steps_per_env: must be >= 2")
        if not 1 <= self.minibatch_size <= frames:
            raise ValueError(
                f"PPOConfig.minibatch_size: must be in [1, num_envs * steps_per_env = {frames}] "
                f"(got {self.minibatch_size})"
            )
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(
                f"PPOConfig.lr_schedule: valid: {', '.join(LR_SCHEDULES)} "
                f"(got {self.lr_schedule!r})"
            )
        if self.activation not in ACTIVATIONS:
            raise ValueError(
                f"PPOConfig.activation: valid: {', '.join(ACTIVATIONS)} (got {self.activation!r})"
            )
        if not self.reward_scale > 0:
            raise ValueError(f"PPOConfig.reward_scale: must be > 0 (got {self.reward_scale})")
        if self.compile_update:
            raise ValueError(
                "PPOConfig.compile_update: not available for PPO (compiling ClipPPOLoss did not "
                "finish within 10 minutes on a 2-core CPU)"
            )


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


def make_config(algo: str, preset: str = "paper", **overrides) -> TrainConfig:
    """The config of ``algo`` from a preset, with field overrides, validated."""
    if algo not in CONFIGS:
        raise ValueError(f"unknown algorithm {algo!r}; valid: {', '.join(CONFIGS)}")
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; valid: {', '.join(PRESETS)}")
    cls = CONFIGS[algo]
    known = {f.name for f in fields(cls)} - _NOT_OPTIONS
    unknown = set(overrides) - known
    if unknown:
        raise ValueError(f"unknown {algo} option(s): {', '.join(sorted(unknown))}")
    cfg = cls(**{**PRESETS[preset][algo], **overrides})
    cfg.validate()
    return cfg


def check_types(algo: str, values: dict[str, Any]) -> None:
    """Refuse (``ValueError``, one line) a field of ``algo``'s config that is unknown or whose
    value has the wrong type: booleans for bool fields, integers for int fields, numbers for
    float fields, strings for str fields, a list of integers for ``hidden``."""
    if algo not in CONFIGS:
        raise ValueError(f"unknown algorithm {algo!r}; valid: {', '.join(CONFIGS)}")
    hints = get_type_hints(CONFIGS[algo])
    known = {f.name for f in fields(CONFIGS[algo])} - _NOT_OPTIONS
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


def parse_overrides(algo: str, items: Sequence[str]) -> dict[str, Any]:
    """``FIELD=VALUE`` strings to typed overrides of ``algo``'s config (``true``/``false``
    for booleans, comma-separated integers for ``hidden``); raises ``ValueError`` on an
    unknown field or a value of the wrong type."""
    if algo not in CONFIGS:
        raise ValueError(f"unknown algorithm {algo!r}; valid: {', '.join(CONFIGS)}")
    hints = get_type_hints(CONFIGS[algo])
    known = {f.name for f in fields(CONFIGS[algo])} - _NOT_OPTIONS
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
    known = {f.name for f in fields(CONFIGS[args.algo])} - _NOT_OPTIONS
    overrides = {}
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
