"""n-step targets for SAC and TD3 (``n_steps``, not in the paper)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase


def n_step_transitions(data: TensorDictBase, n_steps: int, gamma: float) -> TensorDictBase:
    """n-step transitions (not in the paper) from time-ordered data of shape ``(envs, L)``.

    The transition of step ``t`` keeps ``observation`` and ``action`` of ``t`` and looks ahead
    ``m = min(n_steps, steps left in its episode)`` steps: its reward is
    ``sum_{k<m} gamma^k r_{t+k}``, its ``next`` entries (observation and the ``done`` /
    ``terminated`` / ``truncated`` flags) are those of step ``t + m - 1``, and
    ``steps_to_next_obs = m``, which TorchRL's TD(0) estimator turns into the bootstrap
    discount ``gamma^m``. A transition ending on a terminal step therefore never bootstraps.
    Only the first ``L - n_steps + 1`` steps have their whole window in ``data`` and are
    returned; the caller carries the last ``n_steps - 1`` steps over to the next call."""
    length = data.shape[-1]
    count = length - n_steps + 1
    if count < 1:
        raise ValueError(f"n-step transitions need at least {n_steps} steps, got {length}")
    reward = data["next", "reward"]
    done = data["next", "done"]
    index = torch.arange(count, device=reward.device).expand(*data.shape[:-1], count)
    last = index.clone()
    summed = torch.zeros_like(reward[..., :count, :])
    alive = torch.ones_like(done[..., :count, :])
    for k in range(n_steps):
        summed = summed + alive * (gamma**k) * reward[..., k : k + count, :]
        last = torch.where(alive.squeeze(-1), index + k, last)
        alive = alive & ~done[..., k : k + count, :]
    out = data[..., :count].clone()
    out["next"] = data["next"].gather(-1, last)
    out["next", "reward"] = summed
    out["steps_to_next_obs"] = (last - index + 1).unsqueeze(-1).to(reward.dtype)
    return out


class NStepWindow:
    """What the replay buffer stores of successive collections: one-step transitions, or with
    ``n_steps > 1`` the n-step ones of :func:`n_step_transitions`, the last ``n_steps - 1``
    steps of each collection waiting for the next one to complete their window. A checkpoint
    does not keep those steps: a resumed run restarts its envs' episodes, so they have no
    continuation."""

    def __init__(self, n_steps: int, gamma: float) -> None:
        self.n_steps = n_steps
        self.gamma = gamma
        self.tail: TensorDictBase | None = None

    def __call__(self, data: TensorDictBase) -> TensorDictBase:
        n = self.n_steps
        if n == 1:
            return data
        if self.tail is not None:
            data = torch.cat((self.tail, data), dim=-1)
        self.tail = data[..., data.shape[-1] - (n - 1) :].clone()
        return n_step_transitions(data, n, self.gamma)
