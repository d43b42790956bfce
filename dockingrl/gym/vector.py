"""The batched docking env as a native ``gymnasium.vector.VectorEnv``: what
``gymnasium.make_vec("dockingrl/Docking-v0", num_envs=N)`` builds. All ``N`` envs step at once in
the TorchRL pipeline of :func:`dockingrl.make_env` (no copy of one env per process); numpy in and
out."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from torchrl.envs.utils import step_mdp

from dockingrl.env.specs import ACTION_DIM
from dockingrl.gym.bare import action_space, real_array
from dockingrl.gym.single import gym_pipeline, observation_space
from dockingrl.scenarios import layout_options, observation_layout

#: per-env entries of ``info`` (every sub-env has each, so each ``_key`` mask is all True)
INFO_KEYS = (
    "ocean_current",
    "true_state",
    "step_count",
    "success",
    "contact_score",
    "contact_speed",
)
AUTORESET_MODES = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)


class DockingVectorEnv(VectorEnv):
    """``num_envs`` copies of one scenario as a ``gymnasium.vector.VectorEnv``, stepped as one
    batch by the TorchRL pipeline ``dockingrl.make_env(scenario, num_envs, ...)``.

    Observations ``(num_envs, k)`` float32 and actions ``(num_envs, 2)`` as the single env's
    (:class:`~dockingrl.gym.DockingScenarioEnv`); rewards float64, ``terminated`` and
    ``truncated`` bool ``(num_envs,)``. ``info`` holds, per env, ``ocean_current``,
    ``true_state``, ``step_count``, ``success``, ``contact_score`` and ``contact_speed``, each
    with its ``_key`` mask (Gymnasium's vector ``info`` convention).

    Autoreset (``metadata["autoreset_mode"]``): ``NEXT_STEP`` (Gymnasium's default): the step
    after an env's episode ended resets it, ignores its action and returns its first
    observation with reward 0 and both flags False. ``SAME_STEP``: an env whose episode ends
    is reset in the same step; the observation returned is the new episode's first, the last
    one is in ``info["final_obs"]`` (an object array, ``None`` elsewhere) and its info in
    ``info["final_info"]``, with masks ``_final_obs`` and ``_final_info``; stable-baselines3's
    ``VecEnv`` works this way (:class:`dockingrl.gym.sb3.SB3VecEnv`).

    ``reset(seed=s)`` seeds the batch's one generator (an int; the batch of one env gives the
    single env's numbers for the same seed); ``reset(options={"reset_mask": mask})`` resets only
    the envs where the boolean ``(num_envs,)`` ``mask`` is True.

    Args:
        num_envs: number of envs.
        scenario: ``no_noise``, ``noise``, ``filtered`` or ``compound``.

    Keyword Args:
        autoreset_mode: an ``AutoresetMode`` or its value (``"NextStep"``, ``"SameStep"``).
        device: torch device of the batch.
        compile: ``torch.compile`` the simulation and filter steps.
        options: :func:`~dockingrl.gym.scenario_pipeline`'s.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int = 1,
        scenario: str = "noise",
        *,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        device: torch.device | str = "cpu",
        compile: bool = False,
        **options,
    ) -> None:
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError:
            mode = None
        if mode not in AUTORESET_MODES:
            valid = ", ".join(repr(m.value) for m in AUTORESET_MODES)
            raise ValueError(f"autoreset_mode must be one of {valid}, got {autoreset_mode!r}")
        self.pipeline = gym_pipeline(scenario, num_envs, device=device, compile=compile, **options)
        self.num_envs = int(num_envs)
        self.scenario = scenario
        self.config = self.pipeline.base_env.config
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        layout = observation_layout(scenario, **layout_options(options))
        self.single_observation_space = observation_space(layout, self.config)
        self.single_action_space = action_space(self.config)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._low = np.array(self.config.action_low)
        self._high = np.array(self.config.action_high)
        self._td = None
        self._autoreset = np.zeros(self.num_envs, dtype=bool)

    # -- helpers -------------------------------------------------------------------------
    def _info(self, td, into: dict | None = None) -> dict[str, Any]:
        info = {} if into is None else into
        everyone = np.ones(self.num_envs, dtype=bool)
        for key in INFO_KEYS:
            value = td[key].cpu().numpy()
            info[key] = value.reshape(self.num_envs) if value.shape[-1:] == (1,) else value
            info[f"_{key}"] = everyone.copy()
        return info

    def _observation(self, td) -> np.ndarray:
        return td["observation"].cpu().numpy().copy()

    def _actions(self, actions) -> torch.Tensor:
        expected = f"a finite real array of shape ({self.num_envs}, {ACTION_DIM}) [v_d, w_d]"
        shape = (self.num_envs, ACTION_DIM)
        array = real_array(actions, shape, f"actions must be {expected}", "sequence")
        finite = np.isfinite(array).all(-1)
        if not finite.all():
            index = int(np.flatnonzero(~finite)[0])
            raise ValueError(f"actions must be {expected}; env {index} got {array[index].tolist()}")
        clipped = np.clip(array, self._low, self._high).astype(np.float32)
        return torch.from_numpy(clipped).to(self.pipeline.device)

    # -- Gymnasium API -------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int | np.integer)):
            raise ValueError(f"seed must be an int or None (one generator per batch), got {seed!r}")
        super().reset(seed=seed)
        sim = self.pipeline.base_env
        if seed is not None:
            sim.set_seed(int(seed))
        elif self._td is None:
            sim.set_seed(int(self.np_random.integers(0, 2**62)))
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if options:
            raise ValueError(f"reset options may only hold 'reset_mask', got {sorted(options)}")
        if mask is not None:
            mask = np.asarray(mask)
            if mask.dtype != bool or mask.shape != (self.num_envs,):
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({self.num_envs},), "
                    f"got {mask.dtype} of shape {mask.shape}"
                )
            if self._td is None:
                raise RuntimeError("reset_mask resets some envs: call reset() once before")
            root = self._td.clone()
            root.set("_reset", torch.as_tensor(mask, device=sim.device).reshape(-1, 1))
            self._td = self.pipeline.reset(root)
            self._autoreset[mask] = False
        else:
            self._td = self.pipeline.reset()
            self._autoreset[:] = False
        return self._observation(self._td), self._info(self._td)

    def step(self, actions):
        if self._td is None:
            raise RuntimeError("call reset() before step()")
        td = self._td.set("action", self._actions(actions))
        if self.autoreset_mode == AutoresetMode.SAME_STEP:
            td, root = self.pipeline.step_and_maybe_reset(td)
            nxt = td["next"]
            reward = nxt["reward"].reshape(-1).double().cpu().numpy()
            terminated = nxt["terminated"].reshape(-1).cpu().numpy()
            truncated = nxt["truncated"].reshape(-1).cpu().numpy()
            info = self._info(root)
            done = terminated | truncated
            if done.any():
                final_obs = np.full(self.num_envs, None, dtype=object)
                last = nxt["observation"].cpu().numpy()
                for i in np.flatnonzero(done):
                    final_obs[i] = last[i].copy()
                info["final_obs"], info["_final_obs"] = final_obs, done.copy()
                info["final_info"] = {
                    key: np.where(done.reshape(-1, *[1] * (v.ndim - 1)), v, np.zeros_like(v))
                    for key, v in self._info(nxt).items()
                    if not key.startswith("_")
                }
                info["final_info"].update({f"_{key}": done.copy() for key in INFO_KEYS})
                info["_final_info"] = done.copy()
            self._td = root
            return self._observation(root), reward, terminated, truncated, info
        td = self.pipeline.step(td)
        nxt = td["next"]
        reward = nxt["reward"].reshape(-1).double().cpu().numpy()
        terminated = nxt["terminated"].reshape(-1).cpu().numpy()
        truncated = nxt["truncated"].reshape(-1).cpu().numpy()
        root = step_mdp(td)
        if self._autoreset.any():
            # the envs whose episode ended at the last step start over, their action ignored
            mask = torch.as_tensor(self._autoreset, device=root.device).reshape(-1, 1)
            root = self.pipeline.reset(root.set("_reset", mask))
            reward[self._autoreset] = 0.0
            terminated[self._autoreset] = False
            truncated[self._autoreset] = False
        self._autoreset = terminated | truncated
        self._td = root
        return self._observation(root), reward, terminated, truncated, self._info(root)

    def close_extras(self, **kwargs) -> None:
        self._td = None

    def __repr__(self) -> str:
        return f"DockingVectorEnv({self.num_envs}, {self.scenario!r}, {self.autoreset_mode})"
