"""The off-policy algorithms' own fields of the training config: what SAC and TD3 share (a
replay buffer, soft target updates, the update-to-data ratio, n-step targets), then SAC's
(Table 3) and TD3's (Table 4)."""

from __future__ import annotations

from dataclasses import dataclass

from dockingrl.agents.option_fields import (
    check_lr_schedule,
    check_ranges,
    documented,
    lr_schedule_field,
    refuse,
)


@dataclass
class OffPolicyOptions:
    """What SAC and TD3 share."""

    batch_size: int = documented("minibatch size", default=256)
    gamma: float = documented("discount", default=0.99)
    lr: float = documented("Adam learning rate, actor and critics", default=3e-4)
    lr_schedule: str = lr_schedule_field()
    buffer_size: int = documented("replay buffer capacity", default=1_000_000)
    start_steps: int = documented("uniformly random env steps before learning", default=10_000)
    tau: float = documented("target-network soft-update rate (every target update)", default=0.005)
    updates_per_step: float = documented("gradient updates per env step (UTD ratio)", default=1.0)
    frames_per_batch: int = documented("env steps collected between update rounds", default=1_000)
    n_steps: int = documented(
        "n-step bootstrapped targets: rewards summed over up to n steps of the episode, then "
        "gamma^m times the target critic, m <= n the steps summed (1: the paper's one-step "
        "targets; not in the paper)",
        default=1,
    )
    critic_layer_norm: bool = documented(
        "LayerNorm after each hidden layer of the critics, before the activation (not in "
        "the paper)",
        default=False,
    )
    critic_dropout: float = documented(
        "dropout probability after each hidden linear layer of the critics, before the layer "
        "norm (DroQ, Hiraoka et al. 2022: with critic_layer_norm, a cheap stand-in for a large "
        "critic ensemble at high update ratios; 0: none; not in the paper)",
        default=0.0,
    )
    reset_every: int = documented(
        "env steps between resets of the actor, the critics, their targets and the "
        "optimisers to the weights the run's agent was built with (moments cleared), the "
        "replay buffer kept: against the primacy bias of high update ratios (Nikishin et al., "
        "ICML 2022); at each multiple of it before the run's last batch; 0: never; not in the "
        "paper",
        default=0,
    )
    mirror_augment: bool = documented(
        "store each transition twice in the replay buffer: as collected and mirrored "
        "through the docking axis (y -> -y; the task is symmetric under it, see "
        "dockingrl.scenarios.mirror_signs; not in the paper); each takes two slots of "
        "buffer_size. Refused where the task is not symmetric (a learned Q with cross terms)",
        default=False,
    )

    def _check_off_policy(self) -> None:
        """Refuse an off-policy field out of its range, naming it."""
        check_ranges(
            self,
            counts=("n_steps",),
            positive=("lr", "updates_per_step"),
            unit=("tau", "gamma"),
            non_negative=("start_steps", "reset_every"),
        )
        check_lr_schedule(self)
        if not 0.0 <= self.critic_dropout < 1.0:
            refuse(self, "critic_dropout", "must lie in [0, 1)")
        if self.batch_size < 1 or self.buffer_size < self.batch_size:
            raise ValueError(
                f"{type(self).__name__}.buffer_size: must hold at least one batch "
                f"({self.buffer_size} < {self.batch_size})"
            )


@dataclass
class SACOptions:
    """SAC's own fields, Table 3."""

    alpha: float = documented("entropy temperature (fixed)", default=0.2)
    learn_alpha: bool = documented(
        "tune alpha to the target entropy instead (not in the paper)", default=False
    )
    target_entropy: float = documented(
        "target entropy of learn_alpha, in the env's action units: -dim(action) = -2; "
        "stable-baselines3's 'auto' (-2 in its [-1, 1] action units) is -2 + log(0.6 * 0.3) "
        "= -3.71 here",
        default=-2.0,
    )
    privileged_critic: bool = documented(
        "the critics also read the simulator's true state and ocean current (asymmetric "
        "actor-critic, training only: the policy's input is unchanged; SAC only: TD3Loss "
        "gives its target critics the actor's inputs alone; not in the paper)",
        default=False,
    )


@dataclass
class TD3Options:
    """TD3's own fields, Table 4."""

    policy_delay: int = documented("critic updates per actor and target update", default=2)
    target_policy_noise: float = documented("target policy smoothing noise sigma", default=0.2)
    target_noise_clip: float = documented("target policy smoothing noise clip", default=0.5)
    exploration_sigma: float = documented(
        "Gaussian action-noise sigma while collecting", default=0.2
    )

    def _check_td3(self) -> None:
        """Refuse a TD3 field out of its range, naming it."""
        check_ranges(
            self,
            counts=("policy_delay",),
            non_negative=("target_policy_noise", "target_noise_clip", "exploration_sigma"),
        )
