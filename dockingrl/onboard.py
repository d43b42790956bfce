"""A trained policy with the observation pipeline it was trained with, for a vehicle's control
loop: raw sensor readings in, velocity commands out, with no env and no collector.

On the vehicle, every control step (``dt`` = 0.2 s): read the sensors into the 6 numbers of
eq. 2 (USBL range and bearing, heading, DVL surge and sway, IMU yaw rate; what
:class:`~dockingrl.env.DockingEnv` calls ``observation``), take the ocean current in the docking
station's frame, and call :meth:`OnboardPolicy.act`. In the ``filtered`` and ``compound``
scenarios the policy runs the same EKF as the training env, initialised from the first reading
of an approach and then predicted with the previous command and updated with each reading.
``reset()`` begins a new approach.
"""

from __future__ import annotations

from pathlib import Path

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type

from dockingrl.env import DockingConfig
from dockingrl.scenarios import SCENARIOS, make_filter
from dockingrl.transforms.ekf import measurement_function

OBS_DIM = 6


class OnboardPolicy(nn.Module):
    """``act(z, current) -> command`` for a batch of vehicles (often one), stateful.

    Args:
        actor: a trained actor (``dockingrl.agents.saving.load_policy``), read deterministically.
        scenario: the scenario it was trained on: what it reads (raw readings, filtered ones
            or both) follows from it.
        filter_params: learned ``Q`` and ``R`` (``dockingrl learn-filter``) for the EKF;
            ``None``: Tables 1-2.
        observe_current: the actor also reads the current (``--observe-current``).
        config: the env config whose step length and command bounds the filter assumes.
    """

    def __init__(
        self,
        actor: nn.Module,
        scenario: str,
        *,
        filter_params: str | Path | None = None,
        observe_current: bool = False,
        config: DockingConfig | None = None,
    ) -> None:
        super().__init__()
        if scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {scenario!r}; valid: {', '.join(SCENARIOS)}")
        self.actor, self.scenario, self.observe_current = actor, scenario, observe_current
        self.uses_filter = scenario in ("filtered", "compound")
        if filter_params is not None and not self.uses_filter:
            raise ValueError(f"scenario {scenario!r} has no filter: filter_params do not apply")
        self.ekf = make_filter(config or DockingConfig()) if self.uses_filter else None
        if filter_params is not None:
            self.ekf.load_filter_params(filter_params)
        self._state: tuple[torch.Tensor, ...] | None = None  # mean, cov, command, age

    @classmethod
    def from_file(
        cls,
        path: str | Path,
        *,
        filter_params: str | Path | None = None,
        device: torch.device | str = "cpu",
    ) -> OnboardPolicy:
        """Load a policy saved by training (``policy.pt``); its scenario, its ``--observe-current``
        and, unless ``filter_params`` is given, its training ``--filter-params`` come with it."""
        from dockingrl.agents.saving import load_policy

        actor, info = load_policy(path, device=device)
        config = info["config"]
        params = filter_params if filter_params is not None else config.get("filter_params") or None
        policy = cls(
            actor,
            info["scenario"],
            filter_params=params,
            observe_current=bool(config.get("observe_current")),
        )
        return policy.to(device)

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Begin a new approach: in every vehicle, or where ``mask`` (``(batch,)`` bool) is
        True. The next :meth:`act` of those initialises the filter from its reading."""
        if mask is None or self._state is None:
            self._state = None
            return
        mean, cov, command, age = self._state
        self._state = (mean, cov, command, torch.where(mask.view(-1, 1), -1.0, age))

    @torch.no_grad()
    def act(self, z: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
        """The command ``(surge m/s, yaw rate rad/s)`` for the readings ``z`` (``(..., 6)``,
        eq. 2) and the current ``(..., 2)`` (DS frame, m/s); also remembered as the command
        the filter predicts the next step with."""
        z, current = self._check(z, "z", OBS_DIM), self._check(current, "current", 2)
        observation = z
        if self.uses_filter:
            filtered = self._filter(z, current)
            observation = filtered if self.scenario == "filtered" else torch.cat((z, filtered), -1)
        if self.observe_current:
            observation = torch.cat((observation, current), -1)
        td = TensorDict({"observation": observation}, batch_size=observation.shape[:-1])
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            command = self.actor(td)["action"]
        if self.uses_filter:
            mean, cov, _, age = self._state
            self._state = (mean, cov, command, age)
        return command

    def _filter(self, z: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
        ekf = self.ekf
        init_mean, init_cov = ekf._initial_state(z, current)
        if self._state is None:
            age = torch.zeros_like(z[..., :1])
            mean, cov = init_mean, init_cov
            filtered = measurement_function(mean, current)
        else:
            mean, cov, command, age = self._state
            fresh = age < 0  # reset: initialise from this reading instead
            new_mean, new_cov, new_filtered = ekf._filter_step(
                mean, cov, command, z, current, age.clamp_min(0).squeeze(-1)
            )
            mean = torch.where(fresh, init_mean, new_mean)
            cov = torch.where(fresh.unsqueeze(-1), init_cov, new_cov)
            filtered = torch.where(fresh, measurement_function(init_mean, current), new_filtered)
            age = torch.where(fresh, torch.zeros_like(age), age + 1)
        self._state = (mean, cov, None, age)
        return filtered

    def _check(self, value, name: str, size: int) -> torch.Tensor:
        param = next(self.actor.parameters())
        value = torch.as_tensor(value, dtype=param.dtype, device=param.device)
        if value.shape[-1:] != (size,):
            raise ValueError(f"{name} must end in {size} numbers, got shape {tuple(value.shape)}")
        if not bool(torch.isfinite(value).all()):
            raise ValueError(f"{name} must be finite, got {value.tolist()}")
        batch = value.shape[:-1]
        if self._state is not None and self.uses_filter and self._state[0].shape[:-1] != batch:
            raise ValueError(
                f"{name} has batch {tuple(batch)} but the filter runs on "
                f"{tuple(self._state[0].shape[:-1])} vehicles: reset() first"
            )
        return value


__all__ = ["OnboardPolicy"]
