"""Update scheduling: how many updates a collected batch buys."""

from __future__ import annotations

from dockingrl.agents import Agent
from dockingrl.agents.config import TrainConfig


def learn_on(agent: Agent, cfg: TrainConfig, data, frames: int, batch_frames: int) -> dict:
    """Update ``agent`` on a collected batch of ``batch_frames`` env steps, ``frames`` counted
    so far (the batch included), at the share of the run done before it (the learning-rate
    schedule's): PPO's epochs; SAC and TD3 up to ``updates_per_step`` updates per env step
    after ``start_steps``. Returns the losses as ``losses/`` metrics."""
    progress = (frames - batch_frames) / cfg.total_steps
    if cfg.algo == "ppo":
        losses = agent.learn(data, progress=progress)
    else:
        learning_frames = frames - cfg.start_steps
        target = int(cfg.updates_per_step * learning_frames) if learning_frames > 0 else 0
        losses = agent.learn(data, num_updates=max(0, target - agent.updates), progress=progress)
    return {f"losses/{k}": v for k, v in losses.items()}
