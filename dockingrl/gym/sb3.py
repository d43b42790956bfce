"""stable-baselines3 adapters: the batched env as an SB3 ``VecEnv``, and an SB3 model (or any
object with SB3's ``predict``) as a policy for :func:`dockingrl.evaluate`."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from stable_baselines3.common.vec_env import VecEnv
from tensordict import TensorDictBase

from dockingrl.env.checks import checked_seed
from dockingrl.gym.vector import DockingVectorEnv


class SB3VecEnv(VecEnv):
    """``num_envs`` envs of one scenario as a stable-baselines3 ``VecEnv``, stepped as one
    batch (:class:`~dockingrl.gym.DockingVectorEnv` in ``SAME_STEP`` autoreset mode, SB3's).

    An env whose episode ends is reset in the same step; its ``infos[i]`` then holds SB3's
    ``terminal_observation``, ``TimeLimit.truncated`` (the 600-step limit, so that SB3
    bootstraps the value there) and ``is_success`` (what SB3 logs as ``success_rate``); the
    other ``infos[i]`` are empty. ``seed(s)`` then ``reset()`` seeds the batch's one
    generator with ``s``.

    Args:
        num_envs: number of envs.
        scenario: ``no_noise``, ``noise``, ``filtered`` or ``compound``.
        kwargs: :class:`~dockingrl.gym.DockingVectorEnv`'s (``device``, the scenario's
            options, ...).
    """

    def __init__(self, num_envs: int = 1, scenario: str = "noise", **kwargs) -> None:
        self.env = DockingVectorEnv(num_envs, scenario, autoreset_mode="SameStep", **kwargs)
        self.render_mode = None
        super().__init__(
            self.env.num_envs, self.env.single_observation_space, self.env.single_action_space
        )
        self._pending: np.ndarray | None = None

    def seed(self, seed: int | None = None):
        """SB3's ``seed``, with the seed checked now (one line) rather than at the next
        ``reset()``."""
        return super().seed(None if seed is None else checked_seed(seed))

    def reset(self) -> np.ndarray:
        observation, _ = self.env.reset(seed=self._seeds[0])
        self._reset_seeds()
        self._reset_options()
        return observation

    def step_async(self, actions: np.ndarray) -> None:
        self._pending = actions

    def step_wait(self):
        observation, reward, terminated, truncated, info = self.env.step(self._pending)
        done = terminated | truncated
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(done):
            infos[i] = {
                "terminal_observation": info["final_obs"][i],
                "TimeLimit.truncated": bool(truncated[i] and not terminated[i]),
                "is_success": bool(info["final_info"]["success"][i]),
            }
        return observation, reward.astype(np.float32), done, infos

    def close(self) -> None:
        self.env.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self, attr_name)] * len(list(self._get_indices(indices)))

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise AttributeError(f"SB3VecEnv: the envs of one batch share {attr_name!r}; not settable")

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs):
        raise AttributeError(f"SB3VecEnv: no per-env method {method_name!r} (one batched env)")

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(list(self._get_indices(indices)))


class SB3Policy:
    """A stable-baselines3 model as a policy of :func:`dockingrl.evaluate` (and
    :func:`dockingrl.render.write_video`): reads the tensordict's ``observation`` ``(N, k)``,
    writes ``action`` ``(N, 2)`` = ``model.predict(observation, deterministic=True)``.

    Args:
        model: an SB3 model trained on the same scenario and options (or anything with its
            ``predict(observation, deterministic=...)``).
        deterministic: take the policy's mode (the paper's metrics) or sample it.
    """

    def __init__(self, model, *, deterministic: bool = True) -> None:
        if not callable(getattr(model, "predict", None)):
            raise TypeError(f"model must have a predict() method, got {type(model).__name__}")
        self.model = model
        self.deterministic = deterministic

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        observation = td["observation"].cpu().numpy()
        action, _ = self.model.predict(observation, deterministic=self.deterministic)
        return td.set("action", torch.as_tensor(action, dtype=torch.float32, device=td.device))
