"""The batched docking environment (Sec. 3 and 4.1 of the paper), a TorchRL ``EnvBase``."""

from __future__ import annotations

import numbers

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Composite, Unbounded
from torchrl.envs import EnvBase

from dockingrl.env.config import DockingConfig
from dockingrl.env.dynamics import (
    clip_action,
    noisy_observation,
    observation_from_state,
    pid_thrust,
    pose_update,
    velocity_update,
)
from dockingrl.env.realism import (
    SENSOR_OF_ENTRY,
    SENSORS,
    draw_scales,
    dropout_step,
    dropout_transition,
    limit_thrust,
    ou_current_step,
    usbl_outlier,
    vehicle_parameters,
)
from dockingrl.env.reward import (
    contact_reward,
    contact_score,
    distance_reward,
    entry_velocity_reward,
    thrust_reward,
)

OBSERVATION_DIM = 6
TRUE_STATE_DIM = 6
ACTION_DIM = 2
#: added to the env's seed for its realism generator (:attr:`DockingEnv.realism_rng`)
REALISM_SEED_OFFSET = 0x5EA1


def _uniform(low: float, high: float, n: int, generator, device, dtype) -> torch.Tensor:
    return low + (high - low) * torch.rand(n, generator=generator, device=device, dtype=dtype)


