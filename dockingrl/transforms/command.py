"""The previous command as an observation (not in the paper).

The paper's policies read positions, heading and velocities over ground (eq. 2). Under an
ocean current the ground velocity mixes the vehicle's own speed through the water with the
current's drift: a ground surge of 0.45 m/s may be 0.45 m/s of the vehicle's own, or 0.15 m/s
carried on by a following current of 0.3 m/s, and a memoryless policy cannot tell the two
apart although they call for opposite commands near the station. The vehicle's guidance
knows the command it sent last; through eq. 24's first-order response (time constant
``1 / k_v = 0.4 s``) that command is close to the surge through the water, so with it the
ground velocity separates into the vehicle's part and the current's. Onboard, the same value
is the command the control loop holds (:class:`dockingrl.OnboardPolicy`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs.transforms import Transform

from dockingrl.env.dynamics import clip_action


class PreviousAction(Transform):
    """Writes the action applied at the last step as ``out_key`` (default
    ``previous_action``), clipped to the command bounds as the env applies it; zeros at the
    start of an episode (the vehicle at rest, as the env starts it).

    ``make_env(..., observe_command=True)`` appends it to ``observation`` with
    :class:`~dockingrl.transforms.CompoundObservation`, after the scenario's entries and the
    current's. Under :class:`~dockingrl.transforms.ActionRepeat` it is the held action.

    Args:
        action_low, action_high: the env's command bounds (``DockingConfig.action_low`` and
            ``action_high``).
        action_key: where the action is read.
        out_key: where the previous action is written.
    """

    def __init__(
        self,
        action_low: Sequence[float],
        action_high: Sequence[float],
        *,
        action_key: str = "action",
        out_key: str = "previous_action",
    ) -> None:
        super().__init__(in_keys=[action_key], out_keys=[out_key])
        low = torch.as_tensor(action_low, dtype=torch.float32)
        high = torch.as_tensor(action_high, dtype=torch.float32)
        if low.shape != high.shape or low.dim() != 1 or not bool((low < high).all()):
            raise ValueError(f"need 1-D bounds with low < high, got {low} and {high}")
        self.register_buffer("action_low", low)
        self.register_buffer("action_high", high)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get(self.in_keys[0]).to(self.action_low.dtype)
        next_tensordict.set(
            self.out_keys[0], clip_action(action, self.action_low, self.action_high)
        )
        return next_tensordict

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        # zeros for every env: on a partial reset, TransformedEnv keeps the entries of the
        # envs outside the "_reset" mask
        shape = (*tensordict_reset.batch_size, self.action_low.numel())
        zeros = torch.zeros(shape, dtype=self.action_low.dtype, device=tensordict_reset.device)
        tensordict_reset.set(self.out_keys[0], zeros)
        return tensordict_reset

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        raise RuntimeError(
            "PreviousAction needs each step's action: use it inside a TransformedEnv"
        )

    forward = _call

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        n = self.action_low.numel()
        observation_spec[self.out_keys[0]] = Unbounded(
            shape=(*observation_spec.shape, n),
            device=observation_spec.device,
            dtype=self.action_low.dtype,
        )
        return observation_spec
