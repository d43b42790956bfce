"""A single-env Gymnasium view of :class:`DockingEnv` (numpy in, numpy out).

Registered as ``dockingrl/Docking-v0`` on ``import dockingrl``, so that any Gymnasium-based
library can use the task::

    import gymnasium, dockingrl
    env = gymnasium.make("dockingrl/Docking-v0")
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium
import numpy as np
import torch
from gymnasium import spaces

from dockingrl.env.config import DockingConfig
from dockingrl.env.docking import ACTION_DIM, OBSERVATION_DIM, DockingEnv

_INFO_KEYS = ("success", "contact_score", "contact_speed", "step_count")


class DockingGymEnv(gymnasium.Env):
    """The docking task as a ``gymnasium.Env``; see :class:`DockingEnv` for the full description.

    Observations are float32 ``(6,)`` (eq. 2), actions ``(2,)`` (eq. 3, clipped to the bounds;
    any real dtype; a wrong shape, a bool, complex or text dtype, NaN or inf raise
    ``ValueError``). ``info`` holds ``ocean_current``, ``true_state`` and, on the last step,
    ``success``, ``contact_score`` and ``contact_speed``.
    """

    metadata = {"render_modes": []}

    def __init__(self, config: DockingConfig | None = None) -> None:
        self._env = DockingEnv(1, config=config, seed=0)
        cfg = self._env.config
        self.action_space = spaces.Box(
            low=np.array(cfg.action_low, dtype=np.float32),
            high=np.array(cfg.action_high, dtype=np.float32),
            dtype=np.float32,
        )
        inf, pi = np.inf, np.float32(math.pi)
        self.observation_space = spaces.Box(
            low=np.array([0.0, -pi, -pi, -inf, -inf, -inf], dtype=np.float32),
            high=np.array([inf, pi, pi, inf, inf, inf], dtype=np.float32),
            shape=(OBSERVATION_DIM,),
            dtype=np.float32,
        )
        self._td = None

    @staticmethod
    def _info(td) -> dict[str, Any]:
        info = {
            "ocean_current": td["ocean_current"][0].numpy().copy(),
            "true_state": td["true_state"][0].numpy().copy(),
        }
        for key in _INFO_KEYS:
            if key in td.keys():
                info[key] = td[key][0].item()
        return info

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._env.set_seed(seed)
        elif self._td is None:
            self._env.set_seed(int(self.np_random.integers(0, 2**62)))
        self._td = self._env.reset()
        return self._td["observation"][0].numpy().astype(np.float32), self._info(self._td)

    def _action(self, action) -> np.ndarray:
        """``action`` as the float32 ``(2,)`` command the env applies: real numbers of shape
        ``(2,)`` exactly (an array, list or tuple), finite, clipped to the bounds in float64 so
        that a finite value beyond float32's range is clipped like any other."""
        expected = f"a finite real action of shape ({ACTION_DIM},) [v_d, w_d]"
        if action is None:
            raise ValueError(f"action must be {expected}, got None")
        try:
            array = np.asarray(action)
        except ValueError:
            raise ValueError(f"action must be {expected}, got a ragged {action!r}") from None
        if array.dtype.kind not in "iuf":
            raise ValueError(
                f"action must be {expected}, got dtype {array.dtype} of shape {array.shape}"
            )
        if array.shape != (ACTION_DIM,):
            raise ValueError(f"action must be {expected}, got shape {array.shape}")
        array = array.astype(np.float64)
        if not np.isfinite(array).all():
            raise ValueError(f"action must be {expected}, got {array.tolist()}")
        low, high = self._env.config.action_low, self._env.config.action_high
        return np.clip(array, low, high).astype(np.float32)

    def step(self, action):
        if self._td is None:
            raise RuntimeError("call reset() before step()")
        self._td["action"] = torch.from_numpy(self._action(action)).reshape(1, ACTION_DIM)
        out = self._env.step(self._td)["next"]
        self._td = out.clone()
        return (
            out["observation"][0].numpy().astype(np.float32),
            float(out["reward"][0, 0]),
            bool(out["terminated"][0, 0]),
            bool(out["truncated"][0, 0]),
            self._info(out),
        )
