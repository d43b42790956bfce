"""A single-env Gymnasium view of :class:`DockingEnv` (numpy in, numpy out), stepped without the
TorchRL machinery, in one of two ways:

- ``fast=False``: each step calls the batched env's own transition function on tensors of one
  env, with no ``TensorDict`` and no spec checks: the same numbers as ``DockingEnv(1)``, bit
  for bit;
- ``fast=True``: each step calls :func:`dockingrl.env.transition.paper_step`, the same equation
  functions (:mod:`dockingrl.env.dynamics`, :mod:`dockingrl.env.reward`) on Python floats, with
  no tensor at all but the sensor noise, drawn from the env's own generator as ``DockingEnv(1)``
  draws it: the same numbers up to float32 rounding (the floats are float64), several times
  faster.

The registered ``dockingrl/Docking-v0`` (:mod:`dockingrl.gym`) builds on it with the paper's
four scenarios::

    import gymnasium, dockingrl
    env = gymnasium.make("dockingrl/Docking-v0", scenario="compound")
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDict

from dockingrl.env.checks import compiled
from dockingrl.env.config import DockingConfig
from dockingrl.env.docking import DockingEnv
from dockingrl.env.specs import ACTION_DIM, OBSERVATION_DIM
from dockingrl.env.state_access import StateAccessMixin
from dockingrl.env.transition import SimulatorState, paper_step

#: the entries of ``info`` read from the env's outputs as Python numbers
_INFO_NUMBERS = (("success", bool), ("contact_score", float), ("contact_speed", float))
#: the attributes of :class:`DockingEnv` that hold its state, in the order of
#: :meth:`DockingGymEnv._tensor_step`
_SIMULATOR_STATE = StateAccessMixin._STATE_ATTRIBUTES
#: what ``reset(options=...)`` accepts: a start pose and a current for that episode
RESET_OPTIONS = ("pose", "ocean_current")

#: why a Gymnasium env refuses the realism options
PAPER_TASK_ONLY = (
    "the Gymnasium env steps the paper's task, on either vehicle (vehicle='paper', 'fossen' "
    "or 'mixed'); for the other realism options of DockingConfig (docs/realism.md) use "
    "dockingrl.make_env"
)


def gym_task_problem(config: DockingConfig) -> str | None:
    """Why a Gymnasium env cannot step ``config`` (``None`` if it can): the paper's task on
    the paper's model or the Fossen vehicle (docs/vehicles.md), no other realism option."""
    return PAPER_TASK_ONLY if config.replace(vehicle="paper", scale_fossen=True).realistic else None


