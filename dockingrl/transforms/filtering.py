"""TorchRL transforms of the paper's learning approach (Sec. 3.5, Figure 3): the EKF that
filters the noisy observation, and the compound observation that concatenates raw and filtered."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import Composite, Unbounded
from torchrl.envs.transforms import Transform
from torchrl.envs.transforms.utils import _get_reset

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
    measurement_noise_std,
    state_from_observation,
)


class ProcessNoise(nn.Module):
    """Learnable process-noise covariance ``Q = L L^T + eps I`` (eq. 29), positive-definite by
    construction: ``L = diag(sigma) (I + C)`` with ``sigma = exp(log_diag)`` and ``C`` strictly
    lower-triangular (``off_diag``), so ``L`` has the strictly positive diagonal ``sigma``.

    ``C`` is free of units: ``off_diag`` entries are correlations-like shares relative to each
    row's sigma, so a gradient step changes a 0.01 rad/s sigma and a 0.02 m sigma by the same
    relative amount (a unit-carrying ``C`` would let steps of an optimiser's learning rate,
    ~0.01-0.1, swamp a 0.01 rad/s sigma). Initialised diagonal from Table 1 sigmas.

    With ``manoeuvre=True`` (not in the paper) ``Q`` also grows with the manoeuvre: eq. 24's
    first-order velocity model is least accurate while the vehicle's PID is saturated, that is
    when the commanded velocity is far from the present one, so

        ``Q(x, u) = L L^T + diag(sum_j (gain_j,i * (u_j - nu_j))^2) + eps I``

    with ``u = [v_d, w_d]`` the applied command, ``nu = [nu, w]`` the estimated surge and yaw
    rate before the prediction, and ``gain = exp(log_manoeuvre_gain)`` ``(2, 5)`` (units of
    each state per m/s or rad/s of gap, initialised at 10 % of the Table 1 sigma per unit of
    gap). The added term is positive semi-definite, so ``Q`` stays positive-definite."""

    def __init__(
        self,
        std: Sequence[float] = PROCESS_NOISE_STD,
        eps: float = 1e-10,
        *,
        manoeuvre: bool = False,
    ) -> None:
        super().__init__()
        std = torch.as_tensor(std, dtype=torch.float64)
        if std.shape != (STATE_DIM,) or not bool((std > 0).all()):
            raise ValueError(f"process noise needs {STATE_DIM} positive sigmas, got {std}")
        self.log_diag = nn.Parameter(std.log().float())
        self.off_diag = nn.Parameter(torch.zeros(STATE_DIM * (STATE_DIM - 1) // 2))
        self.eps = eps
        if manoeuvre:
            self.set_manoeuvre(True)

    @property
    def manoeuvre(self) -> bool:
        """Whether ``Q`` depends on the manoeuvre (see the class docstring)."""
        return hasattr(self, "log_manoeuvre_gain")

    def set_manoeuvre(self, enabled: bool) -> ProcessNoise:
        """Add (initialised at 10 % of the diagonal sigma per unit of velocity gap) or drop the
        manoeuvre gains."""
        if enabled and not self.manoeuvre:
            init = (self.log_diag.detach() + math.log(0.1)).expand(2, STATE_DIM).clone()
            self.log_manoeuvre_gain = nn.Parameter(init, requires_grad=self.log_diag.requires_grad)
        elif not enabled and self.manoeuvre:
            del self.log_manoeuvre_gain
        return self

    def cholesky_factor(self) -> torch.Tensor:
        rows, cols = torch.tril_indices(STATE_DIM, STATE_DIM, offset=-1)
        sigma = self.log_diag.exp()
        unit = torch.eye(STATE_DIM, dtype=sigma.dtype, device=sigma.device)
        unit = unit.index_put((rows.to(sigma.device), cols.to(sigma.device)), self.off_diag)
        return sigma.unsqueeze(-1) * unit

    def forward(
        self, mean: torch.Tensor | None = None, action: torch.Tensor | None = None
    ) -> torch.Tensor:
        """``Q`` ``(5, 5)``; with manoeuvre gains and the prior ``mean`` ``(..., 5)`` and
        applied ``action`` ``(..., 2)`` given, ``(..., 5, 5)``."""
        L = self.cholesky_factor()
        eye = torch.eye(STATE_DIM, dtype=L.dtype, device=L.device)
        Q = L @ L.T
        Q = 0.5 * (Q + Q.T) + self.eps * eye
        if self.manoeuvre and mean is not None:
            if action is None:
                raise ValueError("a manoeuvre-dependent Q needs the action with the mean")
            gap = (action - mean[..., 3:5]).to(L.dtype)  # (..., 2)
            extra = (gap.unsqueeze(-1) * self.log_manoeuvre_gain.exp()).pow(2).sum(-2)
            Q = Q + torch.diag_embed(extra)
        return Q


class MeasurementNoise(nn.Module):
    """Learnable diagonal measurement-noise model (eq. 31): log-sigmas of Table 2, the range
    sigma being relative to the range ``rho`` (the measured one in the paper; see
    :class:`EKFTransform`'s ``range_noise_from``). ``forward(rho)`` returns the ``(..., 6)``
    variances (a diagonal ``R``), strictly positive by construction."""

    def __init__(self, std: Sequence[float] = MEASUREMENT_NOISE_STD, eps: float = 1e-12) -> None:
        super().__init__()
        std = torch.as_tensor(std, dtype=torch.float64)
        if std.shape != (MEASUREMENT_DIM,) or not bool((std > 0).all()):
            raise ValueError(
                f"measurement noise needs {MEASUREMENT_DIM} positive sigmas, got {std}"
            )
        self.log_std = nn.Parameter(std.log().float())
        self.eps = eps

    def std(self) -> torch.Tensor:
        return self.log_std.exp()

    def forward(self, measured_range: torch.Tensor) -> torch.Tensor:
        sigma = measurement_noise_std(measured_range, self.std().to(measured_range.dtype))
        return sigma**2 + self.eps


#: What may scale the range sigma of ``R`` (:class:`EKFTransform`'s ``range_noise_from``).
RANGE_NOISE_FROM = ("measurement", "estimate")

#: Inputs of :class:`NoiseContext`, each scaled to about unit range: the velocity gaps of the
#: manoeuvre (applied command minus the estimate), the estimated yaw rate and surge, the
#: range that scales ``R`` (measured or estimated, see ``range_noise_from``) and the filter's
#: age (steps since its first fix).
CONTEXT_FEATURES = (
    "surge_gap",  # |v_d - nu| / 0.5 m/s
    "yaw_gap",  # |w_d - w| / 0.2 rad/s
    "yaw_rate",  # |w| / 0.2 rad/s
    "surge",  # |nu| / 0.5 m/s
    "log_range",  # log(max(rho, 0.5 m) / 10 m), rho the range that scales R
    "fresh",  # exp(-k / 100), k the filter's steps since its first fix
    "age",  # min(k, 600) / 300
)
#: bound on each log-scale, so that no input can drive a variance to 0 or infinity
MAX_LOG_SCALE = 12.0


class NoiseContext(nn.Module):
    """Context-dependent scaling of ``Q`` and ``R`` (not in the paper).

    Eq. 24's first-order velocity model misses the vehicle's PID saturation and integrator,
    so its error depends on the manoeuvre and on the phase of the approach; with a constant
    ``Q`` a filter is overconfident while it turns towards the DS and underconfident in the
    slow final approach. Here each variance is scaled by a log-linear function of the context
    features ``f`` (:data:`CONTEXT_FEATURES`, all known to the filter on a real vehicle):

        ``Q(f) = S_q Q S_q``, ``S_q = diag(exp(0.5 f W_q))``;
        ``R(f) = R exp(f W_r)`` (``R`` diagonal),

    with ``W_q`` ``(7, 5)`` and ``W_r`` ``(7, 6)`` learned, initialised at zero (the constant
    ``Q`` and ``R``). A congruence with a positive diagonal keeps ``Q`` positive-definite and a
    positive factor keeps ``R`` positive, whatever the weights; each log-scale is clipped to
    ``+-MAX_LOG_SCALE``."""

    def __init__(self) -> None:
        super().__init__()
        self.q_weight = nn.Parameter(torch.zeros(len(CONTEXT_FEATURES), STATE_DIM))
        self.r_weight = nn.Parameter(torch.zeros(len(CONTEXT_FEATURES), MEASUREMENT_DIM))

    @staticmethod
    def features(
        mean: torch.Tensor, action: torch.Tensor, measured_range: torch.Tensor, age: torch.Tensor
    ) -> torch.Tensor:
        """``(..., 7)`` features from the prior ``mean`` ``(..., 5)``, the applied ``action``
        ``(..., 2)``, the range that scales ``R`` ``(...)`` (the measured one unless
        ``range_noise_from="estimate"``) and the filter's ``age`` in steps ``(...)``."""
        age = age.to(mean.dtype)
        return torch.stack(
            (
                (action[..., 0] - mean[..., 3]).abs() / 0.5,
                (action[..., 1] - mean[..., 4]).abs() / 0.2,
                mean[..., 4].abs() / 0.2,
                mean[..., 3].abs() / 0.5,
                torch.log(measured_range.to(mean.dtype).clamp_min(0.5) / 10.0),
                torch.exp(-age / 100.0),
                age.clamp_max(600.0) / 300.0,
            ),
            dim=-1,
        )

    def forward(
        self, mean: torch.Tensor, action: torch.Tensor, measured_range: torch.Tensor, age
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Log-scales of ``Q``'s state components ``(..., 5)`` and of ``R``'s ``(..., 6)``."""
        f = self.features(mean, action, measured_range, age)
        q = (f @ self.q_weight.to(f.dtype)).clamp(-MAX_LOG_SCALE, MAX_LOG_SCALE)
        r = (f @ self.r_weight.to(f.dtype)).clamp(-MAX_LOG_SCALE, MAX_LOG_SCALE)
        return q, r


def arrived_readings(sensor_age: torch.Tensor | None) -> torch.Tensor | None:
    """``(..., 6)`` bool, which observation entries are new readings, from the env's
    ``sensor_age`` ``(..., 3)`` (age 0: the sensor's reading arrived this step); ``None`` for
    ``None`` (every reading is new, the paper)."""
    if sensor_age is None:
        return None
    return (sensor_age == 0)[..., list(SENSOR_OF_ENTRY)]


class EKFTransform(Transform):
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
        observation_key: str = "observation",
        action_key: str = "action",
        current_key: str = "ocean_current",
        out_key: str = "filtered_observation",
        compile: bool = False,
    ) -> None:
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a positive number, got {dt}")
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
        self.mean_key, self.cov_key, self.age_key = "ekf_mean", "ekf_cov", "ekf_age"
        self.dt, self.k_v, self.k_w = dt, k_v, k_w
        self.process_noise = ProcessNoise(process_noise_std, manoeuvre=manoeuvre_noise)
        self.measurement_noise = MeasurementNoise(measurement_noise_std)
        self.noise_context: NoiseContext | None = None
        self.set_context_noise(context_noise)
        self.range_noise_from = range_noise_from
        self.set_learnable(learnable)
        bounds = None
        if (action_low is None) != (action_high is None):
            raise ValueError("give both action_low and action_high, or neither")
        if action_low is not None:
            bounds = torch.tensor([list(action_low), list(action_high)], dtype=torch.float32)
        self.register_buffer("action_bounds", bounds)
        if compile:
            self.filter_step = torch.compile(self.filter_step, dynamic=False)

    # -- parameters -----------------------------------------------------------------------
    def set_learnable(self, learnable: bool = True) -> EKFTransform:
        """Freeze or unfreeze ``Q`` and ``R``."""
        for p in self.noise_parameters():
            p.requires_grad_(learnable)
        return self

    def noise_parameters(self) -> list[nn.Parameter]:
        context = [] if self.noise_context is None else list(self.noise_context.parameters())
        return [*self.process_noise.parameters(), *self.measurement_noise.parameters(), *context]

    @property
    def context_noise(self) -> bool:
        """Whether ``Q`` and ``R`` are scaled by a :class:`NoiseContext`."""
        return self.noise_context is not None

    def set_context_noise(self, enabled: bool) -> EKFTransform:
        """Add a :class:`NoiseContext` (zero weights: ``Q`` and ``R`` unchanged) or drop it."""
        if enabled and self.noise_context is None:
            learnable = self.measurement_noise.log_std.requires_grad
            device = self.measurement_noise.log_std.device
            self.noise_context = NoiseContext().to(device).requires_grad_(learnable)
        elif not enabled:
            self.noise_context = None
        return self

    @property
    def range_noise_from(self) -> str:
        """``"measurement"`` or ``"estimate"``: the range that scales the range sigma of ``R``
        (see the class docstring)."""
        return self._range_noise_from

    @range_noise_from.setter
    def range_noise_from(self, value: str) -> None:
        if value not in RANGE_NOISE_FROM:
            raise ValueError(
                f"range_noise_from must be one of {', '.join(RANGE_NOISE_FROM)}, got {value!r}"
            )
        self._range_noise_from = value

    def noise_covariances(
        self, mean: torch.Tensor, action: torch.Tensor, z: torch.Tensor, age: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``Q`` ``(5, 5)`` or ``(..., 5, 5)`` and the diagonal of ``R`` ``(..., 6)`` for a
        step from the prior ``mean`` under the applied ``action`` to the measurement ``z``,
        the filter being ``age`` steps old (the age matters to a context model only). The
        range that scales ``R`` is ``z``'s or ``mean``'s (:attr:`range_noise_from`)."""
        Q = self.process_noise(mean, action).to(z.dtype)
        if self.range_noise_from == "estimate":
            rho = torch.linalg.vector_norm(mean[..., :2], dim=-1).to(z.dtype)
        else:
            rho = z[..., 0]
        R = self.measurement_noise(rho)
        if self.noise_context is not None:
            q_log, r_log = self.noise_context(mean, action, rho, age)
            half = torch.exp(0.5 * q_log)
            Q = Q * half.unsqueeze(-1) * half.unsqueeze(-2)
            R = R * torch.exp(r_log)
        return Q, R

    def save_filter_params(self, path: str | Path) -> None:
        """Write ``Q`` and ``R``'s parameters to ``path`` (atomically)."""
        from dockingrl.transforms.params import save_filter_params

        save_filter_params(self, path)

    def load_filter_params(self, source) -> EKFTransform:
        """Load ``Q`` and ``R``'s parameters written by :meth:`save_filter_params`: a file's
        path, or its payload (:func:`~dockingrl.transforms.params.read_filter_params`)."""
        from dockingrl.transforms.params import load_filter_params

        load_filter_params(self, source)
        return self

    # -- filtering ------------------------------------------------------------------------
    def _applied_action(self, action: torch.Tensor) -> torch.Tensor:
        if self.action_bounds is None:
            return action
        low, high = self.action_bounds.to(action)
        return clip_action(action, low, high)

    def filter_step(self, mean, cov, action, z, current, age, *, sensor_age=None):
        """One predict + update with the current ``Q`` and ``R`` (what ``compile=True``
        compiles, noise models included): the previous ``action`` (clipped to the command
        bounds as the env applies it) predicts, the readings ``z`` update; ``age`` is the
        number of updates since the estimate was initialised. ``sensor_age`` ``(..., 3)``:
        the env's ages of the USBL, DVL and IMU readings; only those of age 0 update
        (``None``: all). Readings beyond :attr:`gate` are rejected. Returns ``(mean, cov,
        filtered)``, ``filtered`` the readings the estimate predicts (eq. 2 on it). The
        transform calls it each step; :class:`dockingrl.OnboardPolicy` too."""
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
        )

    def initial_estimate(self, observation, current):
        """``(mean, cov)`` from an approach's first readings (the state from the inverse of eq. 26,
        covariance from ``R`` through that inversion)."""
        mean = state_from_observation(observation, current)
        R = torch.diag_embed(self.measurement_noise(observation[..., 0]))
        return mean, initial_covariance(observation, current, R.to(observation.dtype))

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
        mean, cov, filtered = self.filter_step(
            tensordict.get(self.mean_key),
            tensordict.get(self.cov_key),
            tensordict.get(self.action_key),
            next_tensordict.get(self.observation_key),
            next_tensordict.get(self.current_key),
            age.squeeze(-1),
            sensor_age=next_tensordict.get(self.sensor_age_key, None),
        )
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
            reset = _get_reset(self.parent.reset_keys[0], tensordict)
            reset = reset.reshape(z.shape[:-1])
            mean, cov = self.start_where(
                reset, previous_mean, tensordict.get(self.cov_key), z, current
            )
            age = torch.where(reset.unsqueeze(-1), age, tensordict.get(self.age_key))
        tensordict_reset.set(self.mean_key, mean)
        tensordict_reset.set(self.cov_key, cov)
        tensordict_reset.set(self.age_key, age)
        tensordict_reset.set(self.out_key, measurement_function(mean, current))
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
        return {
            self.mean_key: Unbounded(shape=(*shape, STATE_DIM), device=device, dtype=dtype),
            self.cov_key: Unbounded(
                shape=(*shape, STATE_DIM, STATE_DIM), device=device, dtype=dtype
            ),
            self.age_key: Unbounded(shape=(*shape, 1), device=device, dtype=dtype),
        }

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


class CompoundObservation(Transform):
    """Concatenates observation entries in the given, fixed order (no sorting) into one key.

    The paper's compound observation (Sec. 3.5, Figure 3) is
    ``CompoundObservation(["observation", "filtered_observation"])``: raw first, then
    filtered, 12 numbers, written to ``observation`` (which the policy reads). With a single
    key it renames, as in the ``filtered`` scenario.

    Args:
        in_keys: entries to concatenate along the last dimension, in this order.
        out_key: where to write the result (default ``"observation"``, overwritten).
    """

    def __init__(self, in_keys: Sequence[str], out_key: str = "observation") -> None:
        if isinstance(in_keys, str) or len(in_keys) == 0:
            raise ValueError("in_keys must be a non-empty sequence of keys")
        super().__init__(in_keys=list(in_keys), out_keys=[out_key])

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        values = [next_tensordict.get(key) for key in self.in_keys]
        next_tensordict.set(self.out_keys[0], torch.cat(values, dim=-1))
        return next_tensordict

    forward = _call

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        specs = [observation_spec[key] for key in self.in_keys]
        size = sum(spec.shape[-1] for spec in specs)
        first = specs[0]
        observation_spec[self.out_keys[0]] = Unbounded(
            shape=(*first.shape[:-1], size), device=first.device, dtype=first.dtype
        )
        return observation_spec
