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
        if resets_before(cfg, frames, batch_frames):
            agent.reset_networks()
        learning_frames = frames - cfg.start_steps
        target = int(cfg.updates_per_step * learning_frames) if learning_frames > 0 else 0
        losses = agent.learn(data, num_updates=max(0, target - agent.updates), progress=progress)
    return {f"losses/{k}": v for k, v in losses.items()}


def resets_before(cfg: TrainConfig, frames: int, batch_frames: int) -> bool:
    """Whether the off-policy agent resets its networks before learning on the batch that
    brings the run to ``frames`` env steps: a multiple of ``reset_every`` falls within the
    batch, and the batch is not the run's last."""
    every = cfg.reset_every
    if not every or frames >= cfg.total_steps:
        return False
    return frames // every > (frames - batch_frames) // every
