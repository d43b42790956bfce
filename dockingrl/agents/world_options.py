"""The world's fields of the training config: the scenario the agent observes, the env's
sensor mismatch and stress level, the filter's learned noise, the training envs' draws and
what the policy's observation appends."""

from __future__ import annotations

import math
from dataclasses import dataclass

from dockingrl.agents.option_fields import check_ranges, documented, env_field, refuse
from dockingrl.env.config import noise_scale_problem
from dockingrl.env.levels import LEVELS
from dockingrl.env.task_options import TRAINING_DRAWS

#: k_v = k_w of eq. 24 (1/s), the EKF's default
PAPER_RESPONSE_RATE = 2.5


def curriculum_levels(curriculum: str) -> list[str]:
    """The levels of a ``train_curriculum`` string, in order (none for ``''``)."""
    return [level.strip() for level in curriculum.split(",") if level.strip()]


@dataclass
class WorldOptions:
    """The env a run trains in and the observation its policy reads."""

    scenario: str = documented("observation scenario", default="compound")
    range_noise_scale: float = documented(
        "env's USBL range noise x this (filter keeps Table 2)", default=1.0
    )
    bearing_noise_scale: float = documented(
        "env's USBL bearing noise x this (filter keeps Table 2)", default=1.0
    )
    filter_params: str = documented(
        "learned Q/R file for the EKF (dockingrl learn-filter)", default=""
    )
    following_current_fraction: float = env_field("following_current_fraction")
    lateral_current_fraction: float = env_field("lateral_current_fraction")
    near_start_fraction: float = env_field("near_start_fraction")
    train_fossen_fraction: float = documented(
        "training envs of a level that flies either vehicle (M0, M4, M5, M5F): the share of their "
        "episodes flown on the Fossen vehicle; evaluations keep the level's even share (0.5; "
        "not in the paper)",
        default=0.5,
    )
    train_level: str = documented(
        "stress-ladder level (L0-L5, docs/realism.md) whose realism options the run's world "
        "takes: its training env (after train_curriculum's stages) and all its evaluations "
        "(L0: the paper's task; not in the paper)",
        default="L0",
    )
    train_curriculum: str = documented(
        "stress-ladder levels, comma-separated, that the training env passes through before "
        "train_level, each for an equal share of total_steps ('L1,L4' with train_level L5: "
        "a third of the run at L1, a third at L4, the last third at L5; a stage ends with the "
        "batch that reaches its share); evaluations stay at train_level ('': none; not in "
        "the paper)",
        default="",
    )
    compensate_latency: bool = documented(
        "the EKF of a filtered scenario compensates the USBL latency of the run's world "
        "(train_level, or a train_curriculum stage's level; docs/realism.md): a late fix is "
        "compared with the estimate of the instant it describes (not in the paper)",
        default=False,
    )
    estimate_current: bool = documented(
        "the EKF of a filtered scenario estimates the error of the current the vehicle "
        "believes, as two more states (docs/realism.md; not in the paper)",
        default=False,
    )
    filter_gate: float = documented(
        "chi-square threshold of the EKF's innovation gate in a filtered scenario: a sensor's "
        "two readings are left out when their innovation's squared Mahalanobis distance "
        "exceeds it, so that a USBL outlier leaves the estimate as predicted (13.816: the "
        "99.9th percentile at 2 degrees of freedom; 0: no gate, the paper's; docs/realism.md)",
        default=0.0,
    )
    filter_response_rate: float = documented(
        "rate (1/s) of the first-order surge and yaw-rate responses in the EKF's motion model "
        "of a filtered scenario (k_v = k_w of eq. 24; 2.5: the paper's model, whose low-level "
        "loop reaches a command in about a second; the Fossen vehicle answers more slowly, "
        "docs/realism.md)",
        default=PAPER_RESPONSE_RATE,
    )
    observe_current: bool = documented(
        "append the ocean current (DS frame) to the policy's observation (not in the paper)",
        default=False,
    )
    observe_command: bool = documented(
        "append the command applied at the previous step to the policy's observation, "
        "after the current's (zeros at an episode's start; not in the paper)",
        default=False,
    )
    observe_filter_std: bool = documented(
        "append the standard deviations of the EKF's x and y (m) to the policy's observation, "
        "after the scenario's entries (filtered and compound only; not in the paper)",
        default=False,
    )
    observe_current_error: bool = documented(
        "append the filter's estimate of the believed current's error to the policy's "
        "observation, after the current's (with estimate_current; not in the paper)",
        default=False,
    )
    action_repeat: int = documented(
        "hold each action for this many env steps of 0.2 s (1: the paper's; not in the "
        "paper); total_steps, eval_every, start_steps and updates_per_step still count env "
        "steps, one transition per action_repeat of them",
        default=1,
    )

    def _check_world(self) -> None:
        """Refuse a world field out of its range, naming it."""
        from dockingrl.scenarios import FILTERED_OBSERVATION_KEYS, SCENARIOS

        if self.scenario not in SCENARIOS:
            refuse(self, "scenario", f"unknown scenario; valid: {', '.join(SCENARIOS)}")
        if self.train_level not in LEVELS:
            refuse(self, "train_level", f"unknown stress level; valid: {', '.join(LEVELS)}")
        for level in curriculum_levels(self.train_curriculum):
            if level not in LEVELS:
                refuse(
                    self,
                    "train_curriculum",
                    f"unknown stress level {level!r}; valid: {', '.join(LEVELS)}",
                )
        check_ranges(
            self,
            counts=("action_repeat",),
            positive=("filter_response_rate",),
            fraction=(*TRAINING_DRAWS, "train_fossen_fraction"),
            flags=(
                "compensate_latency",
                "estimate_current",
                "observe_filter_std",
                "observe_current_error",
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
            refuse(self, "filter_params", f"scenario {self.scenario!r} has no filter")
        if not (0.0 <= self.filter_gate < math.inf):
            refuse(self, "filter_gate", "must be a chi-square threshold > 0, or 0 for no gate")
        for name in (
            "compensate_latency",
            "estimate_current",
            "filter_gate",
            "observe_filter_std",
            "observe_current_error",
        ):
            if getattr(self, name) and self.scenario not in FILTERED_OBSERVATION_KEYS:
                refuse(self, name, f"scenario {self.scenario!r} has no filter")
        if self.observe_current_error and not self.estimate_current:
            refuse(self, "observe_current_error", "needs estimate_current (the filter's estimate)")
        if self.filter_response_rate != PAPER_RESPONSE_RATE and (
            self.scenario not in FILTERED_OBSERVATION_KEYS
        ):
            refuse(self, "filter_response_rate", f"scenario {self.scenario!r} has no filter")
