"""Recorded rollouts to fit and score a filter on: ``num_envs`` noisy envs under a behaviour
policy, with the truth beside the readings, and the mismatched env of the filter ablation."""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from dockingrl.env import DockingConfig, DockingEnv


def mismatched_config(scale: float = 2.0, config: DockingConfig | None = None) -> DockingConfig:
    """The env with its USBL range and bearing noise scaled by ``scale`` (the filter keeps
    Table 2's ``R``): the mismatched condition of the ablation."""
    config = config or DockingConfig()
    return config.replace(
        range_noise_fraction=config.range_noise_fraction * scale,
        bearing_noise=config.bearing_noise * scale,
    )


def behaviour_policy(name: str):
    """``managed_surge`` (the baseline on the noisy pose) or ``random`` (uniform actions)."""
    if name == "managed_surge":
        from dockingrl.agents.managed_surge import ManagedSurgePolicy

        return ManagedSurgePolicy()
    if name == "random":
        return None
    raise ValueError(f"unknown behaviour policy {name!r}; valid: managed_surge, random")


def record_rollouts(
    num_envs: int,
    steps: int,
    *,
    config: DockingConfig | None = None,
    behaviour: str = "managed_surge",
    seed: int = 0,
) -> TensorDict:
    """Record ``steps`` steps of ``num_envs`` noisy envs (auto-reset) under a behaviour policy.

    Returns a ``(steps, num_envs)`` tensordict of what each step saw: ``observation`` (the raw
    measurement at that step), ``action`` (applied after it, clipped), ``ocean_current``,
    ``true_state`` and ``step_count`` (0 marks the first observation of an episode); and
    ``sensor_age`` ``(steps, num_envs, 3)`` when the env reports it (a sensor option is on).
    """
    config = (config or DockingConfig()).replace(noise=True)
    env = DockingEnv(num_envs, config=config, seed=seed)
    policy = behaviour_policy(behaviour)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        data = env.rollout(steps, policy, break_when_any_done=False)
    low = torch.tensor(config.action_low)
    high = torch.tensor(config.action_high)
    action = torch.maximum(torch.minimum(data["action"], high), low)
    out = TensorDict(
        {
            "observation": data["observation"],
            "action": action,
            "ocean_current": data["ocean_current"],
            "true_state": data["true_state"],
            "step_count": data["step_count"].squeeze(-1),
        },
        batch_size=data.batch_size,
    )
    if "sensor_age" in data.keys():
        out["sensor_age"] = data["sensor_age"]
    return out.transpose(0, 1).contiguous()  # time first
