"""The paper's four scenarios as a single ``gymnasium.Env``, registered as
``dockingrl/Docking-v0``.

Each step calls the same functions as the TorchRL pipeline of :func:`dockingrl.make_env`, with
no ``TensorDict``: the batched env's transition and the EKF transform's filter step on tensors
of one env (``fast=False``), or the same equation functions (:mod:`dockingrl.env.dynamics`,
:mod:`dockingrl.env.reward`, :mod:`dockingrl.transforms.ekf`) on Python floats
(``fast=True``: :func:`~dockingrl.env.transition.paper_step` and
:func:`~dockingrl.transforms.ekf.filter_entries`). The pipeline itself is built once by
:func:`dockingrl.make_env`, so that the options mean exactly what they mean there.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch
from gymnasium import spaces
from torchrl.envs import TransformedEnv

from dockingrl.env import DockingConfig
from dockingrl.env.config import config_or_default
from dockingrl.gym.bare import DockingGymEnv, gym_task_problem, reading_bounds
from dockingrl.scenarios import layout_options, make_env, observation_layout
from dockingrl.transforms import EKFTransform
from dockingrl.transforms.ekf import (
    STATE_DIM,
    filter_entries,
    measurement_noise_std,
)
from dockingrl.transforms.observations import position_std


def scenario_pipeline(
    scenario: str = "noise",
    num_envs: int = 1,
    *,
    seed: int = 0,
    device: torch.device | str = "cpu",
    config: DockingConfig | None = None,
    range_noise_scale: float = 1.0,
    bearing_noise_scale: float = 1.0,
    filter_params: str | Path | Mapping | None = None,
    ekf_kwargs: dict | None = None,
    observe_current: bool = False,
    observe_command: bool = False,
    observe_filter_std: bool = False,
    observe_current_error: bool = False,
    following_current_fraction: float | None = None,
    lateral_current_fraction: float | None = None,
    near_start_fraction: float | None = None,
    vehicle: str | None = None,
    compile: bool = False,
) -> TransformedEnv:
    """The :func:`dockingrl.make_env` pipeline of the Gymnasium envs' options.

    ``config`` (default: the paper's) gets its USBL noise scaled by ``range_noise_scale`` and
    ``bearing_noise_scale`` (:meth:`DockingConfig.scale_usbl_noise`, as ``dockingrl train``'s
    options of the same names) and the training draws given (``following_current_fraction``,
    ``lateral_current_fraction``, ``near_start_fraction``; ``None`` keeps ``config``'s) and the
    vehicle flown (``vehicle``: ``"paper"``, ``"fossen"`` or ``"mixed"``, docs/vehicles.md;
    ``None`` keeps ``config``'s).
    ``filter_params``, ``ekf_kwargs``, ``observe_current``, ``observe_command``,
    ``observe_filter_std``, ``observe_current_error`` and ``compile`` are
    :func:`dockingrl.make_env`'s."""
    config = config_or_default(config).scale_usbl_noise(range_noise_scale, bearing_noise_scale)
    draws = {
        "following_current_fraction": following_current_fraction,
        "lateral_current_fraction": lateral_current_fraction,
        "near_start_fraction": near_start_fraction,
        "vehicle": vehicle,
    }
    config = config.replace(**{k: v for k, v in draws.items() if v is not None})
    return make_env(
        scenario,
        num_envs,
        seed=seed,
        device=device,
        config=config,
        filter_params=filter_params,
        ekf_kwargs=ekf_kwargs,
        compile=compile,
        observe_current=observe_current,
        observe_command=observe_command,
        observe_filter_std=observe_filter_std,
        observe_current_error=observe_current_error,
    )


def gym_pipeline(scenario: str, num_envs: int, **options):
    """:func:`scenario_pipeline` for a Gymnasium env, which seeds at ``reset(seed=...)`` and
    steps the paper's task on either vehicle only (its observation space bounds the paper's
    readings)."""
    if "seed" in options:
        raise ValueError(
            "seed: a Gymnasium env is seeded by reset(seed=...), not by its constructor"
        )
    pipeline = scenario_pipeline(scenario, num_envs, **options)
    problem = gym_task_problem(pipeline.base_env.config)
    if problem is not None:
        raise ValueError(problem)
    return pipeline


def observation_space(layout: tuple[str, ...], config: DockingConfig) -> spaces.Box:
    """The float32 box of the policy's observation with entries ``layout``
    (:func:`dockingrl.scenarios.observation_layout`): readings as
    :func:`~dockingrl.gym.bare.reading_bounds`, the current within ``ocean_current_range``
    (one float32 step wider, as it is drawn in float32), the previous command within the
    action bounds, the filter's standard deviations at 0 or more and its estimate of the
    current's error unbounded."""
    lows, highs = [], []
    for key in layout:
        if key in ("observation", "filtered_observation"):
            low, high = reading_bounds()
        elif key == "ocean_current":
            low_c, high_c = (
                np.float32(config.ocean_current_range[0]),
                np.float32(config.ocean_current_range[1]),
            )
            low = np.full(2, np.nextafter(low_c, np.float32(-np.inf)), dtype=np.float32)
            high = np.full(2, np.nextafter(high_c, np.float32(np.inf)), dtype=np.float32)
        elif key == "previous_action":
            low = np.array(config.action_low, dtype=np.float32)
            high = np.array(config.action_high, dtype=np.float32)
        elif key == "filter_std":
            low, high = np.zeros(2, dtype=np.float32), np.full(2, np.inf, dtype=np.float32)
        elif key == "current_error":
            low, high = np.full(2, -np.inf, dtype=np.float32), np.full(2, np.inf, dtype=np.float32)
        else:
            raise ValueError(f"unknown observation entry {key!r}")
        lows.append(low)
        highs.append(high)
    return spaces.Box(np.concatenate(lows), np.concatenate(highs), dtype=np.float32)


def _fast_filter_problem(ekf: EKFTransform, config: DockingConfig) -> str | None:
    """Why the fast path cannot run ``ekf`` (``None``: it can): it filters with the paper's
    EKF only, on the env's action bounds."""
    if ekf.state_dim != STATE_DIM:
        return (
            "fast=True filters with the paper's EKF; this one estimates the current: use fast=False"
        )
    if ekf.process_noise.manoeuvre or ekf.context_noise or ekf.gate is not None:
        return (
            "fast=True filters with a constant Q, a diagonal R and no gate (the paper's "
            "EKF); this filter has manoeuvre noise, context noise or a gate: use fast=False"
        )
    bounds = ekf.action_bounds
    env_bounds = torch.tensor([config.action_low, config.action_high])
    if bounds is not None and bounds.tolist() != env_bounds.tolist():
        return "fast=True needs the filter's action bounds to be the env's"
    return None


class DockingScenarioEnv(DockingGymEnv):
    """One of the paper's four scenarios (Sec. 4) as a ``gymnasium.Env``: what
    ``gymnasium.make("dockingrl/Docking-v0", scenario=..., ...)`` builds.

    The observation is the policy's ``observation`` of ``dockingrl.make_env(scenario, 1,
    ...)``, float32: 6 numbers in ``no_noise``, ``noise`` and ``filtered``, 12 in
    ``compound`` (raw first), plus the filter's standard deviations, the current and the
    previous command when observed. For
    the same seed and actions every step gives the same numbers as that TorchRL pipeline.
    ``info`` is the bare env's (:class:`~dockingrl.gym.bare.DockingGymEnv`).

    Args:
        scenario: ``no_noise``, ``noise``, ``filtered`` or ``compound``.

    Keyword Args:
        render_mode: ``None``, ``"rgb_array"`` (``render()`` returns an ``(H, W, 3)`` uint8
            frame: the station's funnel, the vehicle, its track and the current's arrow) or
            ``"human"`` (the same frame in a matplotlib window).
        compile: ``torch.compile`` the whole step, simulation and filter (the first step
            compiles, about 20 s on a 2-core CPU; then a step costs several times less).
        fast: step on Python floats, simulation and filter: the same functions and noise
            draws, the numbers equal to float32 rounding, several times faster than
            ``compile``; a reset still runs on tensors. The filter must be the paper's (a
            constant ``Q``, a diagonal ``R``, no gate): not with manoeuvre or context noise.
            ``None`` (default): fast where it can be (no ``compile``, the paper's filter);
            ``False`` gives the TorchRL pipeline's numbers bit for bit.
        options: :func:`scenario_pipeline`'s (``config``, ``range_noise_scale``,
            ``bearing_noise_scale``, ``filter_params``, ``ekf_kwargs``, ``observe_current``,
            ``observe_command``, ``observe_filter_std``, ``following_current_fraction``,
            ``lateral_current_fraction``, ``near_start_fraction``, ``vehicle``: the Fossen
            vehicle, ``"fossen"``, or either per episode, ``"mixed"``, steps on tensors).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 5}

    def __init__(
        self,
        scenario: str = "noise",
        *,
        render_mode: str | None = None,
        compile: bool = False,
        fast: bool | None = None,
        **options,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be None, 'human' or 'rgb_array', got {render_mode!r}"
            )
        pipeline = gym_pipeline(scenario, 1, **options)
        ekf = next((t for t in pipeline.transform if isinstance(t, EKFTransform)), None)
        if compile and ekf is not None and ekf.state_dim != STATE_DIM:
            raise ValueError("CurrentEstimatingEKF does not support compile=True")
        if fast is None:
            config = pipeline.base_env.config
            fast = (
                not compile
                and config.vehicle == "paper"
                and (ekf is None or _fast_filter_problem(ekf, config) is None)
            )
        super().__init__(simulator=pipeline.base_env, compile=compile, fast=fast)
        self.scenario = scenario
        self.render_mode = render_mode
        self.layout = observation_layout(scenario, **layout_options(options))
        self.observation_space = observation_space(self.layout, self.config)
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.config.dt)}
        self._ekf = ekf
        if fast and self._ekf is not None:
            self._float_filter_constants()
        self._track: list[list[float]] = []
        self._renderer = None

    def _observation(self, parts: dict[str, torch.Tensor]) -> torch.Tensor:
        if len(self.layout) == 1:
            return parts[self.layout[0]]
        return torch.cat([parts[key] for key in self.layout], dim=-1)

    def _observe_reset(self, out) -> torch.Tensor:
        parts = {"observation": out["observation"], "ocean_current": out["ocean_current"]}
        if "previous_action" in self.layout:
            parts["previous_action"] = torch.zeros(1, 2)
        if self._ekf is not None:
            z, current = out["observation"], out["ocean_current"]
            mean, cov = self._ekf.initial_estimate(z, current)
            self._extra = (mean, cov, torch.zeros(1, dtype=z.dtype))
            parts["filtered_observation"] = self._ekf.filtered_readings(mean, current)
            parts["filter_std"] = position_std(cov)
            parts["current_error"] = mean[..., STATE_DIM:]
        return self._observation(parts)

    def _float_filter_constants(self) -> None:
        """The filter's ``Q``, Table 2's sigmas and ``R``'s floor as floats, for the fast path."""
        ekf = self._ekf
        problem = _fast_filter_problem(ekf, self.config)
        if problem is not None:
            raise ValueError(problem)
        with torch.no_grad():
            self._q = tuple(map(tuple, ekf.process_noise().float().tolist()))
            self._r_std = tuple(ekf.measurement_noise.std().float().tolist())
        self._r_eps = ekf.measurement_noise.eps

    def _start_fast(self) -> None:
        if self._ekf is not None:
            mean, cov, _ = self._extra
            self._filter_state = (tuple(mean[0].tolist()), tuple(map(tuple, cov[0].tolist())))

    def _observe_fast(self, observation: tuple, action: tuple) -> tuple:
        current = (self._state.oc_x, self._state.oc_y)
        parts = {"observation": observation, "ocean_current": current, "previous_action": action}
        if self._ekf is not None:
            ekf, (mean, cov) = self._ekf, self._filter_state
            estimate = ekf.range_noise_from == "estimate"
            rho = math.hypot(mean[0], mean[1]) if estimate else observation[0]
            sigma = tuple(
                math.sqrt(s * s + self._r_eps) for s in measurement_noise_std(rho, self._r_std)
            )
            mean, cov, filtered = filter_entries(
                mean,
                cov,
                action,
                observation,
                current,
                self._q,
                sigma,
                ekf.dt,
                k_v=ekf.k_v,
                k_w=ekf.k_w,
            )
            self._filter_state = (mean, cov)
            parts["filtered_observation"] = filtered
            parts["filter_std"] = (math.sqrt(max(cov[0][0], 0.0)), math.sqrt(max(cov[1][1], 0.0)))
        if len(self.layout) == 1:
            return parts[self.layout[0]]
        return tuple(value for key in self.layout for value in parts[key])

    def _tensor_step(self, state, extra, action, noise):
        state, _, observation, out = super()._tensor_step(state, (), action, noise)
        observation, extra = self._observe_step(observation, state[2], action, extra)
        return state, extra, observation, out

    def _observe_step(self, observation, current, action, extra):
        parts = {"observation": observation, "ocean_current": current, "previous_action": action}
        if self._ekf is not None:
            mean, cov, age = extra
            mean, cov, filtered = self._ekf.filter_step(
                mean, cov, action, observation, current, age
            )
            extra = (mean, cov, age + 1)
            parts["filtered_observation"] = filtered
            parts["filter_std"] = position_std(cov)
            parts["current_error"] = mean[..., STATE_DIM:]
        return self._observation(parts), extra

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        result = super().reset(seed=seed, options=options)
        self._record(result[1])
        return result

    def step(self, action):
        result = super().step(action)
        self._record(result[4])
        return result

    # -- rendering ------------------------------------------------------------------------
    def _record(self, info) -> None:
        if self.render_mode is None:
            return
        pose = info["true_state"][:3].tolist()
        if info["step_count"] == 0:
            self._track = [pose]
        else:
            self._track.append(pose)

    def render(self):
        if self.render_mode is None:
            return None
        if self._last_info is None:
            raise RuntimeError("call reset() before render()")
        if self._renderer is None:
            from dockingrl.render import DockingRenderer

            self._renderer = DockingRenderer(self.config)
        frame = self._renderer.draw(
            np.asarray(self._track),
            self._last_info["ocean_current"].tolist(),
            title=f"{self.scenario}, t = {(len(self._track) - 1) * self.config.dt:.1f} s",
        )
        if self.render_mode == "rgb_array":
            return frame
        self._renderer.show(frame)
        return None

    def close(self) -> None:
        super().close()
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
