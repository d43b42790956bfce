"""The batched docking environment (Sec. 3 and 4.1 of the paper), a TorchRL ``EnvBase``."""

from __future__ import annotations

import numbers

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import EnvBase

from dockingrl.env.checks import (
    available_device,
    check_finite,
    checked_seed,
    compiled,
    validated_action,
)
from dockingrl.env.config import DockingConfig, config_or_default
from dockingrl.env.dynamics import noisy_observation, observation_from_state
from dockingrl.env.realism_env import RealismMixin
from dockingrl.env.reward import (
    contact_reward,
    distance_reward,
    entry_velocity_reward,
    thrust_reward,
)
from dockingrl.env.specs import ACTION_DIM, OBSERVATION_DIM, TRUE_STATE_DIM, docking_specs
from dockingrl.env.starts import paper_start, pinned, training_start
from dockingrl.env.state_access import StateAccessMixin
from dockingrl.env.step import make_transition

__all__ = ["ACTION_DIM", "OBSERVATION_DIM", "REALISM_SEED_OFFSET", "TRUE_STATE_DIM", "DockingEnv"]

#: added to the env's seed for its realism generator (:attr:`DockingEnv.realism_rng`)
REALISM_SEED_OFFSET = 0x5EA1


class DockingEnv(RealismMixin, StateAccessMixin, EnvBase):
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
        compile_step: run the simulation step, of either vehicle, through ``torch.compile``
            (same numbers up to rounding, faster; the first step pays the compilation). The
            Fossen vehicle's quantised thruster commands can turn a rounding difference into a
            step of thrust, so its long rollouts part from the eager ones. Not to be
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
        config = config_or_default(config)
        available_device(str(device))
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.num_envs = num_envs
        self.config = config
        self.check_finite = bool(check_finite)
        self.dtype = dtype
        self._make_specs()
        self._make_constants()
        self.compile_step = bool(compile_step)
        self._transition = self._make_transition()
        if compile_step:
            self._transition = compiled(self._transition, self.device, dynamic=False)
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

    def _make_specs(self) -> None:
        specs = docking_specs(self.config, self.num_envs, self.device, self.dtype)
        for name, spec in specs.items():
            setattr(self, name, spec)

    def _set_seed(self, seed: int | None) -> None:
        if seed is None:
            return
        seed = checked_seed(seed)
        self.rng = torch.Generator(device=self.device)
        self.rng.manual_seed(seed)
        self.realism_rng = torch.Generator(device=self.device)
        self.realism_rng.manual_seed((seed + REALISM_SEED_OFFSET) % 2**63)

    def set_initial_state(
        self, pose: torch.Tensor | None = None, ocean_current: torch.Tensor | None = None
    ) -> None:
        """Pin what the following resets start from, instead of sampling it (Sec. 4.1).

        Args:
            pose: ``(num_envs, 3)`` ``(x, y, alpha)`` start poses (``(3,)``: one for every env),
                or ``None`` to sample again.
            ocean_current: ``(num_envs, 2)`` currents, or ``None`` to sample again. Any
                finite current, also one outside ``ocean_current_range`` (to test a policy
                beyond what it trained on; the Gymnasium env, whose users pin a current per
                reset, keeps to the range).

        Used for the success map over currents (Figure 9) and for chosen trajectories
        (Figure 10). The random draws still happen, so the env's random stream is the same
        whether or not a state is pinned.
        """
        n, dev, dtype = self.num_envs, self.device, self.dtype
        self._pinned_pose = pinned(pose, 3, "pose", n, dev, dtype)
        self._pinned_current = pinned(ocean_current, 2, "ocean_current", n, dev, dtype)

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
        pose, current = paper_start(cfg, n, gen, dev, dtype)
        training_start(cfg, pose, current, gen, dev, dtype)
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
        check_finite(entries, self._step_count, when)

    def _validated_action(
        self, action: torch.Tensor, batch_size: torch.Size | None = None
    ) -> torch.Tensor:
        """``action`` checked (shape ``(*batch_size, 2)``, the env's batch by default; finite)
        and clipped to the bounds of eq. 3, on the env's device and dtype."""
        batch = tuple(self.batch_size if batch_size is None else batch_size)
        low, high = self._action_low, self._action_high
        return validated_action(action, batch, self.device, self.dtype, low, high)

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

    def _sample_noise(self) -> torch.Tensor:
        shape = (self.num_envs, OBSERVATION_DIM)
        return torch.randn(shape, generator=self.rng, device=self.device, dtype=self.dtype)

    def _make_transition(self):
        """The whole simulation step as one pure tensor function (:func:`make_transition`)."""
        gains = (self._kp, self._ki, self._kd, self._inertia)
        return make_transition(self.config, *gains, self._noise_std, self.step_reward)

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
