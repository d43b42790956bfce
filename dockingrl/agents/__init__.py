"""Policies: the managed surge controller baseline and the SAC / TD3 / PPO agents."""

from dockingrl.agents.managed_surge import (
    ManagedSurgeConstants,
    ManagedSurgePolicy,
    managed_surge_action,
)

__all__ = ["ManagedSurgeConstants", "ManagedSurgePolicy", "managed_surge_action"]
