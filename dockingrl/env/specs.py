"""The specs of :class:`~dockingrl.env.DockingEnv`: what its tensordicts hold, their shapes
and dtypes (the tables of its docstring)."""

from __future__ import annotations

import torch
from torchrl.data import Binary, Bounded, Composite, TensorSpec, Unbounded

from dockingrl.env.config import DockingConfig
from dockingrl.env.realism import SENSORS

OBSERVATION_DIM = 6
TRUE_STATE_DIM = 6
ACTION_DIM = 2


def docking_specs(
    config: DockingConfig, n: int, device: torch.device, dtype: torch.dtype
) -> dict[str, TensorSpec]:
    """The env's ``observation_spec``, ``action_spec`` (the bounds of eq. 3), ``reward_spec``
    and ``full_done_spec`` for a batch of ``n`` envs; ``sensor_age`` and
    ``true_ocean_current`` join the observation when ``config``'s realism options add them."""

    def unbounded(*shape: int, dt: torch.dtype = dtype) -> Unbounded:
        return Unbounded(shape=(n, *shape), device=device, dtype=dt)

    def flag() -> Binary:
        return Binary(n=1, shape=(n, 1), device=device, dtype=torch.bool)

    observation = Composite(
        observation=unbounded(OBSERVATION_DIM),
        ocean_current=unbounded(2),
        true_state=unbounded(TRUE_STATE_DIM),
        step_count=unbounded(1, dt=torch.int64),
        success=flag(),
        contact_score=unbounded(1),
        contact_speed=unbounded(1),
        shape=(n,),
        device=device,
    )
    if config.sensor_timing:
        observation["sensor_age"] = unbounded(len(SENSORS))
    if config.current_model:
        observation["true_ocean_current"] = unbounded(2)
    action = Bounded(
        low=torch.tensor(config.action_low, dtype=dtype).expand(n, ACTION_DIM).clone(),
        high=torch.tensor(config.action_high, dtype=dtype).expand(n, ACTION_DIM).clone(),
        shape=(n, ACTION_DIM),
        device=device,
        dtype=dtype,
    )
    return {
        "observation_spec": observation,
        "action_spec": action,
        "reward_spec": unbounded(1),
        "full_done_spec": Composite(
            done=flag(), terminated=flag(), truncated=flag(), shape=(n,), device=device
        ),
    }
