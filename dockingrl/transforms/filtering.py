"""The TorchRL transform of the paper's EKF (Sec. 3.5, Figure 3), which filters the noisy
observation. The EKF's noise models ``Q`` and ``R`` are in :mod:`dockingrl.transforms.noise`;
the compound observation that concatenates raw and filtered is in
:mod:`dockingrl.transforms.observations`."""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from pathlib import Path
from typing import Self

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs.transforms import Transform

from dockingrl.env.checks import compiled
from dockingrl.env.dynamics import clip_action
from dockingrl.env.realism import SENSOR_OF_ENTRY
from dockingrl.transforms.ekf import (
    MEASUREMENT_DIM,
    MEASUREMENT_NOISE_STD,
    PROCESS_NOISE_STD,
    STATE_DIM,
    ekf_step,
    initial_covariance,
    measurement_function,
    state_from_observation,
)
from dockingrl.transforms.noise import NoiseParameters
from dockingrl.transforms.params import load_filter_params, save_filter_params


def arrived_readings(sensor_age: torch.Tensor | None) -> torch.Tensor | None:
    """``(..., 6)`` bool, which observation entries are new readings, from the env's
    ``sensor_age`` ``(..., 3)`` (age 0: the sensor's reading arrived this step); ``None`` for
    ``None`` (every reading is new, the paper)."""
    if sensor_age is None:
        return None
    return (sensor_age == 0)[..., list(SENSOR_OF_ENTRY)]


