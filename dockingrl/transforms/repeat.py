"""Holding each action for several simulation steps (not in the paper).

The paper's agents choose an action every step of ``dt = 0.2 s``; a docking approach lasts
200-300 of them, and a contact reward earned at the end reaches the first decisions only
through as many bootstrapped targets. Holding each action for ``k`` steps (a zero-order hold,
"action repeat" in the RL literature) makes the agent decide every ``k dt`` seconds: ``k``
times fewer decisions per approach and transitions per env step, the simulation, the EKF and
the rewards still at ``dt``. A vehicle's autopilot runs its velocity loop faster than its
guidance anyway; here the PID of the env keeps running at ``dt`` under the held command.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.envs import Transform


def check_action_repeat(repeat) -> int:
    """``repeat`` if it is an integer >= 1 (not a bool), else ``ValueError``: the one check of
    every place that takes an action repeat (the transform, ``make_env``, the onboard policy)."""
    if isinstance(repeat, bool) or not isinstance(repeat, int) or repeat < 1:
        raise ValueError(f"action_repeat must be an integer >= 1, got {repeat!r}")
    return repeat


def _where_live(live: torch.Tensor, new: TensorDictBase, old: TensorDictBase) -> TensorDictBase:
    """``new``'s entries where ``live`` (``(*batch, 1)``), ``old``'s elsewhere."""
    batch_dims = live.dim() - 1

    def pick(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        mask = live.reshape(*live.shape[:batch_dims], *[1] * (a.dim() - batch_dims))
        return torch.where(mask, a, b)

    return new.apply(pick, old.select(*new.keys(True, True)))


class ActionRepeat(Transform):
    """Steps the transforms before it (and the env) ``repeat`` times with the same action.

    One step of the transformed env is ``repeat`` steps of its parent: the EKF and every
    transform placed before this one see each of them, the ``reward`` is their sum, and the
    returned entries are those of the last step. An env whose episode ends during the repeat
    keeps the entries of the step where it ended (``done``, ``success``, ``contact_*``,
    ``step_count``, the final observation) and adds no reward after it, so an episode's total
    reward, length in steps and outcome are those of the same actions applied step by step.
    Envs of the batch that are done keep stepping underneath (the docking env allows it) until
    the batch's repeat ends; they are reset afterwards as usual.

    Place it right after the scenario's transforms and before ``RewardSum`` and reward-shaping
    transforms (:func:`dockingrl.make_env` does, with ``action_repeat=k``), so that those see
    one step per decision. Its state travels as the other transforms' do: the EKF's mean and
    covariance of each intermediate step are passed on to the next.

    Args:
        repeat: the number of simulation steps each action is held for (>= 1).
    """

    def __init__(self, repeat: int) -> None:
        super().__init__()
        self.repeat = check_action_repeat(repeat)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        if self.repeat == 1:
            return next_tensordict
        parent = self.parent
        if parent is None:
            raise RuntimeError("ActionRepeat must be part of a TransformedEnv")
        action_key, reward_key = parent.action_key, parent.reward_key
        action = tensordict.get(action_key)
        out = next_tensordict
        reward = out.get(reward_key)
        done = out.get("done").clone()
        for _ in range(self.repeat - 1):
            if bool(done.all()):
                break
            step_input = out.copy()
            step_input.set(action_key, action)
            step = parent._step(step_input)
            live = ~done
            reward = reward + torch.where(live, step.get(reward_key), torch.zeros_like(reward))
            if bool(done.any()):
                step = _where_live(live, step, out)
            out = step
            done = done | out.get("done")
        out.set(reward_key, reward)
        return out

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        return tensordict_reset

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        raise RuntimeError("ActionRepeat steps an env: use it inside a TransformedEnv")
