"""PPO's own fields of the training config (Table 5, stable-baselines3's defaults otherwise),
its networks' options among them."""

from __future__ import annotations

from dataclasses import dataclass

from dockingrl.agents.option_fields import (
    check_lr_schedule,
    check_ranges,
    documented,
    lr_schedule_field,
)

#: hidden-layer activations: option name -> ``torch.nn`` class name
ACTIVATIONS = {"relu": "ReLU", "tanh": "Tanh"}


@dataclass
class PPOOptions:
    """PPO's rollouts, loss and optimiser, and its networks' activation and initialisation."""

    lr: float = documented("Adam learning rate", default=3e-4)
    lr_schedule: str = lr_schedule_field()
    steps_per_env: int = documented("rollout length per env and update (n_steps)", default=2048)
    minibatch_size: int = documented("minibatch size", default=64)
    epochs: int = documented("passes over each rollout", default=10)
    gamma: float = documented("discount", default=0.99)
    gae_lambda: float = documented("GAE lambda", default=0.95)
    clip: float = documented("PPO clip range", default=0.2)
    normalize_advantage: bool = documented("normalise advantages per minibatch", default=True)
    entropy_coef: float = documented("entropy bonus coefficient", default=0.0)
    value_coef: float = documented("value-loss coefficient", default=0.5)
    max_grad_norm: float = documented("gradient-norm clip", default=0.5)
    reward_scale: float = documented(
        "rewards x this inside GAE and the value loss (not in the paper; logs stay unscaled)",
        default=1.0,
    )
    activation: str = documented(
        "hidden-layer activation of actor and critic: relu, or tanh (stable-baselines3's PPO "
        "default)",
        default="relu",
    )
    state_independent_scale: bool = documented(
        "the policy's standard deviation is one learned parameter per action, not a network "
        "output (stable-baselines3's PPO)",
        default=False,
    )
    orthogonal_init: bool = documented(
        "orthogonal weights, gain sqrt(2) in hidden layers, 0.01 on the policy's output and 1 "
        "on the value's, zero biases (stable-baselines3's PPO)",
        default=False,
    )
    advantage_every_epoch: bool = documented(
        "estimate advantages (GAE) again before every epoch with the current value network "
        "(TorchRL's examples); false: once per rollout, before the epochs (stable-baselines3, "
        "CleanRL), a tenth of the value-network passes at 10 epochs",
        default=True,
    )

    def _check_ppo(self) -> None:
        """Refuse a PPO field out of its range, naming it."""
        name = type(self).__name__
        check_ranges(
            self,
            positive=("lr", "clip", "max_grad_norm"),
            counts=("epochs",),
            unit=("gamma",),
            fraction=("gae_lambda",),
            non_negative=("entropy_coef", "value_coef"),
            flags=("advantage_every_epoch",),
        )
        if self.steps_per_env < 2:
            raise ValueError(f"{name}.steps_per_env: must be >= 2")
        check_lr_schedule(self)
        if self.activation not in ACTIVATIONS:
            raise ValueError(
                f"{name}.activation: valid: {', '.join(ACTIVATIONS)} (got {self.activation!r})"
            )
        if not self.reward_scale > 0:
            raise ValueError(f"{name}.reward_scale: must be > 0 (got {self.reward_scale})")