def reading_bounds() -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` float32 of one 6-number reading of eq. 2 (raw, true or filtered):
    range >= 0, bearing and heading in [-pi, pi], velocities unbounded."""
    inf, pi = np.inf, np.float32(math.pi)
    return (
        np.array([0.0, -pi, -pi, -inf, -inf, -inf], dtype=np.float32),
        np.array([inf, pi, pi, inf, inf, inf], dtype=np.float32),
    )


def action_space(config: DockingConfig) -> spaces.Box:
    """The float32 box of eq. 3 for ``config``'s command bounds."""
    return spaces.Box(
        low=np.array(config.action_low, dtype=np.float32),
        high=np.array(config.action_high, dtype=np.float32),
        dtype=np.float32,
    )


def real_array(value, shape: tuple, must: str, ragged: str) -> np.ndarray:
    """``value`` as a float64 array of ``shape``: real numbers (integers or floats, not
    booleans, complex or text), else a one-line ``ValueError`` that starts with ``must`` (what
    the value must be; ``ragged`` names a value of uneven rows)."""
    try:
        array = np.asarray(value)
    except ValueError:
        raise ValueError(f"{must}, got a ragged {ragged}") from None
    if array.dtype.kind not in "iuf":
        raise ValueError(f"{must}, got dtype {array.dtype} of shape {array.shape}")
    if array.shape != shape:
        raise ValueError(f"{must}, got shape {array.shape}")
    return array.astype(np.float64)


def validated_action(action, config: DockingConfig) -> np.ndarray:
    """``action`` as the float32 ``(2,)`` command the env applies: real numbers of shape ``(2,)``
    exactly (an array, list or tuple), finite, clipped to the bounds in float64 so that a finite
    value beyond float32's range is clipped like any other. Anything else is a one-line
    ``ValueError``."""
    expected = f"a finite real action of shape ({ACTION_DIM},) [v_d, w_d]"
    if action is None:
        raise ValueError(f"action must be {expected}, got None")
    values = real_array(action, (ACTION_DIM,), f"action must be {expected}", repr(action))
    values = values.tolist()
    if not all(map(math.isfinite, values)):
        raise ValueError(f"action must be {expected}, got {values}")
    clipped = map(min, map(max, values, config.action_low), config.action_high)
    return np.array(tuple(clipped), dtype=np.float32)


class DockingGymEnv(gymnasium.Env):
    """The bare docking task as a ``gymnasium.Env``; see :class:`DockingEnv` for the full
    description.

    Observations are float32 ``(6,)`` (eq. 2; noisy unless ``config.noise`` is False), actions
    ``(2,)`` (eq. 3, clipped to the bounds; any real dtype; a wrong shape, a bool, complex or
    text dtype, NaN or inf raise ``ValueError``). ``info`` holds ``ocean_current``,
    ``true_state``, ``step_count`` and ``success``, ``contact_score`` and ``contact_speed``
    (meaningful on the last step). ``reset(options={"pose": (x, y, alpha), "ocean_current":
    (oc_x, oc_y)})`` starts that episode there (either key alone too).

    Args:
        config: the env's constants (:class:`DockingConfig`).

    Keyword Args:
        simulator: a ``DockingEnv`` of one env to step instead of a new one built from
            ``config`` (the base env of a :func:`dockingrl.make_env` pipeline).
        compile: ``torch.compile`` the step (:meth:`_tensor_step`): the first step compiles
            (about 20 s on a 2-core CPU), then a step costs several times less.
        fast: step on Python floats (:func:`~dockingrl.env.transition.paper_step`) instead of
            tensors: the same functions and noise draws, the numbers equal to float32 rounding
            (see the module's docstring). Not with ``compile``. ``None`` (default): fast
            unless ``compile``; ``False`` gives the batched env's numbers bit for bit.
    """

    metadata = {"render_modes": []}

    def __init__(
        self,
        config: DockingConfig | None = None,
        *,
        simulator: DockingEnv | None = None,
        compile: bool = False,
        fast: bool | None = None,
    ) -> None:
        if fast is None:
            fast = not compile
        if simulator is None:
            simulator = DockingEnv(1, config=config, seed=0)
        elif not isinstance(simulator, DockingEnv) or simulator.num_envs != 1:
            raise ValueError(f"simulator must be a DockingEnv of 1 env, got {simulator!r}")
        problem = gym_task_problem(simulator.config)
        if problem is not None:
            raise ValueError(problem)
        #: the Fossen vehicle steps through the batched env's own ``_step``
        self._through_env = simulator.config.vehicle != "paper"
        if self._through_env and (fast or compile):
            raise ValueError(
                f"vehicle={simulator.config.vehicle!r} steps on tensors through the batched env: "
                "fast=True and compile=True step the paper's model only"
            )
        self._env = simulator
        self.config = simulator.config
        self.action_space = action_space(self.config)
        low, high = reading_bounds()
        self.observation_space = spaces.Box(low, high, shape=(OBSERVATION_DIM,), dtype=np.float32)
        #: the last reset's or step's entries, keyed as the batched env's tensordict
        self._td: Mapping[str, torch.Tensor] | None = None
        #: a scenario's own state (the filter's), carried from step to step
        self._extra: tuple = ()
        self._step_function = self._tensor_step
        if compile and fast:
            raise ValueError(
                "compile=True compiles the tensor step, fast=True steps on floats: choose one"
            )
        if compile:
            self._step_function = compiled(self._tensor_step, simulator.device, dynamic=False)
        self.fast = bool(fast)
        #: the fast path's constants as floats (the simulator's float32 values) and its state
        sim = simulator
        self._gains = tuple(tuple(t.tolist()) for t in (sim._kp, sim._ki, sim._kd, sim._inertia))
        self._noise_std = tuple(sim._noise_std.tolist())
        self._state: SimulatorState | None = None
        #: the last reset's or step's ``info``
        self._last_info: dict[str, Any] | None = None
        #: whether the last step ended the episode (the next step needs a reset first)
        self._ended = False

    # -- the step as a pure tensor function, and the hooks of the scenarios ---------------
    def _observe_reset(self, out: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The policy's ``(1, k)`` observation after a reset (a scenario also starts its own
        state, :attr:`_extra`, here)."""
        return out["observation"]

    def _start_fast(self) -> None:
        """Carry a scenario's own state (the filter's) from :attr:`_extra` over to floats, after
        a reset of the fast path."""

    def _observe_fast(self, observation: tuple, action: tuple) -> tuple:
        """The policy's observation after a fast step from the env's ``observation`` under
        the applied ``action`` (a scenario steps its own state here)."""
        return observation

    def _tensor_step(
        self, state: tuple, extra: tuple, action: torch.Tensor, noise: torch.Tensor | None
    ) -> tuple[tuple, tuple, torch.Tensor, dict[str, torch.Tensor]]:
        """One step as a pure tensor function (what ``compile=True`` compiles): the
        simulator's ``state`` ``(pose, velocity, current, integral, previous_error,
        step_count)`` and a scenario's own state ``extra`` under the applied ``(1, 2)``
        ``action`` and the step's standard-normal sensor ``noise`` -> ``(state, extra,
        observation, out)``, ``out`` the batched env's step outputs. Here: the batched env's
        own transition."""
        pose, velocity, current, integral, error, step_count = state
        pose, velocity, integral, error, step_count, out = self._env._transition(
            pose, velocity, current, integral, error, step_count, action, noise
        )
        state = (pose, velocity, current, integral, error, step_count)
        return state, extra, out["observation"], out

    # -- Gymnasium API ----------------------------------------------------------------------
    def _info(self, out: Mapping[str, torch.Tensor]) -> dict[str, Any]:
        info: dict[str, Any] = {
            "ocean_current": out["ocean_current"][0].numpy().copy(),
            "true_state": out["true_state"][0].numpy().copy(),
            "step_count": int(out["step_count"]),
        }
        for key, kind in _INFO_NUMBERS:
            info[key] = kind(out[key])
        return info

    def _pin(self, options: Mapping | None) -> None:
        """Pin this episode's start to ``options``' ``pose`` and ``ocean_current`` (checked:
        3 and 2 finite numbers, the current within ``ocean_current_range``)."""
        if not options:
            self._env.set_initial_state(None, None)
            return
        if not isinstance(options, Mapping) or set(options) - set(RESET_OPTIONS):
            raise ValueError(
                f"reset options must be a mapping with keys among {', '.join(RESET_OPTIONS)}, "
                f"got {options!r}"
            )
        pinned = {}
        low, high = self.config.ocean_current_range
        for key, size, what in (("pose", 3, "(x, y, alpha)"), ("ocean_current", 2, "(oc_x, oc_y)")):
            value = options.get(key)
            if value is None:
                continue
            try:
                array = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError):
                array = np.full(0, np.nan)
            if array.shape != (size,) or not np.isfinite(array).all():
                raise ValueError(
                    f"reset options[{key!r}] must be {what}, {size} finite numbers, got {value!r}"
                )
            if key == "ocean_current" and not ((low <= array) & (array <= high)).all():
                raise ValueError(
                    f"reset options['ocean_current'] must lie in ocean_current_range "
                    f"[{low:g}, {high:g}] m/s, got {value!r}"
                )
            pinned[key] = torch.from_numpy(array)
        self._env.set_initial_state(pinned.get("pose"), pinned.get("ocean_current"))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._env.set_seed(seed)
        elif self._td is None:
            self._env.set_seed(int(self.np_random.integers(0, 2**62)))
        self._pin(options)
        with torch.inference_mode():
            out = self._env._reset()
            self._env.set_initial_state(None, None)
            observation = self._observe_reset(out)
        self._td = out
        if self.fast:
            sim = self._env
            entries = (sim._pose, sim._velocity, sim._current, sim._integral, sim._previous_error)
            floats = [value for t in entries for value in t[0].tolist()]
            self._state = SimulatorState(*floats, 0)
            self._start_fast()
        self._last_info = self._info(out)
        self._ended = False
        return observation[0].numpy().copy(), self._last_info

    def _action(self, action) -> np.ndarray:
        return validated_action(action, self.config)

    def _fast_step(self, action):
        applied = tuple(self._action(action).tolist())
        sim = self._env
        noise = tuple(sim._sample_noise()[0].tolist()) if self.config.noise else None
        state, out = paper_step(
            self.config, self._gains, self._state, applied, sim.step_reward, noise, self._noise_std
        )
        self._state = state
        observation = self._observe_fast(out.observation, applied)
        self._last_info = info = {
            "ocean_current": np.array((state.oc_x, state.oc_y), dtype=np.float32),
            "true_state": np.array(state[:6], dtype=np.float32),
            "step_count": state.step_count,
            "success": bool(out.success),
            "contact_score": float(out.contact_score),
            "contact_speed": float(out.contact_speed),
        }
        return (
            np.array(observation, dtype=np.float32),
            float(out.reward),
            bool(out.terminated),
            bool(out.truncated),
            info,
        )

    def step(self, action):
        if self._last_info is None:
            raise RuntimeError("call reset() before step()")
        if self._ended:
            raise RuntimeError("the episode has ended (terminated or truncated): call reset()")
        result = self._fast_step(action) if self.fast else self._tensor_step_once(action)
        self._ended = result[2] or result[3]
        return result

    def close(self) -> None:
        """End the env: a step needs a reset first."""
        self._last_info, self._ended = None, False

    def _observe_step(
        self, observation: torch.Tensor, current: torch.Tensor, action: torch.Tensor, extra: tuple
    ) -> tuple[torch.Tensor, tuple]:
        """The policy's ``(1, k)`` observation after a step from the env's ``observation``, the
        ``current`` it reports and the applied ``action``, and a scenario's own state ``extra``
        stepped (a scenario's filter runs here)."""
        return observation, extra

    def _tensor_step_once(self, action):
        applied = torch.from_numpy(self._action(action)).reshape(1, ACTION_DIM)
        sim = self._env
        if self._through_env:
            with torch.inference_mode():
                out = sim._step(TensorDict({"action": applied}, batch_size=[1]))
                observation, self._extra = self._observe_step(
                    out["observation"], out["ocean_current"], applied, self._extra
                )
            return self._stepped(observation, out)
        with torch.inference_mode():
            noise = sim._sample_noise() if sim.config.noise else None
            state = tuple(getattr(sim, name) for name in _SIMULATOR_STATE)
            state, self._extra, observation, out = self._step_function(
                state, self._extra, applied, noise
            )
        for name, value in zip(_SIMULATOR_STATE, state, strict=True):
            setattr(sim, name, value)
        out["ocean_current"], out["step_count"] = state[2], state[5]
        return self._stepped(observation, out)

    def _stepped(self, observation: torch.Tensor, out: Mapping[str, torch.Tensor]) -> tuple:
        """The Gymnasium step's five values from a tensor step's observation and outputs."""
        self._td = out
        self._last_info = self._info(out)
        return (
            observation[0].numpy().copy(),
            float(out["reward"]),
            bool(out["terminated"]),
            bool(out["truncated"]),
            self._last_info,
        )
