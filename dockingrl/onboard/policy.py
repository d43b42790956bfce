"""A trained policy with the observation pipeline it was trained with, for a vehicle's control
loop: raw sensor readings in, velocity commands out, with no env and no collector.

On the vehicle, every control step (``dt`` = 0.2 s): read the sensors into the 6 numbers of
eq. 2 (USBL range and bearing, heading, DVL surge and sway, IMU yaw rate; what
:class:`~dockingrl.env.DockingEnv` calls ``observation``), take the ocean current in the docking
station's frame, and call :meth:`OnboardPolicy.act`. In the ``filtered`` and ``compound``
scenarios the policy runs the same EKF as the training env, initialised from the first reading
of an approach and then predicted with the previous command and updated with each reading.
A policy trained with ``--action-repeat k`` decides every ``k`` steps and holds its command in
between, as in training; the filter still runs every step.
A vehicle whose sensors report at their own rates (a 1 Hz USBL, say) also passes the age of
each sensor's reading (``sensor_age``: seconds since the USBL, DVL and IMU readings arrived,
what the env reports with a sensor option on, docs/realism.md): the filter then updates with
the readings of age 0 only and predicts through the others, as the training env's filter does.
A filter that compensates the USBL's latency (``compensate_latency``, docs/realism.md) also
keeps the range and bearing its last estimates predicted.
``reset()`` begins a new approach.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type

from dockingrl.env import DockingConfig
from dockingrl.env.config import config_or_default
from dockingrl.env.dynamics import clip_action
from dockingrl.env.realism import SENSORS
from dockingrl.scenarios import (
    FILTERED_OBSERVATION_KEYS,
    SCENARIOS,
    make_filter,
    observation_layout,
)
from dockingrl.transforms.ekf import STATE_DIM
from dockingrl.transforms.observations import check_estimates_current, position_std
from dockingrl.transforms.repeat import check_action_repeat

OBS_DIM = 6


class OnboardStep(nn.Module):
    """One control step as a pure function of the readings and the filter's state, the form
    :func:`export_onboard` hands to ``torch.export``:

    ``(z, current, mean, cov, command, age[, sensor_age[, history]]) -> (command, mean, cov,
    age[, history])``

    with ``z`` ``(B, 6)`` readings (eq. 2), ``current`` ``(B, 2)``, the EKF's ``mean`` ``(B,
    n)`` and ``cov`` ``(B, n, n)`` (``n`` = 5; 7 for the filter that estimates the current), the
    previous ``command`` ``(B, 2)`` and ``age`` ``(B, 1)``, the steps since the approach began;
    ``age < 0`` marks a new approach (the filter starts from ``z``). Scenarios without a filter
    pass ``mean`` and ``cov`` through and still count ``age``. ``sensor_age`` ``(B, 3)``
    (optional): seconds since the USBL, DVL and IMU readings arrived; only those of age 0 update
    the filter (absent: every reading is new). ``history`` ``(B, latency_steps, 2)``, with a
    filter that compensates the USBL latency (and only then): the range and bearing its last
    estimates predicted (the :class:`~dockingrl.transforms.EKFTransform`'s
    ``ekf_usbl_history``). With ``action_repeat = k > 1`` (a policy trained with
    ``--action-repeat k``) the actor's command is taken on the approach's steps ``0, k, 2k,
    ...`` and held in between, as the training env held it
    (:class:`~dockingrl.transforms.ActionRepeat`). ``observe`` (the options of
    :func:`~dockingrl.scenarios.observation_layout`) adds to what the actor reads: the
    ``current``; the previous ``command`` (zeros on an approach's first step, as
    :class:`~dockingrl.transforms.PreviousAction` gives it); the standard deviations of the
    filter's ``x`` and ``y`` after this step's update (:class:`~dockingrl.transforms.observations.
    FilterStd`); the filter's estimate of the current's error after it (:class:`~dockingrl.
    transforms.observations.CurrentError`). The command returned is clipped to ``config``'s
    bounds (eq. 3), as the env applies it."""

    def __init__(
        self,
        actor: nn.Module,
        scenario: str,
        ekf,
        *,
        action_repeat: int = 1,
        config: DockingConfig | None = None,
        **observe: bool,
    ) -> None:
        super().__init__()
        trained = getattr(actor, "trained_on", None)  # an actor from load_policy
        if trained is not None:
            from dockingrl.agents.layout import check_env_layout

            check_env_layout(trained, scenario, {**observe, "action_repeat": action_repeat})
        self.actor, self.scenario, self.ekf = actor, scenario, ekf
        config = config_or_default(config)
        self.register_buffer("action_low", torch.tensor(config.action_low))
        self.register_buffer("action_high", torch.tensor(config.action_high))
        self.layout = observation_layout(scenario, **observe)
        if "current_error" in self.layout:
            check_estimates_current(ekf)
        self.action_repeat = check_action_repeat(action_repeat)

    @property
    def observe_current(self) -> bool:
        return "ocean_current" in self.layout

    @property
    def observe_command(self) -> bool:
        return "previous_action" in self.layout

    def forward(self, z, current, mean, cov, command, age, sensor_age=None, history=None):
        parts = {"observation": z, "ocean_current": current}
        compensates = self.ekf is not None and self.ekf.latency_steps > 0
        if compensates != (history is not None):
            raise ValueError(
                "history is the state of a filter that compensates the USBL latency: pass it "
                "exactly when the filter does"
            )
        if self.ekf is not None:
            mean, cov, parts["filtered_observation"], age, history = self._filter(
                z, current, mean, cov, command, age, sensor_age, history
            )
            parts["filter_std"] = position_std(cov)
            parts["current_error"] = mean[..., STATE_DIM:]
        else:
            age = torch.where(age < 0, torch.zeros_like(age), age + 1)
        parts["previous_action"] = torch.where(age == 0, torch.zeros_like(command), command)
        observation = torch.cat([parts[key] for key in self.layout], -1)
        td = TensorDict({"observation": observation}, batch_size=observation.shape[:-1])
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            new_command = self.actor(td)["action"]
        # what the env applies, and what it reports as the previous command
        new_command = clip_action(new_command, self.action_low, self.action_high)
        if self.action_repeat > 1:
            decide = torch.remainder(age, self.action_repeat) == 0
            new_command = torch.where(decide, new_command, command)
        return (new_command, mean, cov, age) + (() if history is None else (history,))

    def _filter(self, z, current, mean, cov, command, age, sensor_age, history):
        new_mean, new_cov, new_filtered = self.ekf.filter_step(
            mean,
            cov,
            command,
            z,
            current,
            age.clamp_min(0).squeeze(-1),
            sensor_age=sensor_age,
            usbl_prediction=self.ekf.late_fix_prediction(history),
        )
        fresh = age < 0
        mean, cov = self.ekf.start_where(fresh.squeeze(-1), new_mean, new_cov, z, current)
        filtered = torch.where(fresh, self.ekf.filtered_readings(mean, current), new_filtered)
        history = self.ekf.next_history(history, filtered, fresh.squeeze(-1))
        return mean, cov, filtered, torch.where(fresh, torch.zeros_like(age), age + 1), history


class OnboardPolicy(nn.Module):
    """``act(z, current) -> command`` for a batch of vehicles (often one), stateful.

    Args:
        actor: a trained actor (``dockingrl.agents.saving.load_policy``), read deterministically.
        scenario: the scenario it was trained on: what it reads (raw readings, filtered ones
            or both) follows from it.
        filter_params: learned ``Q`` and ``R`` (``dockingrl learn-filter``) for the EKF;
            ``None``: Tables 1-2.
        observe_current: the actor also reads the current (``--observe-current``).
        observe_command: the actor also reads its previous command (``--observe-command``).
        observe_filter_std: the actor also reads the filter's position uncertainty
            (``--observe-filter-std``).
        observe_current_error: the actor also reads the filter's estimate of the current's
            error (``--observe-current-error``; needs ``estimate_current``).
        action_repeat: the actor decides every this many steps and its command is held in
            between (``--action-repeat``).
        config: the env config whose step length and command bounds the filter assumes.
        compensate_latency: the filter compensates ``config``'s USBL latency (as the env's
            filter built with ``compensate_latency=True``; docs/realism.md).
        estimate_current: the filter estimates the current's error (``mean`` ``(B, 7)``,
            ``cov`` ``(B, 7, 7)``; :class:`~dockingrl.transforms.current_filter.
            CurrentEstimatingEKF`).
        gate: the filter's chi-square innovation gate (``--filter-gate``; ``None``: none).
        k_v, k_w: the rates of the filter's surge and yaw-rate responses (eq. 24;
            ``--filter-response-rate``).
    """

    def __init__(
        self,
        actor: nn.Module,
        scenario: str,
        *,
        filter_params: str | Path | None = None,
        observe_current: bool = False,
        observe_command: bool = False,
        observe_filter_std: bool = False,
        observe_current_error: bool = False,
        action_repeat: int = 1,
        config: DockingConfig | None = None,
        compensate_latency: bool = False,
        estimate_current: bool = False,
        gate: float | None = None,
        k_v: float = 2.5,
        k_w: float = 2.5,
    ) -> None:
        super().__init__()
        from dockingrl.agents.layout import reject_policy_pair

        reject_policy_pair(actor, "actor", "or use OnboardPolicy.from_file(path)")
        if not callable(actor):
            raise TypeError(
                f"actor must be a module that maps observations to commands, got {actor!r}"
            )
        if scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {scenario!r}; valid: {', '.join(SCENARIOS)}")
        self.scenario, self.observe_current = scenario, observe_current
        self.uses_filter = scenario in FILTERED_OBSERVATION_KEYS
        if filter_params is not None and not self.uses_filter:
            raise ValueError(f"scenario {scenario!r} has no filter: filter_params do not apply")
        for name, on in (
            ("compensate_latency", compensate_latency),
            ("estimate_current", estimate_current),
            ("gate", gate is not None),
            ("the filter's response rates", (k_v, k_w) != (2.5, 2.5)),
        ):
            if on and not self.uses_filter:
                raise ValueError(f"scenario {scenario!r} has no filter: {name} does not apply")
        config = config_or_default(config)
        observe = {"observe_current": observe_current, "observe_command": observe_command}
        observe["observe_filter_std"] = observe_filter_std
        observe["observe_current_error"] = observe_current_error
        ekf = None
        if self.uses_filter:
            ekf = make_filter(
                config,
                compensate_latency=compensate_latency,
                estimate_current=estimate_current,
                gate=gate,
                k_v=k_v,
                k_w=k_w,
            )
        if filter_params is not None:
            ekf.load_filter_params(filter_params)
        self.step = OnboardStep(
            actor, scenario, ekf, action_repeat=action_repeat, config=config, **observe
        )
        # mean, cov, command, age and, with latency compensation, the history
        self._state: tuple[torch.Tensor, ...] | None = None

    @classmethod
    def from_file(
        cls,
        path: str | Path,
        *,
        filter_params: str | Path | None = None,
        device: torch.device | str = "cpu",
        config: DockingConfig | None = None,
    ) -> OnboardPolicy:
        """Load a policy saved by training (``policy.pt``); its scenario, its ``--observe-*``
        and ``--action-repeat`` and, unless ``filter_params`` is given, its training
        ``--filter-params`` come with it
        (``filter_params="none"``: Table 1's hand-tuned filter instead).
        ``config`` describes the vehicle (default: the paper's): with a policy trained with
        ``--compensate-latency`` the filter compensates ``config``'s USBL latency, not the
        latency of the level the policy was trained at."""
        from dockingrl.agents.layout import training_filter
        from dockingrl.agents.saving import load_policy

        actor, info = load_policy(path, device=device)
        options = dict(info["env_options"])
        if filter_params is None:
            params = training_filter(info)
        else:
            params = None if str(filter_params) == "none" else filter_params
        filter_options = options.pop("ekf_kwargs", {})
        policy = cls(
            actor,
            info["scenario"],
            filter_params=params,
            config=config,
            **filter_options,
            **options,
        )
        return policy.to(device)

    def initial_state(self, batch: int) -> tuple[torch.Tensor, ...]:
        """The state before an approach: ``(mean, cov, command, age)`` with ``age = -1``, and
        the ``(batch, latency_steps, 2)`` history when the filter compensates the latency."""
        like = next(self.step.actor.parameters())
        zeros = partial(torch.zeros, dtype=like.dtype, device=like.device)
        ekf = self.step.ekf
        history = (
            () if ekf is None or not ekf.latency_steps else (zeros(batch, ekf.latency_steps, 2),)
        )
        n = STATE_DIM if ekf is None else ekf.state_dim
        return (
            zeros(batch, n),
            torch.eye(n, dtype=like.dtype, device=like.device).expand(batch, n, n).clone(),
            zeros(batch, 2),
            -torch.ones(batch, 1, dtype=like.dtype, device=like.device),
            *history,
        )

    @property
    def filter_state(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """The filter's ``(mean, cov)`` after the last :meth:`act` (``None`` before the first
        of an approach); a scenario without a filter passes zeros and the identity through."""
        return None if self._state is None else (self._state[0], self._state[1])

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Begin a new approach: in every vehicle, or where ``mask`` (``(batch,)`` bool) is
        True. The next :meth:`act` of those initialises the filter from its reading."""
        if mask is None or self._state is None:
            self._state = None
            return
        mean, cov, command, age, *history = self._state
        is_tensor = isinstance(mask, torch.Tensor)
        if not is_tensor or mask.dtype != torch.bool or mask.shape != (age.shape[0],):
            got = f"{mask.dtype} {tuple(mask.shape)}" if is_tensor else type(mask).__name__
            raise ValueError(
                f"mask must be a bool tensor of shape ({age.shape[0]},), one per vehicle, got {got}"
            )
        self._state = (mean, cov, command, torch.where(mask.view(-1, 1), -1.0, age), *history)

    @torch.no_grad()
    def act(
        self, z: torch.Tensor, current: torch.Tensor, sensor_age: torch.Tensor | None = None
    ) -> torch.Tensor:
        """The command ``(surge m/s, yaw rate rad/s)`` for the readings ``z`` (``(..., 6)``,
        eq. 2) and the current ``(..., 2)`` (DS frame, m/s); also remembered as the command
        the filter predicts the next step with. ``sensor_age`` ``(..., 3)``: seconds since the
        USBL, DVL and IMU readings in ``z`` arrived; the filter updates with those of age 0
        only (``None``: every reading is new; a scenario without a filter ignores them)."""
        z, current = self._check(z, "z", OBS_DIM), self._check(current, "current", 2)
        if bool((z[..., 0] < 0).any()):
            raise ValueError(
                f"z's range (its first entry, eq. 2's rho) must be >= 0 m, got {z.tolist()}"
            )
        single = z.dim() == 1
        if z.shape[:-1] != current.shape[:-1]:
            raise ValueError(
                f"z {tuple(z.shape)} and current {tuple(current.shape)} must hold the same "
                "vehicles (the same leading shape)"
            )
        z, current = z.reshape(-1, OBS_DIM), current.reshape(-1, 2)
        if sensor_age is not None:
            sensor_age = self._check(sensor_age, "sensor_age", len(SENSORS))
            if bool((sensor_age < 0).any()):
                raise ValueError(f"sensor_age must be >= 0 s, got {sensor_age.tolist()}")
            if sensor_age.dim() != (1 if single else 2) or sensor_age.numel() != z.shape[0] * len(
                SENSORS
            ):
                raise ValueError(
                    f"sensor_age must have one row of {len(SENSORS)} ages per vehicle of z, "
                    f"got shape {tuple(sensor_age.shape)} for z of shape "
                    f"{(OBS_DIM,) if single else tuple(z.shape)}"
                )
            sensor_age = sensor_age.reshape(-1, len(SENSORS))
        if self._state is None:
            self._state = self.initial_state(z.shape[0])
        elif self._state[0].shape[0] != z.shape[0]:
            raise ValueError(
                f"z has {z.shape[0]} vehicles but the filter runs on "
                f"{self._state[0].shape[0]}: reset() first"
            )
        mean, cov, command, age, *history = self._state
        command, *state = self.step(z, current, mean, cov, command, age, sensor_age, *history)
        if not bool(command.isfinite().all()):  # never a NaN to the thrusters; state kept
            raise RuntimeError(f"the policy computed a non-finite command {command.tolist()}")
        self._state = (state[0], state[1], command, *state[2:])
        return command[0] if single else command

    def _check(self, value, name: str, size: int) -> torch.Tensor:
        param = next(self.step.actor.parameters())
        try:
            value = torch.as_tensor(value)
        except (TypeError, ValueError, RuntimeError):
            raise ValueError(
                f"{name} must be real numbers of shape ({size},) or (vehicles, {size}), "
                f"got {type(value).__name__}"
            ) from None
        if value.dtype == torch.bool or value.is_complex():
            raise ValueError(f"{name} must be real numbers, got dtype {value.dtype}")
        value = value.to(dtype=param.dtype, device=param.device)
        if value.shape[-1:] != (size,) or value.dim() > 2:
            raise ValueError(
                f"{name} must be ({size},) or (vehicles, {size}), got shape {tuple(value.shape)}"
            )
        if not bool(torch.isfinite(value).all()):
            raise ValueError(f"{name} must be finite, got {value.tolist()}")
        return value


__all__ = ["OBS_DIM", "OnboardPolicy", "OnboardStep"]
