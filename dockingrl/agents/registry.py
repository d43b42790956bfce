"""``make_agent``: the agent of a config's algorithm. A new algorithm is a module with an
:class:`~dockingrl.agents.base.Agent` subclass and a row in ``AGENTS``."""

from __future__ import annotations

import torch
from torchrl.data import Bounded

from dockingrl.agents.base import Agent
from dockingrl.agents.config import PPOConfig, SACConfig, TD3Config, TrainConfig
from dockingrl.agents.mirror import mirror_observation_signs
from dockingrl.agents.networks import ActorAverage, config_observation_scale
from dockingrl.agents.ppo import PPOAgent
from dockingrl.agents.sac import SACAgent
from dockingrl.agents.td3 import TD3Agent

#: the agent class of each config class
AGENTS: dict[type[TrainConfig], type[Agent]] = {
    SACConfig: SACAgent,
    TD3Config: TD3Agent,
    PPOConfig: PPOAgent,
}


def agent_class(cfg: TrainConfig) -> type[Agent]:
    """The agent class of ``cfg``'s algorithm."""
    found = next((a for c, a in AGENTS.items() if isinstance(cfg, c)), None)
    if found is None:
        raise TypeError(f"no agent for {type(cfg).__name__}")
    return found


def build_actor(cfg: TrainConfig, obs_dim: int, action_spec: Bounded, max_dist: float):
    """The policy network of ``cfg``'s algorithm (what a saved policy holds)."""
    scale = config_observation_scale(cfg, obs_dim, max_dist)
    mirror = mirror_observation_signs(cfg, obs_dim)
    return agent_class(cfg).make_actor(cfg, obs_dim, action_spec, scale, mirror)


def make_agent(
    cfg: TrainConfig,
    obs_dim: int,
    action_spec: Bounded,
    max_dist: float,
    device: torch.device | str = "cpu",
) -> Agent:
    """Build the agent of ``cfg.algo`` for observations of ``obs_dim`` numbers."""
    action_spec = action_spec.to(device)
    scale = config_observation_scale(cfg, obs_dim, max_dist)
    actor = build_actor(cfg, obs_dim, action_spec, max_dist).to(device)
    average = ActorAverage(actor, cfg.actor_average) if cfg.actor_average > 0 else None
    agent = agent_class(cfg).build(cfg, actor, action_spec, obs_dim, scale, max_dist, device)
    agent.average = average
    return agent
