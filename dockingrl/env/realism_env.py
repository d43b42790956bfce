"""The part of :class:`~dockingrl.env.DockingEnv` that simulates the realism options of
:class:`~dockingrl.env.DockingConfig` (not in the paper; docs/realism.md): their per-env state,
its start at a reset and the realistic step, through the functions of
:mod:`dockingrl.env.realism`. Their randomness comes from the env's :attr:`realism_rng`, so that
turning an option on leaves the start states and Table 2's noise of every episode as they
were."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from dockingrl.env.checks import compiled
from dockingrl.env.dynamics import noisy_observation
from dockingrl.env.fossen import SPARUS_II, hydrodynamics, strip_tensors
from dockingrl.env.realism import (
    SENSOR_OF_ENTRY,
    SENSORS,
    draw_scales,
    dropout_step,
    dropout_transition,
    ou_current_step,
    usbl_outlier,
    vehicle_parameters,
)
from dockingrl.env.specs import OBSERVATION_DIM
from dockingrl.env.step import make_fossen_transition


class RealismMixin:
    """The realism options' state and step of :class:`~dockingrl.env.DockingEnv`, which
    gives the simulator's state and steps (``_advance``, ``_output``, ``_observe``,
    ``_clean_observation``, ``_sample_noise``, ``_check_finite``)."""

    @property
    def vehicle_scales(self) -> torch.Tensor | None:
        """``(num_envs, 5)`` this episode's factors on mass, damping, thrust, PID gains and
        response time of each env (:attr:`DockingConfig.mass_scale` and the following), a
        copy; ``None`` when no dynamics-mismatch option is on."""
        return None if self._vehicle is None else self._scales.clone()

    def _realism_attributes(self) -> tuple[str, ...]:
        """The attributes holding the realism options' per-env state (those that are on)."""
        cfg = self.config
        names: tuple[str, ...] = ()
        if cfg.dynamics_mismatch:
            names += ("_scales",)
        if cfg.current_model:
            names += ("_current_mean", "_current_bias", "_known_current")
        if cfg.sensor_timing:
            names += ("_held", "_sensor_steps", "_usbl_history", "_lost")
        if cfg.vehicle != "paper":
            names += ("_thrust",)
        if cfg.vehicle == "mixed":
            names += ("_on_fossen",)
        return names

    @property
    def on_fossen(self) -> torch.Tensor:
        """``(num_envs, 1)`` bool: whether each env's episode flies the Fossen vehicle
        (:attr:`DockingConfig.vehicle`), a copy."""
        if self.config.vehicle == "mixed":
            return self._on_fossen.clone()
        value = self.config.vehicle == "fossen"
        return torch.full((self.num_envs, 1), value, dtype=torch.bool, device=self.device)

    def _after_realism_state_set(self) -> None:
        """Recompute what derives from the realism state (the episode's vehicle)."""
        if self.config.dynamics_mismatch:
            self._vehicle = vehicle_parameters(self.config, self._scales)
        self._make_fossen_vehicle()

    def _make_fossen_vehicle(self) -> None:
        """The Fossen vehicle's coefficients: nominal (what its controller's feedforward knows)
        and, with the dynamics scales on (and ``scale_fossen``), this episode's per env."""
        cfg = self.config
        if cfg.vehicle == "paper":
            return
        self._fossen_nominal = hydrodynamics(SPARUS_II, cfg.dt)
        self._fossen_hydro, self._fossen_gain = self._fossen_nominal, 1.0
        if cfg.dynamics_mismatch and cfg.scale_fossen:
            scales = self._scales
            self._fossen_hydro = hydrodynamics(SPARUS_II, cfg.dt, scales, cfg.reverse_thrust_loss)
            self._fossen_gain = scales[:, 3]

    def _make_realism_state(self) -> None:
        """The per-env state of the realism options that are on (docs/realism.md)."""
        cfg, n, dev, dtype = self.config, self.num_envs, self.device, self.dtype
        if cfg.dynamics_mismatch:
            self._scales = torch.ones(n, 5, device=dev, dtype=dtype)
            self._vehicle = vehicle_parameters(cfg, self._scales)
        else:
            self._vehicle = None
        if cfg.current_model:
            self._current_mean = torch.zeros(n, 2, device=dev, dtype=dtype)
            self._current_bias = torch.zeros(n, 2, device=dev, dtype=dtype)
            self._known_current = torch.zeros(n, 2, device=dev, dtype=dtype)
        if cfg.sensor_timing:
            history = cfg.usbl_latency_steps + 1
            self._held = torch.zeros(n, OBSERVATION_DIM, device=dev, dtype=dtype)
            self._sensor_steps = torch.zeros(n, len(SENSORS), device=dev, dtype=torch.int64)
            self._usbl_history = torch.zeros(n, history, 2, device=dev, dtype=dtype)
            self._lost = torch.zeros(n, 1, device=dev, dtype=torch.bool)
            self._sensor_entry = torch.tensor(SENSOR_OF_ENTRY, device=dev)
        if cfg.vehicle != "paper":
            self._thrust = torch.zeros(n, 2, device=dev, dtype=dtype)
            self._strips = strip_tensors(SPARUS_II, dev, dtype)
            self._make_fossen_vehicle()
            gains = (self._kp, self._ki, self._kd, self._inertia)
            self._fossen_transition = make_fossen_transition(
                cfg, *gains, self._strips, self.step_reward
            )
            if self.compile_step:
                self._fossen_transition = compiled(
                    self._fossen_transition, self.device, dynamic=False
                )
        if cfg.vehicle == "mixed":
            self._on_fossen = torch.zeros(n, 1, device=dev, dtype=torch.bool)

    def _reset_realism(self, rows: torch.Tensor, current_mean: torch.Tensor) -> torch.Tensor:
        """Start the realism state of the envs in ``rows`` ``(n, 1)`` (their true state is
        reset already; ``current_mean`` is their drawn current) and return the observation:
        every sensor reports at an episode's start."""
        cfg, n, dev, dtype = self.config, self.num_envs, self.device, self.dtype
        gen = self.realism_rng
        if cfg.dynamics_mismatch:
            scales = draw_scales(cfg, n, gen, dev, dtype)
            self._scales = torch.where(rows, scales, self._scales)
            self._vehicle = vehicle_parameters(cfg, self._scales)
            self._make_fossen_vehicle()
        if cfg.vehicle != "paper":
            self._thrust = self._thrust.masked_fill(rows, 0.0)
        if cfg.vehicle == "mixed":
            draw = torch.rand(n, 1, generator=gen, device=dev, dtype=dtype) < cfg.fossen_fraction
            self._on_fossen = torch.where(rows, draw, self._on_fossen)
        if cfg.current_model:
            self._current_mean = torch.where(rows, current_mean, self._current_mean)
            if cfg.current_knowledge_bias > 0:
                bias = torch.randn(n, 2, generator=gen, device=dev, dtype=dtype)
                bias = cfg.current_knowledge_bias * bias
                self._current_bias = torch.where(rows, bias, self._current_bias)
            self._known_current = self._believed_current()
        if not cfg.sensor_timing:
            return self._observe()
        clean = self._clean_observation()
        reading = clean
        if cfg.noise:
            reading = noisy_observation(clean, self._sample_noise(), self._noise_std)
        self._held = torch.where(rows, reading, self._held)
        self._sensor_steps = self._sensor_steps.masked_fill(rows, 0)
        history = clean[:, None, :2].expand_as(self._usbl_history)
        self._usbl_history = torch.where(rows.unsqueeze(-1), history, self._usbl_history)
        self._lost = self._lost & ~rows
        return self._held

    def _believed_current(self) -> torch.Tensor:
        """The current the vehicle believes: the true one, its episode's bias and this step's
        noise (:attr:`DockingConfig.current_knowledge_bias` and ``current_knowledge_noise``)."""
        cfg = self.config
        believed = self._current + self._current_bias
        if cfg.current_knowledge_noise > 0:
            shape = (self.num_envs, 2)
            noise = torch.randn(
                shape, generator=self.realism_rng, device=self.device, dtype=self.dtype
            )
            believed = believed + cfg.current_knowledge_noise * noise
        return believed

    def _sense(self, clean: torch.Tensor, noise: torch.Tensor | None) -> torch.Tensor:
        """The sensors' readings after a step from the noise-free observation ``clean``: a
        USBL fix of the vehicle ``usbl_latency`` ago every ``usbl_period`` unless lost to a
        dropout, sometimes an outlier; DVL and IMU readings at their periods; every reading
        held between its arrivals (:attr:`_held`); ages counted in :attr:`_sensor_steps`."""
        cfg, n, dev, dtype = self.config, self.num_envs, self.device, self.dtype
        gen = self.realism_rng
        step = self._step_count
        usbl = clean[:, :2]
        if cfg.usbl_latency_steps > 0:
            history = torch.cat((self._usbl_history[:, 1:], usbl.unsqueeze(1)), dim=1)
            self._usbl_history = history
            usbl = history[:, 0]
        reading = torch.cat((usbl, clean[:, 2:]), dim=-1)
        if noise is not None:
            reading = noisy_observation(reading, noise, self._noise_std)
        usbl_due = step % cfg.usbl_period_steps == 0
        usbl_fix = usbl_due
        if cfg.usbl_dropout_probability > 0:
            uniform = torch.rand(n, 1, generator=gen, device=dev, dtype=dtype)
            transition = dropout_transition(cfg.usbl_dropout_probability, cfg.usbl_dropout_burst)
            lost = dropout_step(self._lost, uniform, *transition)
            self._lost = torch.where(usbl_due, lost, self._lost)
            usbl_fix = usbl_due & ~self._lost
        if cfg.usbl_outlier_probability > 0:
            draws = torch.rand(n, 2, generator=gen, device=dev, dtype=dtype)
            outlier = draws[:, 0] < cfg.usbl_outlier_probability
            direction = (2.0 * torch.pi) * draws[:, 1]
            moved = usbl_outlier(reading[:, :2], cfg.usbl_outlier_distance, direction, outlier)
            reading = torch.cat((moved, reading[:, 2:]), dim=-1)
        fresh = torch.cat(
            (usbl_fix, step % cfg.dvl_period_steps == 0, step % cfg.imu_period_steps == 0),
            dim=-1,
        )
        self._held = torch.where(fresh[:, self._sensor_entry], reading, self._held)
        self._sensor_steps = torch.where(fresh, 0, self._sensor_steps + 1)
        return self._held

    def _advance_fossen(self, action: torch.Tensor) -> dict:
        """Move the Fossen vehicle (``"mixed"``: each env its episode's vehicle) one step on
        (:func:`~dockingrl.env.step.make_fossen_transition`) and return the step's entries."""
        mixed = self.config.vehicle == "mixed"
        (
            self._pose,
            self._velocity,
            self._thrust,
            self._integral,
            self._previous_error,
            self._step_count,
            out,
        ) = self._fossen_transition(
            self._pose,
            self._velocity,
            self._thrust,
            self._current,
            self._integral,
            self._previous_error,
            self._step_count,
            action,
            self._fossen_nominal,
            self._fossen_hydro,
            self._fossen_gain,
            self._on_fossen if mixed else None,
            self._vehicle if mixed else None,
        )
        return out

    def _simulate_fossen(self, state: TensorDictBase, action: torch.Tensor):
        """One noise-free step of the nominal Fossen vehicle from ``state`` (any batch size;
        :meth:`~dockingrl.env.state_access.StateAccessMixin.simulate`): ``(pose, velocity,
        integral, error, step_count, out, thrust)``."""
        if "realism" not in state.keys() or "thrust" not in state["realism"].keys():
            raise KeyError("state lacks ['realism']['thrust']: the Fossen vehicle's thrusters")
        pose, velocity, thrust, integral, error, step_count, out = self._fossen_transition(
            state["pose"],
            state["velocity"],
            state["realism"]["thrust"],
            state["ocean_current"],
            state["integral"],
            state["previous_error"],
            state["step_count"],
            action,
            self._fossen_nominal,
            self._fossen_hydro,
            self._fossen_gain,
            None,
            None,
        )
        return pose, velocity, integral, error, step_count, out, thrust

    def _step_realistic(self, action: torch.Tensor) -> TensorDictBase:
        """:meth:`_step` with realism options on: the episode's vehicle, the sensors' timing and
        faults, the current's variation and the vehicle's belief about it. Table 2's noise is
        drawn as in the paper's task, the rest from :attr:`realism_rng`."""
        cfg = self.config
        noise = self._sample_noise() if cfg.noise else None
        if cfg.vehicle == "paper":
            out = self._advance(action, None, self._vehicle)
        else:
            out = self._advance_fossen(action)
        if cfg.sensor_timing:
            out["observation"] = self._sense(out["observation"], noise)
        elif noise is not None:
            out["observation"] = noisy_observation(out["observation"], noise, self._noise_std)
        if cfg.current_time_constant > 0:
            shape = (self.num_envs, 2)
            draw = torch.randn(
                shape, generator=self.realism_rng, device=self.device, dtype=self.dtype
            )
            self._current = ou_current_step(
                self._current,
                self._current_mean,
                cfg.dt,
                cfg.current_time_constant,
                cfg.current_variation_std,
                draw,
            )
        if cfg.current_model:
            self._known_current = self._believed_current()
        out = self._output(**out)
        if self.check_finite:
            self._check_finite(out, "step")
        return out