class EKFTransform(NoiseParameters, Transform):
    """Filters the noisy observation with the EKF of Sec. 3.5 (eqs. 22-34).

    Reads the raw ``observation`` the env produced, the ``action`` that produced it and the
    ``ocean_current``; writes ``filtered_observation`` = ``h(x_hat)`` (eq. 26), the same six
    numbers in the same layout as the raw observation. Each env's estimate lives in the
    tensordict as declared state, ``ekf_mean`` ``(5,)`` and ``ekf_cov`` ``(5, 5)``; on reset an
    env's filter starts from its first observation (eq. 26 inverted, ``P0`` from ``R``), and only
    the envs in the ``"_reset"`` mask are re-initialised.

    ``Q`` (:class:`ProcessNoise`) and ``R`` (:class:`MeasurementNoise`) are parameters with a
    positive-definite parameterisation, Table 1 and Table 2 by default, frozen unless
    ``learnable=True``. Gradients flow from the filtered outputs of a rollout back to them.

    Keyword Args:
        dt: filter step (s); the env's step.
        k_v, k_w: rates of the first-order velocity model of eq. 24 (1/s).
        process_noise_std: Table 1 sigmas of ``[x, y, alpha, nu, w]``.
        measurement_noise_std: Table 2 sigmas, the first relative to the range (measured or
            estimated, ``range_noise_from``).
        learnable: whether ``Q`` and ``R`` require grad.
        manoeuvre_noise: let ``Q`` grow with the gap between commanded and estimated
            velocity (:class:`ProcessNoise`, not in the paper); a loaded parameter file sets
            this to what it was fitted with.
        context_noise: scale ``Q`` and ``R`` with the manoeuvre, the range and the filter's
            age (:class:`NoiseContext`, not in the paper); a loaded parameter file sets this
            to what it was fitted with. The age (steps since the filter's first fix) is kept
            as state ``ekf_age`` either way.
        range_noise_from: which range scales the USBL range sigma of ``R``: ``"measurement"``
            (Sec. 3.5 and Table 2 as specified: the measured range) or ``"estimate"`` (the
            range of the estimate the step starts from, not in the paper). The range noise is a
            fraction of the true range, so a measurement that came out short also gets a small
            sigma and weighs more; the measured-range filter's range estimate is then biased
            short by about ``2 sigma_rel^2`` of the range (0.5 % with the x2 mismatch's 5 %
            sigma). A sigma from the estimate does not depend on the reading it weighs; a
            loaded parameter file sets this to what it was fitted with.
        action_low, action_high: bounds the env clips the action to; the filter predicts with
            the clipped action that was really applied (``None``: as given).
        gate: chi-square threshold of the innovation gate (:func:`~dockingrl.transforms.ekf.
            ekf_update`; e.g. 13.8 for 2 degrees of freedom at 99.9 %): a sensor's readings
            whose innovation is further are rejected as outliers. ``None``: no gate (the paper).
        sensor_age_key: where the env reports the age of each sensor's reading (``(n, 3)``
            s, USBL, DVL, IMU; present when a sensor-timing option of
            :class:`~dockingrl.env.DockingConfig` is on): a sensor's readings update the
            estimate only at an age of 0, when they arrived; the prediction runs every step.
            Without the entry every reading updates every step (the paper).
        latency_steps: the USBL latency the filter compensates, in steps (not in the paper;
            :func:`~dockingrl.scenarios.make_filter` takes it from the env config's
            ``usbl_latency`` with ``compensate_latency=True``). A fix arriving at step ``t``
            describes the vehicle at ``t - latency_steps``: its innovation is taken against the
            range and bearing that the filter's estimate after step ``t - latency_steps``
            predicted (measurement extrapolation, :func:`~dockingrl.transforms.ekf_model.
            innovation`), kept per env as state ``ekf_usbl_history`` ``(latency_steps, 2)``,
            oldest first, and filled with the first estimate's at a reset (the env's first fixes
            of an episode describe its start). 0: a fix describes the step it arrives at (the
            paper).
        observation_key, action_key, current_key, out_key: tensordict keys.
        compile: run the filter step through ``torch.compile`` (faster for large batches;
            the first step pays the compilation).

    Examples:
        >>> from torchrl.envs import TransformedEnv
        >>> from dockingrl.env import DockingEnv
        >>> env = TransformedEnv(DockingEnv(8, seed=0), EKFTransform())
        >>> env.rollout(5)["next", "filtered_observation"].shape
        torch.Size([8, 5, 6])
    """

    #: entries of the state ``ekf_mean`` (eq. 22)
    state_dim = STATE_DIM

    def __init__(
        self,
        *,
        dt: float = 0.2,
        k_v: float = 2.5,
        k_w: float = 2.5,
        process_noise_std: Sequence[float] = PROCESS_NOISE_STD,
        measurement_noise_std: Sequence[float] = MEASUREMENT_NOISE_STD,
        learnable: bool = False,
        manoeuvre_noise: bool = False,
        context_noise: bool = False,
        range_noise_from: str = "measurement",
        action_low: Sequence[float] | None = None,
        action_high: Sequence[float] | None = None,
        gate: float | None = None,
        sensor_age_key: str = "sensor_age",
        latency_steps: int = 0,
        observation_key: str = "observation",
        action_key: str = "action",
        current_key: str = "ocean_current",
        out_key: str = "filtered_observation",
        compile: bool = False,
    ) -> None:
        for name, value in (("dt", dt), ("k_v", k_v), ("k_w", k_w)):
            if (
                isinstance(value, bool)
                or not isinstance(value, numbers.Real)
                or not 0 < value < math.inf
            ):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        super().__init__(in_keys=[observation_key, action_key, current_key], out_keys=[out_key])
        self.observation_key, self.action_key, self.current_key = (
            observation_key,
            action_key,
            current_key,
        )
        self.out_key = out_key
        self.sensor_age_key = sensor_age_key
        if gate is not None and not (isinstance(gate, int | float) and 0 < gate < math.inf):
            raise ValueError(f"gate must be a positive chi-square threshold or None, got {gate!r}")
        self.gate = None if gate is None else float(gate)
        if (
            isinstance(latency_steps, bool)
            or not isinstance(latency_steps, int)
            or latency_steps < 0
        ):
            raise ValueError(
                f"latency_steps must be a whole number of steps >= 0, got {latency_steps!r}"
            )
        self.latency_steps = latency_steps
        self.mean_key, self.cov_key, self.age_key = "ekf_mean", "ekf_cov", "ekf_age"
        self.history_key = "ekf_usbl_history"
        self.dt, self.k_v, self.k_w = dt, k_v, k_w
        self.init_noise_models(
            process_noise_std,
            measurement_noise_std,
            manoeuvre_noise=manoeuvre_noise,
            context_noise=context_noise,
            range_noise_from=range_noise_from,
        )
        self.set_learnable(learnable)
        bounds = None
        if (action_low is None) != (action_high is None):
            raise ValueError("give both action_low and action_high, or neither")
        if action_low is not None:
            bounds = torch.tensor([list(action_low), list(action_high)], dtype=torch.float32)
        self.register_buffer("action_bounds", bounds)
        if compile:
            device = next((t.device for t in self.parameters()), "cpu")
            self.filter_step = compiled(self.filter_step, device, dynamic=False)

    def save_filter_params(self, path: str | Path) -> None:
        """Write ``Q`` and ``R``'s parameters to ``path`` (atomically)."""
        save_filter_params(self, path)

    def load_filter_params(self, source) -> Self:
        """Load ``Q`` and ``R``'s parameters written by :meth:`save_filter_params`: a file's
        path, or its payload (:func:`~dockingrl.transforms.params.read_filter_params`)."""
        load_filter_params(self, source)
        return self

    # -- filtering ------------------------------------------------------------------------
    def _applied_action(self, action: torch.Tensor) -> torch.Tensor:
        if self.action_bounds is None:
            return action
        low, high = self.action_bounds.to(action)
        return clip_action(action, low, high)

    def filter_step(
        self, mean, cov, action, z, current, age, *, sensor_age=None, usbl_prediction=None
    ):
        """One predict + update with the current ``Q`` and ``R`` (what ``compile=True``
        compiles, noise models included): the previous ``action`` (clipped to the command
        bounds as the env applies it) predicts, the readings ``z`` update; ``age`` is the
        number of updates since the estimate was initialised. ``sensor_age`` ``(..., 3)``:
        the env's ages of the USBL, DVL and IMU readings; only those of age 0 update
        (``None``: all). Readings beyond :attr:`gate` are rejected. ``usbl_prediction``
        ``(..., 2)``: the range and bearing predicted for the instant a late USBL fix
        describes (:meth:`late_fix_prediction`; ``None``: the fix describes now). Returns
        ``(mean, cov, filtered)``, ``filtered`` the readings the estimate predicts (eq. 2 on
        it). The transform calls it each step; :class:`dockingrl.OnboardPolicy` too."""
        action = self._applied_action(action).to(z.dtype)
        Q, R = self.noise_covariances(mean, action, z, age)
        return ekf_step(
            mean,
            cov,
            action,
            z,
            current,
            Q,
            R,
            self.dt,
            k_v=self.k_v,
            k_w=self.k_w,
            diagonal=True,
            arrived=arrived_readings(sensor_age),
            gate=self.gate,
            usbl_prediction=usbl_prediction,
        )

    def late_fix_prediction(self, history):
        """The range and bearing ``(..., 2)`` that the estimate after step ``t -
        latency_steps`` predicted, from the ``(..., latency_steps, 2)`` history of step ``t``
        (``None`` without latency compensation)."""
        return None if history is None else history[..., 0, :]

    def pushed_history(self, history, filtered):
        """The history after a step whose filtered readings are ``filtered`` ``(..., 6)``: its
        oldest entry dropped, the new estimate's range and bearing appended."""
        if history is None:
            return None
        return torch.cat((history[..., 1:, :], filtered[..., None, :2]), dim=-2)

    def next_history(self, history, filtered, fresh):
        """The history after a step whose filtered readings are ``filtered`` ``(..., 6)``:
        :meth:`pushed_history`, or :meth:`initial_history` where ``fresh`` ``(...,)`` (an
        approach began at this step); ``None`` without latency compensation."""
        if history is None:
            return None
        return torch.where(
            fresh[..., None, None],
            self.initial_history(filtered),
            self.pushed_history(history, filtered),
        )

    def initial_history(self, filtered):
        """The history at an episode's start, ``(..., latency_steps, 2)``: the first
        estimate's range and bearing (from its ``filtered`` readings), repeated; ``None``
        without latency compensation."""
        if self.latency_steps == 0:
            return None
        shape = (*filtered.shape[:-1], self.latency_steps, 2)
        return filtered[..., None, :2].expand(shape).clone()

    def initial_estimate(self, observation, current):
        """``(mean, cov)`` from an approach's first readings (the state from the inverse of eq. 26,
        covariance from ``R`` through that inversion)."""
        mean = state_from_observation(observation, current)
        R = torch.diag_embed(self.measurement_noise(observation[..., 0]))
        return mean, initial_covariance(observation, current, R.to(observation.dtype))

    def filtered_readings(self, mean, current):
        """The readings ``(..., 6)`` the estimate ``mean`` predicts (eq. 26)."""
        return measurement_function(mean, current)

    def start_where(self, fresh, mean, cov, observation, current):
        """``(mean, cov)`` with the envs where ``fresh`` (shape ``mean.shape[:-1]``) started
        over from :meth:`initial_estimate` of their ``observation``: a new episode's first
        readings. The transform's reset, :func:`dockingrl.filter_learning.run_filter` and
        :class:`dockingrl.onboard.OnboardStep` start episodes through it."""
        init_mean, init_cov = self.initial_estimate(observation, current)
        fresh = fresh.unsqueeze(-1)
        return torch.where(fresh, init_mean, mean), torch.where(fresh.unsqueeze(-1), init_cov, cov)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        age = tensordict.get(self.age_key)
        history = tensordict.get(self.history_key) if self.latency_steps else None
        mean, cov, filtered = self.filter_step(
            tensordict.get(self.mean_key),
            tensordict.get(self.cov_key),
            tensordict.get(self.action_key),
            next_tensordict.get(self.observation_key),
            next_tensordict.get(self.current_key),
            age.squeeze(-1),
            sensor_age=next_tensordict.get(self.sensor_age_key, None),
            usbl_prediction=self.late_fix_prediction(history),
        )
        if history is not None:
            next_tensordict.set(self.history_key, self.pushed_history(history, filtered))
        next_tensordict.set(self.mean_key, mean)
        next_tensordict.set(self.cov_key, cov)
        next_tensordict.set(self.age_key, age + 1)
        next_tensordict.set(self.out_key, filtered)
        return next_tensordict

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        z = tensordict_reset.get(self.observation_key)
        current = tensordict_reset.get(self.current_key)
        age = torch.zeros_like(z[..., :1])
        previous_mean = tensordict.get(self.mean_key, None)
        if previous_mean is None:
            mean, cov = self.initial_estimate(z, current)
        else:
            reset = reset_mask(tensordict, self.parent.reset_keys[0])
            reset = reset.reshape(z.shape[:-1])
            mean, cov = self.start_where(
                reset, previous_mean, tensordict.get(self.cov_key), z, current
            )
            age = torch.where(reset.unsqueeze(-1), age, tensordict.get(self.age_key))
        filtered = self.filtered_readings(mean, current)
        if self.latency_steps:
            history = self.initial_history(filtered)
            if previous_mean is not None:
                previous = tensordict.get(self.history_key)
                history = torch.where(reset[..., None, None], history, previous)
            tensordict_reset.set(self.history_key, history)
        tensordict_reset.set(self.mean_key, mean)
        tensordict_reset.set(self.cov_key, cov)
        tensordict_reset.set(self.age_key, age)
        tensordict_reset.set(self.out_key, filtered)
        return tensordict_reset

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        raise RuntimeError(
            "EKFTransform is stateful and needs the action of each step: use it inside a "
            "TransformedEnv, or call dockingrl.transforms.ekf.ekf_step on recorded data."
        )

    forward = _call

    # -- specs ----------------------------------------------------------------------------
    def _state_specs(self, like) -> dict:
        shape, device, dtype = like.shape[:-1], like.device, like.dtype
        specs = {
            self.mean_key: Unbounded(shape=(*shape, self.state_dim), device=device, dtype=dtype),
            self.cov_key: Unbounded(
                shape=(*shape, self.state_dim, self.state_dim), device=device, dtype=dtype
            ),
            self.age_key: Unbounded(shape=(*shape, 1), device=device, dtype=dtype),
        }
        if self.latency_steps:
            specs[self.history_key] = Unbounded(
                shape=(*shape, self.latency_steps, 2), device=device, dtype=dtype
            )
        return specs

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        raw = observation_spec[self.observation_key]
        if raw.shape[-1] != MEASUREMENT_DIM:
            raise ValueError(
                f"EKFTransform expects a {MEASUREMENT_DIM}-vector '{self.observation_key}' "
                f"(eq. 2), got shape {tuple(raw.shape)}"
            )
        observation_spec[self.out_key] = raw.clone()
        observation_spec.update(self._state_specs(raw))
        return observation_spec

    def transform_input_spec(self, input_spec: Composite) -> Composite:
        raw = self.parent.full_observation_spec[self.observation_key] if self.parent else None
        if raw is None:
            return input_spec
        state_spec = input_spec["full_state_spec"]
        if state_spec is None:
            state_spec = Composite(shape=input_spec.shape, device=input_spec.device)
        state_spec.update(self._state_specs(raw))
        input_spec["full_state_spec"] = state_spec
        return input_spec


def reset_mask(tensordict: TensorDictBase, key) -> torch.Tensor:
    """The envs a reset starts anew: the partial-reset mask ``tensordict[key]`` that TorchRL
    passes to a transform's ``_reset`` (reduced to the batch's dimensions), all envs where
    there is none."""
    mask = tensordict.get(key, None)
    if mask is None:
        return torch.ones(tensordict.batch_size, dtype=torch.bool, device=tensordict.device)
    if mask.ndim > tensordict.ndim:
        mask = mask.flatten(tensordict.ndim, -1).any(-1)
    return mask
