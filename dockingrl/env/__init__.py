"""The docking environment: config, dynamics, reward and the batched TorchRL env (each name
imported on first use: ``dockingrl.env.config`` and the checks load without torch)."""

from typing import TYPE_CHECKING

from dockingrl.imports import lazy_attributes

_EXPORTS = {
    "DockingConfig": "dockingrl.env.config",
    "DockingEnv": "dockingrl.env.docking",
    "contact_score": "dockingrl.env.reward",
    "observation_from_state": "dockingrl.env.dynamics",
    "pose_from_observation": "dockingrl.env.dynamics",
    "wrap_angle": "dockingrl.env.dynamics",
}

__all__ = [
    "DockingConfig",
    "DockingEnv",
    "contact_score",
    "observation_from_state",
    "pose_from_observation",
    "wrap_angle",
]

if TYPE_CHECKING:
    from dockingrl.env.config import DockingConfig
    from dockingrl.env.docking import DockingEnv
    from dockingrl.env.dynamics import observation_from_state, pose_from_observation, wrap_angle
    from dockingrl.env.reward import contact_score

__getattr__, __dir__ = lazy_attributes(__name__, _EXPORTS)
