"""Running one episode in every env of a batch at once, and what each episode came to."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from dockingrl.env import DockingEnv

Policy = Callable[[TensorDictBase], TensorDictBase]


def base_env(env: EnvBase) -> DockingEnv:
    """The :class:`DockingEnv` under any stack of transforms."""
    while isinstance(env, TransformedEnv):
        env = env.base_env
    if not isinstance(env, DockingEnv):
        raise TypeError(f"expected a DockingEnv pipeline, got {type(env).__name__}")
    return env


def run_episodes(
    policy: Policy,
    env: EnvBase,
    *,
    record_trajectories: bool = False,
    progress: bool = False,
    stochastic: bool = False,
) -> dict[str, torch.Tensor]:
    """Run one episode in every env of the batch at once, with a deterministic policy (a
    TorchRL actor's mode; ``stochastic=True``: its samples, as while training).

    A policy with a ``bind_env(env)`` method (:class:`~dockingrl.planning.PlannerPolicy`)
    gets the env before the first step.

    Stops when every env is done (at most ``max_steps``); an env that finished keeps stepping
    but its outcome is frozen at its first ``done``.

    Returns per-episode tensors (CPU): ``success``, ``docked`` (terminated by contact),
    ``truncated``, ``contact_score``, ``contact_speed``, ``steps``, ``total_reward``,
    ``ocean_current``, ``start`` and ``end`` (true poses ``x, y, alpha`` at the first step
    and at the episode's end), and with ``record_trajectories`` the ``trajectory``
    ``(num_envs, T + 1, 3)`` of true poses (frozen after the end).
    """
    sim = base_env(env)
    bind_env = getattr(policy, "bind_env", None)
    if bind_env is not None:  # a privileged planner reads the simulator itself
        bind_env(env)
    n, max_steps = sim.num_envs, sim.config.max_steps
    zeros = torch.zeros(n, device=sim.device)
    active = torch.ones(n, dtype=torch.bool, device=sim.device)
    out = {
        "success": torch.zeros(n, dtype=torch.bool, device=sim.device),
        "docked": torch.zeros(n, dtype=torch.bool, device=sim.device),
        "truncated": torch.zeros(n, dtype=torch.bool, device=sim.device),
        "contact_score": zeros.clone(),
        "contact_speed": zeros.clone(),
        "steps": torch.zeros(n, dtype=torch.int64, device=sim.device),
        "transitions": torch.zeros(n, dtype=torch.int64, device=sim.device),
        "total_reward": zeros.clone(),
    }
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=max_steps, desc="evaluating", unit="step", leave=False)
    mode = ExplorationType.RANDOM if stochastic else ExplorationType.DETERMINISTIC
    with torch.no_grad(), set_exploration_type(mode):
        td = env.reset()
        # the water's current (what the vehicle believes of it is ``ocean_current`` when the
        # realism options make them differ)
        out["ocean_current"] = td.get("true_ocean_current", td["ocean_current"]).clone()
        out["start"] = td["true_state"][:, :3].clone()
        out["end"] = out["start"].clone()
        poses = [td["true_state"][:, :3].clone()]
        for _ in range(max_steps):
            td = env.step(policy(td))
            nxt = td["next"]
            reward = nxt["reward"].squeeze(-1)
            out["total_reward"] += torch.where(active, reward, torch.zeros_like(reward))
            out["transitions"] += active.long()
            done = nxt["done"].squeeze(-1) & active
            for key, source in (
                ("success", "success"),
                ("docked", "terminated"),
                ("truncated", "truncated"),
                ("contact_score", "contact_score"),
                ("contact_speed", "contact_speed"),
                ("steps", "step_count"),
            ):
                value = nxt[source].squeeze(-1)
                out[key] = torch.where(done, value, out[key])
            pose = nxt["true_state"][:, :3]
            out["end"] = torch.where(done.unsqueeze(-1), pose, out["end"])
            if record_trajectories:
                poses.append(torch.where(active.unsqueeze(-1), pose, poses[-1]))
            active = active & ~done
            if bar is not None:
                bar.update(1)
            if not bool(active.any()):
                break
            td = step_mdp(td, keep_other=True)
    if bar is not None:
        bar.close()
    if record_trajectories:
        out["trajectory"] = torch.stack(poses, dim=1)
    return {k: v.cpu() for k, v in out.items()}


def episode_record(outcomes: dict[str, torch.Tensor], i: int, config) -> dict:
    """Episode ``i`` of :func:`run_episodes`' outcomes (``record_trajectories=True``) as
    :func:`~dockingrl.plots.plot_trajectories` draws it: its ``path`` of true poses to the
    end, one per decision of the policy (every ``action_repeat`` env steps), ``docked``,
    ``success``, ``r_g`` (eq. 11; NaN without contact) and ``time_s``."""
    steps = int(outcomes["steps"][i])
    docked = bool(outcomes["docked"][i])
    return {
        "path": outcomes["trajectory"][i, : int(outcomes["transitions"][i]) + 1].tolist(),
        "docked": docked,
        "success": bool(outcomes["success"][i]),
        "r_g": float(outcomes["contact_score"][i]) * config.contact_weight if docked else math.nan,
        "time_s": steps * config.dt,
    }
