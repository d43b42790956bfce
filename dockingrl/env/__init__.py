"""The docking environment: config, dynamics, reward and the batched TorchRL env."""

from dockingrl.env.config import DockingConfig
from dockingrl.env.docking import DockingEnv
from dockingrl.env.dynamics import observation_from_state, pose_from_observation, wrap_angle
from dockingrl.env.reward import contact_score

__all__ = [
    "DockingConfig",
    "DockingEnv",
    "contact_score",
    "observation_from_state",
    "pose_from_observation",
    "wrap_angle",
]