class DockingEnv(EnvBase):
    """Dock an under-actuated AUV into a funnel-shaped docking station (DS) under ocean currents.

    ## Description

    Re-implementation of the docking task of "Autonomous Underwater Vehicle Docking Under
    Realistic Assumptions Using Deep Reinforcement Learning" (Sec. 3, 4.1). A torpedo-shaped
    AUV without rudders, commanded in surge and yaw rate through a low-level PID velocity
    controller, must enter a funnel whose mouth opens towards -x at the origin, slowly enough
    (<= 0.3 m/s over ground) and well aligned, while a constant ocean current drifts it. Its
    sensors (inverted USBL, DVL, IMU) are noisy (Table 2). ``num_envs`` independent copies step
    at once with tensor operations, on any torch device.

    ## Action Space

    ``action``: ``(num_envs, 2)`` float, the velocity set-points of eq. 3.

    | Num | Action | Min | Max | Unit |
    |-----|--------|-----|-----|------|
    | 0 | desired surge ``v_d`` | -0.4 | 0.8 | m/s |
    | 1 | desired yaw rate ``w_d`` | -0.3 | 0.3 | rad/s |

    Actions outside the bounds are clipped to them; a NaN or infinite action raises
    ``ValueError``, and so does an action of the wrong shape or a bool or complex one.

    ## Observation Space

    ``observation``: ``(num_envs, 6)`` float, eq. 2, noisy unless ``config.noise`` is False.

    | Num | Observation | Sensor | Noise sigma (Table 2) | Unit |
    |-----|-------------|--------|-----------------------|------|
    | 0 | range to the DS ``rho`` | USBL | 2.5 % of rho | m |
    | 1 | bearing to the DS ``psi``, in (-pi, pi] | USBL | 1.5 deg | rad |
    | 2 | heading ``alpha`` in the DS frame, in (-pi, pi] | IMU | 3 deg | rad |
    | 3 | surge velocity over ground ``vx`` (body frame) | DVL | 0.02 | m/s |
    | 4 | sway velocity over ground ``vy`` (body frame) | DVL | 0.02 | m/s |
    | 5 | yaw rate ``w`` | IMU | 0.2 deg/s | rad/s |

    Also in each tensordict, for the filter, the baseline and the evaluation (a policy must not
    need them): ``ocean_current`` ``(num_envs, 2)`` m/s in the DS frame (known to the vehicle, as
    the paper assumes for the EKF); ``true_state`` ``(num_envs, 6)``
    ``[x, y, alpha, u, v, r]`` (pose in the DS frame, velocity through the water in the body
    frame); ``step_count`` ``(num_envs, 1)``; and, meaningful on the contact step only,
    ``success``, ``contact_score`` (``g`` of eq. 10) and ``contact_speed`` (m/s over ground);
    they are 0 / False on other steps.

    ## Transition Dynamics

    Every ``dt = 0.2`` s: a PID turns the velocity errors ``(v_d - u, w_d - r)`` into the
    thrust ``tau = (tau_u, tau_r)``, clipped to +-40 N (N m); sway is not actuated. Per axis,
    ``acc = (tau - d) / m`` with damping ``d = K_dl v + K_qdl |v| v`` (eq. 36), ``acc`` clipped to
    +-5, then ``v = clip(v + dt acc, -1, 1)`` (eq. 37). The pose integrates the body velocity
    rotated into the DS frame plus the ocean current (eq. 38). The PID gains and the yaw inertia
    are not in the paper; see :class:`DockingConfig`.

    ## Reward

    Summed every step (eq. 12): ``r_dist = -rho / 30`` (eq. 4), ``r_tau = -||tau|| / 100``
    (eq. 5), ``r_entry_vel = -10 max(V - 0.3, 0) (3 - rho) / 3`` inside 3 m (eq. 6, ``V`` the
    ground speed), and on contact ``r_g = 200 g`` (eqs. 7-11) with ``g = 1`` for a perfect
    entry and ``g <= 0`` when the AUV misses the funnel.

    ## Starting State

    ``x ~ U(-30, -25)``, ``y ~ U(-7.5, 7.5)``, ``alpha ~ U(-pi/2, pi/2)``, at rest, ocean
    current ``oc_x, oc_y ~ U(-0.3, 0.3)``, all independent (Sec. 4.1). Training curricula
    (not in the paper) bias these draws: ``following_current_fraction``,
    ``lateral_current_fraction`` and ``near_start_fraction`` of :class:`DockingConfig`.

    ## Episode End

    ``terminated`` on contact: ``-0.8 <= x <= 0`` and ``-0.5 <= y <= 0.5`` (Sec. 4.1).
    ``truncated`` after 600 steps (2 min). Success (Tables 6-7): contact with ``g > 0`` and
    ground speed ``<= 0.3`` m/s (+ ``contact_speed_tolerance``).

    ## Arguments

    Args:
        num_envs: number of independent envs stepped at once (the batch size).

    Keyword Args:
        config: a :class:`DockingConfig`; defaults to the paper's values.
        device: torch device of every tensor.
        seed: seed of the env's own ``torch.Generator``; ``None`` draws one from torch's global
            generator. The same seed gives bit-identical rollouts on CPU.
        dtype: floating dtype of the simulation (float32 by default).
        compile_step: run the simulation step through ``torch.compile`` (same numbers up to
            rounding, faster for large batches; the first step pays the compilation). Not to be
            confused with TorchRL's own ``compile=`` option, which compiles the whole
            ``EnvBase.step``.
        check_finite: a debug option: after every reset and step, check the outputs and the PID's
            state for NaN and inf and raise ``FloatingPointError`` naming the entry, the first
            env holding one and its step count. Off, it costs nothing.

    Examples:
        >>> env = DockingEnv(num_envs=4, seed=0)
        >>> td = env.rollout(10, break_when_any_done=False)
        >>> td["next", "observation"].shape
        torch.Size([4, 10, 6])
    """

    batch_locked = True

    def __init__(
        self,
        num_envs: int = 1,
        *,
        config: DockingConfig | None = None,
        device: torch.device | str = "cpu",
        seed: int | None = None,
        dtype: torch.dtype = torch.float32,
        compile_step: bool = False,
        check_finite: bool = False,
    ) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, numbers.Integral):
            raise TypeError(
                f"num_envs must be a positive integer (int or numpy integer), got {num_envs!r} "
                f"({type(num_envs).__name__})"
            )
        if num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        num_envs = int(num_envs)
        if config is None:
            config = DockingConfig()
        if not isinstance(config, DockingConfig):
            raise TypeError(f"config must be a DockingConfig, got {type(config).__name__}")
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.num_envs = num_envs
        self.config = config
        self.check_finite = bool(check_finite)
        self.dtype = dtype
        self._make_specs()
        self._make_constants()
        self._transition = self._make_transition()
        if compile_step:
            self._transition = torch.compile(self._transition, dynamic=False)
        n, dev = num_envs, self.device
        self._pose = torch.zeros(n, 3, device=dev, dtype=dtype)
        self._velocity = torch.zeros(n, 3, device=dev, dtype=dtype)
        self._current = torch.zeros(n, 2, device=dev, dtype=dtype)
        self._integral = torch.zeros(n, 2, device=dev, dtype=dtype)
        self._previous_error = torch.zeros(n, 2, device=dev, dtype=dtype)
        self._step_count = torch.zeros(n, 1, device=dev, dtype=torch.int64)
        self._pinned_pose: torch.Tensor | None = None
        self._pinned_current: torch.Tensor | None = None
        self._make_realism_state()
        if seed is None:
            seed = int(torch.randint(0, 2**62, (1,)).item())
        self.set_seed(seed)

    # -- set-up ---------------------------------------------------------------------------
    def _make_constants(self) -> None:
        cfg, dev, dtype = self.config, self.device, self.dtype

        def vector(*values: float) -> torch.Tensor:
            return torch.tensor(values, device=dev, dtype=dtype)

        self._kp = vector(cfg.surge_kp, cfg.yaw_kp)
        self._ki = vector(cfg.surge_ki, cfg.yaw_ki)
        self._kd = vector(cfg.surge_kd, cfg.yaw_kd)
        self._inertia = vector(cfg.mass, cfg.mass, cfg.yaw_inertia)
        self._action_low = vector(*cfg.action_low)
        self._action_high = vector(*cfg.action_high)
        self._noise_std = vector(*cfg.observation_noise_std)

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

    def _make_specs(self) -> None:
        cfg, n, dev, dtype = self.config, self.num_envs, self.device, self.dtype

        def unbounded(*shape: int, dt: torch.dtype = dtype) -> Unbounded:
            return Unbounded(shape=(n, *shape), device=dev, dtype=dt)

        def flag() -> Binary:
            return Binary(n=1, shape=(n, 1), device=dev, dtype=torch.bool)

        self.observation_spec = Composite(
            observation=unbounded(OBSERVATION_DIM),
            ocean_current=unbounded(2),
            true_state=unbounded(TRUE_STATE_DIM),
            step_count=unbounded(1, dt=torch.int64),
            success=flag(),
            contact_score=unbounded(1),
            contact_speed=unbounded(1),
            shape=(n,),
            device=dev,
        )
        if cfg.sensor_timing:
            self.observation_spec["sensor_age"] = unbounded(len(SENSORS))
        if cfg.current_model:
            self.observation_spec["true_ocean_current"] = unbounded(2)
        self.action_spec = Bounded(
            low=torch.tensor(cfg.action_low, dtype=dtype).expand(n, ACTION_DIM).clone(),
            high=torch.tensor(cfg.action_high, dtype=dtype).expand(n, ACTION_DIM).clone(),
            shape=(n, ACTION_DIM),
            device=dev,
            dtype=dtype,
        )
        self.reward_spec = unbounded(1)
        self.full_done_spec = Composite(
            done=flag(), terminated=flag(), truncated=flag(), shape=(n,), device=dev
        )

    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            return
        self.rng = torch.Generator(device=self.device)
        self.rng.manual_seed(int(seed))
        self.realism_rng = torch.Generator(device=self.device)
        self.realism_rng.manual_seed((int(seed) + REALISM_SEED_OFFSET) % 2**63)

    def set_initial_state(
        self, pose: torch.Tensor | None = None, ocean_current: torch.Tensor | None = None
    ) -> None:
        """Pin what the following resets start from, instead of sampling it (Sec. 4.1).

        Args:
            pose: ``(num_envs, 3)`` ``(x, y, alpha)`` start poses, or ``None`` to sample again.
            ocean_current: ``(num_envs, 2)`` currents, or ``None`` to sample again.

        Used for the success map over currents (Figure 9) and for chosen trajectories
        (Figure 10). The random draws still happen, so the env's random stream is the same
        whether or not a state is pinned.
        """

        def check(value, size, name):
            if value is None:
                return None
            value = torch.as_tensor(value, dtype=self.dtype, device=self.device)
            value = value.expand(self.num_envs, size) if value.dim() == 1 else value
            if value.shape != (self.num_envs, size):
                raise ValueError(
                    f"{name} must be ({self.num_envs}, {size}), got {tuple(value.shape)}"
                )
            if not bool(torch.isfinite(value).all()):
                raise ValueError(f"{name} must be finite")
            return value.clone()

        self._pinned_pose = check(pose, 3, "pose")
        self._pinned_current = check(ocean_current, 2, "ocean_current")

    @property
    def vehicle_scales(self) -> torch.Tensor | None:
        """``(num_envs, 5)`` this episode's factors on mass, damping, thrust, PID gains and
        response time of each env (:attr:`DockingConfig.mass_scale` and the following), a
        copy; ``None`` when no dynamics-mismatch option is on."""
        return None if self._vehicle is None else self._scales.clone()

    #: the simulator's whole state, as :meth:`get_state` returns it (``step_count`` is int64),
    #: and the attribute holding each entry
    STATE_KEYS = ("pose", "velocity", "ocean_current", "integral", "previous_error", "step_count")
    _STATE_ATTRIBUTES = (
        "_pose",
        "_velocity",
        "_current",
        "_integral",
        "_previous_error",
        "_step_count",
    )

    def get_state(self) -> TensorDict:
        """The simulator's whole state, a copy: ``pose`` ``(n, 3)``, ``velocity`` ``(n, 3)``,
        ``ocean_current`` ``(n, 2)``, the PID's ``integral`` and ``previous_error`` ``(n, 2)``
        and ``step_count`` ``(n, 1)``. With :meth:`set_state` and :meth:`simulate` it lets a
        planner roll the dynamics forward from any state (:mod:`dockingrl.planning`)."""
        pairs = zip(self.STATE_KEYS, self._STATE_ATTRIBUTES, strict=True)
        return TensorDict(
            {key: getattr(self, name).clone() for key, name in pairs},
            batch_size=self.batch_size,
            device=self.device,
        )

    def set_state(self, state: TensorDictBase) -> None:
        """Continue from ``state`` (as :meth:`get_state` returns it, same batch size and
        shapes). This is the bare simulator's state: the transforms above it (the EKF's
        estimate, the previous command, a held action, reward sums) keep their own."""
        missing = [k for k in self.STATE_KEYS if k not in state.keys()]
        if missing:
            raise KeyError(f"state lacks {missing}; expected {list(self.STATE_KEYS)}")
        if tuple(state.batch_size) != tuple(self.batch_size):
            raise ValueError(
                f"state batch size {tuple(state.batch_size)} != env's {tuple(self.batch_size)}"
            )
        values = {}
        for key, name in zip(self.STATE_KEYS, self._STATE_ATTRIBUTES, strict=True):
            value, expected = state[key], getattr(self, name)
            if value.shape != expected.shape:
                raise ValueError(
                    f"state[{key!r}] must have shape {tuple(expected.shape)}, "
                    f"got {tuple(value.shape)}"
                )
            if key == "step_count":
                if value.is_floating_point() or value.is_complex() or bool((value < 0).any()):
                    raise ValueError("state['step_count'] must hold integers >= 0")
            elif not bool(torch.isfinite(value).all()):
                raise ValueError(f"state[{key!r}] must be finite")
            values[name] = value.to(device=self.device, dtype=expected.dtype).clone()
        for name, value in values.items():
            setattr(self, name, value)

    def simulate(
        self, state: TensorDictBase, action: torch.Tensor
    ) -> tuple[TensorDict, dict[str, torch.Tensor]]:
        """One noise-free step of the dynamics from ``state`` (any batch size), without
        touching the env's own state: ``(next_state, out)`` with ``out`` the step's entries
        (``reward``, ``terminated``, ``success``, ``contact_score``, ``contact_speed``, ...).
        ``action`` ``(batch, 2)`` is clipped to the bounds of eq. 3, as :meth:`step` does."""
        action = self._validated_action(action, state.batch_size)
        pose, velocity, integral, error, step_count, out = self._transition(
            state["pose"],
            state["velocity"],
            state["ocean_current"],
            state["integral"],
            state["previous_error"],
            state["step_count"],
            action,
            None,
        )
        values = (pose, velocity, state["ocean_current"], integral, error, step_count)
        next_state = TensorDict(
            dict(zip(self.STATE_KEYS, values, strict=True)),
            batch_size=state.batch_size,
            device=self.device,
        )
        return next_state, out

    # -- helpers -------------------------------------------------------------------------
    def _clean_observation(self) -> torch.Tensor:
        """Eq. 2 on the true state."""
        x, y, alpha = self._pose.unbind(-1)
        u, v, r = self._velocity.unbind(-1)
        return observation_from_state(x, y, alpha, u, v, r, self._current)

    def _observe(self) -> torch.Tensor:
        """Eq. 2 on the true state, plus the Gaussian noise of Table 2 when enabled."""
        obs = self._clean_observation()
        if not self.config.noise:
            return obs
        return noisy_observation(obs, self._sample_noise(), self._noise_std)

    def _output(self, **entries: torch.Tensor) -> TensorDict:
        # the env's state tensors are replaced, never modified in place: no copies needed
        current = self._current
        if self.config.current_model:
            current = self._known_current
            entries["true_ocean_current"] = self._current
        if self.config.sensor_timing:
            entries["sensor_age"] = self._sensor_steps.to(self.dtype) * self.config.dt
        return TensorDict(
            {"ocean_current": current, "step_count": self._step_count, **entries},
            batch_size=self.batch_size,
            device=self.device,
        )

    # -- EnvBase API ---------------------------------------------------------------------
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        cfg, n, dev, dtype, gen = self.config, self.num_envs, self.device, self.dtype, self.rng
        pose = torch.stack(
            (
                _uniform(*cfg.init_x, n, gen, dev, dtype),
                _uniform(*cfg.init_y, n, gen, dev, dtype),
                _uniform(*cfg.init_heading, n, gen, dev, dtype),
            ),
            dim=-1,
        )
        current = torch.stack(
            (
                _uniform(*cfg.ocean_current_range, n, gen, dev, dtype),
                _uniform(*cfg.ocean_current_range, n, gen, dev, dtype),
            ),
            dim=-1,
        )
        if cfg.following_current_fraction > 0:
            # reflect oc_x into the upper half of the range: still uniform there
            mid = 0.5 * sum(cfg.ocean_current_range)
            follow = _uniform(0.0, 1.0, n, gen, dev, dtype) < cfg.following_current_fraction
            upper = mid + (current[:, 0] - mid).abs()
            current[:, 0] = torch.where(follow, upper, current[:, 0])
        if cfg.lateral_current_fraction > 0:
            # fold |oc_y - mid| into the outer half of the range, sign kept: uniform there
            low, high = cfg.ocean_current_range
            mid, half = 0.5 * (low + high), 0.5 * (high - low)
            strong = _uniform(0.0, 1.0, n, gen, dev, dtype) < cfg.lateral_current_fraction
            offset = current[:, 1] - mid
            outer = mid + torch.sign(offset) * (0.5 * half + 0.5 * offset.abs())
            current[:, 1] = torch.where(strong, outer, current[:, 1])
        if cfg.near_start_fraction > 0:
            near = _uniform(0.0, 1.0, n, gen, dev, dtype) < cfg.near_start_fraction
            near_xy = torch.stack(
                (
                    _uniform(*cfg.near_start_x, n, gen, dev, dtype),
                    _uniform(*cfg.near_start_y, n, gen, dev, dtype),
                ),
                dim=-1,
            )
            pose[:, :2] = torch.where(near.unsqueeze(-1), near_xy, pose[:, :2])
        if self._pinned_pose is not None:
            pose = self._pinned_pose
        if self._pinned_current is not None:
            current = self._pinned_current
        current_mean = current
        if cfg.current_time_constant > 0:
            deviation = torch.randn(n, 2, generator=self.realism_rng, device=dev, dtype=dtype)
            current = current_mean + cfg.current_variation_std * deviation
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is None:
            self._pose = pose
            self._current = current
            self._velocity = torch.zeros_like(self._velocity)
            self._integral = torch.zeros_like(self._integral)
            self._previous_error = torch.zeros_like(self._previous_error)
            self._step_count = torch.zeros_like(self._step_count)
        else:
            mask = mask.reshape(n, 1)
            self._pose = torch.where(mask, pose, self._pose)
            self._current = torch.where(mask, current, self._current)
            self._velocity = self._velocity.masked_fill(mask, 0.0)
            self._integral = self._integral.masked_fill(mask, 0.0)
            self._previous_error = self._previous_error.masked_fill(mask, 0.0)
            self._step_count = self._step_count.masked_fill(mask, 0)
        if cfg.realistic:
            rows = torch.ones(n, 1, dtype=torch.bool, device=dev) if mask is None else mask
            observation = self._reset_realism(rows, current_mean)
        else:
            observation = self._observe()
        false = torch.zeros(n, 1, dtype=torch.bool, device=dev)
        zero = torch.zeros(n, 1, dtype=dtype, device=dev)
        out = self._output(
            observation=observation,
            true_state=torch.cat((self._pose, self._velocity), dim=-1),
            done=false,
            terminated=false.clone(),
            truncated=false.clone(),
            success=false.clone(),
            contact_score=zero,
            contact_speed=zero.clone(),
        )
        if self.check_finite:
            self._check_finite(out, "reset")
        return out

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

    def _check_finite(self, out: TensorDictBase, when: str) -> None:
        """Raise ``FloatingPointError`` at the first entry holding a NaN or inf (``check_finite``):
        the state (``true_state``, the PID's ``integral`` and ``previous_error``) before what
        derives from it, so that the entry named is where it began."""
        entries = {
            "true_state": out["true_state"],
            "integral": self._integral,
            "previous_error": self._previous_error,
            **{key: value for key, value in out.items() if value.is_floating_point()},
        }
        for key, value in entries.items():
            finite = torch.isfinite(value).reshape(self.num_envs, -1).all(-1)
            if not bool(finite.all()):
                env = int((~finite).nonzero()[0, 0])
                step = int(self._step_count[env, 0])
                raise FloatingPointError(
                    f"DockingEnv check_finite: {key!r} is not finite after {when} in env {env} "
                    f"at its step {step}: {value[env].tolist()}"
                )

    def _validated_action(
        self, action: torch.Tensor, batch_size: torch.Size | None = None
    ) -> torch.Tensor:
        """``action`` checked (shape ``(*batch_size, 2)``, the env's batch by default; finite)
        and clipped to the bounds of eq. 3, on the env's device and dtype."""
        batch = tuple(self.batch_size if batch_size is None else batch_size)
        expected = (*batch, ACTION_DIM)
        if not isinstance(action, torch.Tensor):
            raise TypeError(
                f"action must be a torch.Tensor of shape {expected}, got {type(action).__name__}"
            )
        if action.dtype == torch.bool or action.is_complex():
            raise ValueError(f"action must be a real-valued tensor, got dtype {action.dtype}")
        if tuple(action.shape) != expected:
            raise ValueError(
                f"action must have shape {expected} (batch, [v_d, w_d]), got {tuple(action.shape)}"
            )
        finite = torch.isfinite(action).reshape(-1, ACTION_DIM).all(-1)
        if not bool(finite.all()):
            index = int((~finite).nonzero()[0, 0])
            raise ValueError(
                f"action must be finite, no NaN or inf; batch entry {index} (flattened) is "
                f"{action.reshape(-1, ACTION_DIM)[index].tolist()}"
            )
        action = action.to(device=self.device, dtype=self.dtype)
        return clip_action(action, self._action_low, self._action_high)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = self._validated_action(tensordict.get("action"))
        if self.config.realistic:
            return self._step_realistic(action)
        noise = self._sample_noise() if self.config.noise else None
        out = self._advance(action, noise)
        out = self._output(**out)
        if self.check_finite:
            self._check_finite(out, "step")
        return out

    def _advance(self, action: torch.Tensor, noise, vehicle=None) -> dict:
        """Move the simulator's state one :meth:`_transition` on and return its outputs."""
        (
            self._pose,
            self._velocity,
            self._integral,
            self._previous_error,
            self._step_count,
            out,
        ) = self._transition(
            self._pose,
            self._velocity,
            self._current,
            self._integral,
            self._previous_error,
            self._step_count,
            action,
            noise,
            vehicle,
        )
        return out

    def _step_realistic(self, action: torch.Tensor) -> TensorDictBase:
        """:meth:`_step` with realism options on: the episode's vehicle, the sensors' timing and
        faults, the current's variation and the vehicle's belief about it. Table 2's noise is
        drawn as in the paper's task, the rest from :attr:`realism_rng`."""
        cfg = self.config
        noise = self._sample_noise() if cfg.noise else None
        out = self._advance(action, None, self._vehicle)
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

    def _sample_noise(self) -> torch.Tensor:
        shape = (self.num_envs, OBSERVATION_DIM)
        return torch.randn(shape, generator=self.rng, device=self.device, dtype=self.dtype)

    def _make_transition(self):
        """The whole simulation step as one pure tensor function (what ``compile=True``
        hands to ``torch.compile``)."""
        cfg = self.config
        kp, ki, kd, inertia = self._kp, self._ki, self._kd, self._inertia
        noise_std = self._noise_std
        speed_limit = cfg.entry_speed_max + cfg.contact_speed_tolerance

        def transition(
            pose,
            velocity,
            current,
            integral,
            previous_error,
            step_count,
            action,
            noise,
            vehicle=None,
        ):
            error = action - velocity[:, 0::2]
            if vehicle is None:
                tau, integral = pid_thrust(
                    error, integral, previous_error, kp, ki, kd, cfg.dt, cfg.max_thrust
                )
                masses, damping = inertia, (cfg.linear_damping, cfg.quadratic_damping)
            else:
                thrust = vehicle["max_thrust"]
                tau, integral = pid_thrust(
                    error,
                    integral,
                    previous_error,
                    vehicle["kp"],
                    vehicle["ki"],
                    vehicle["kd"],
                    cfg.dt,
                    thrust,
                )
                tau = limit_thrust(tau, thrust, cfg.reverse_thrust_loss, cfg.turning_surge_loss)
                masses, damping = vehicle["inertia"], (vehicle["linear"], vehicle["quadratic"])
            tau3 = torch.stack((tau[:, 0], torch.zeros_like(tau[:, 0]), tau[:, 1]), dim=-1)
            velocity = velocity_update(
                velocity,
                tau3,
                masses,
                *damping,
                cfg.max_acceleration,
                cfg.max_velocity,
                cfg.dt,
            )
            pose = pose_update(pose, velocity, current, cfg.dt)
            step_count = step_count + 1

            x, y, alpha = pose.unbind(-1)
            u, v, r = velocity.unbind(-1)
            observation = observation_from_state(x, y, alpha, u, v, r, current)
            rho, vx, vy = observation[:, 0], observation[:, 3], observation[:, 4]
            speed = torch.sqrt(vx * vx + vy * vy)
            contact = (
                (x >= cfg.dock_x[0])
                & (x <= cfg.dock_x[1])
                & (y >= cfg.dock_y[0])
                & (y <= cfg.dock_y[1])
            )
            score = contact_score(x, y, alpha, cfg.aligned_weight, cfg.misaligned_weight)
            score = torch.where(contact, score, torch.zeros_like(score))
            reward = self.step_reward(rho, tau, speed, score)
            if noise is not None:
                observation = noisy_observation(observation, noise, noise_std)
            terminated = contact.unsqueeze(-1)
            truncated = (step_count >= cfg.max_steps) & ~terminated
            success = contact & (score > 0) & (speed <= speed_limit)
            out = {
                "observation": observation,
                "true_state": torch.cat((pose, velocity), dim=-1),
                "reward": reward.unsqueeze(-1),
                "done": terminated | truncated,
                "terminated": terminated,
                "truncated": truncated,
                "success": success.unsqueeze(-1),
                "contact_score": score.unsqueeze(-1),
                "contact_speed": torch.where(contact, speed, torch.zeros_like(speed)).unsqueeze(-1),
            }
            return pose, velocity, integral, error, step_count, out

        return transition

    def step_reward(
        self, rho: torch.Tensor, tau: torch.Tensor, speed: torch.Tensor, score: torch.Tensor
    ) -> torch.Tensor:
        """Eq. 12: ``r = r_dist + r_tau + r_entry_vel + r_g`` (``score`` is 0 off contact)."""
        cfg = self.config
        return (
            distance_reward(rho, cfg.max_dist)
            + thrust_reward(tau, cfg.thrust_weight)
            + entry_velocity_reward(
                speed, rho, cfg.entry_speed_max, cfg.approach_distance, cfg.entry_speed_weight
            )
            + contact_reward(score, cfg.contact_weight)
        )
