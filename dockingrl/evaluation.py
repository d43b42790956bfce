"""Evaluation as in the paper's Tables 6-7 and Figures 9-10: success rate, time, reward, the
success map over ocean currents and chosen trajectories."""

from __future__ import annotations

import math
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from dockingrl.env import DockingEnv
from dockingrl.io import write_json
from dockingrl.scenarios import make_env

Policy = Callable[[TensorDictBase], TensorDictBase]

#: Tables 6 and 7 of the paper (500 trials each): success %, time mean/std (s), reward mean/std.
PAPER_RESULTS: dict[tuple[str, str], tuple[float, float, float, float, float]] = {
    ("sac", "no_noise"): (97.0, 47.1, 11.4, 42.7, 63.1),
    ("sac", "noise"): (73.4, 48.3, 11.0, -23.3, 99.5),
    ("sac", "filtered"): (88.4, 46.9, 12.7, 0.7, 78.1),
    ("sac", "compound"): (99.4, 44.5, 11.0, 36.7, 80.1),
    ("td3", "no_noise"): (98.0, 44.1, 10.8, 50.8, 48.3),
    ("td3", "noise"): (69.0, 47.4, 9.8, -44.1, 106.9),
    ("td3", "filtered"): (97.2, 45.3, 15.5, -0.1, 61.0),
    ("td3", "compound"): (99.8, 44.4, 9.7, 36.1, 30.6),
    ("ppo", "no_noise"): (88.2, 50.7, 15.6, -41.0, 93.9),
    ("ppo", "noise"): (64.2, 68.4, 21.5, -94.1, 112.5),
    ("ppo", "filtered"): (90.8, 45.7, 11.0, 2.4, 83.6),
    ("ppo", "compound"): (94.2, 45.5, 11.2, 23.6, 65.3),
    ("managed_surge", "noise"): (73.7, 59.2, 7.7, -115.8, 114.2),
}


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


def _stats(values: torch.Tensor, over: str) -> dict[str, Any]:
    v = values.double().numpy()
    if v.size == 0:
        return {"over": over, "n": 0, "mean": None, "std": None}
    return {"over": over, "n": int(v.size), "mean": float(v.mean()), "std": float(v.std())}


def _failures(docked, score, speed, speed_limit) -> dict[str, int]:
    return {
        "timeout": int((~docked).sum()),
        "missed_funnel": int((docked & (score <= 0)).sum()),
        "too_fast": int((docked & (score > 0) & (speed > speed_limit)).sum()),
    }


def summarize(
    outcomes: dict[str, torch.Tensor],
    dt: float,
    speed_limit: float,
    current_range: tuple[float, float] = (-0.3, 0.3),
    entrance_x: float = 0.0,
) -> dict:
    """Table 6/7 metrics from :func:`run_episodes` outcomes.

    - ``success_rate`` (%): docked within the time limit with ``g > 0`` and ground speed
      ``<= v_max``.
    - ``time_s``: episode time over the **docked** episodes (every contact, successful or
      not), which is how the paper's Table 6 reads; ``time_success_s`` over successful episodes
      only; ``time_all_s`` over all episodes (a timeout counts as the full 120 s).
    - ``total_reward``: over all episodes.
    - ``contact_score`` (``g``) and ``contact_speed`` (m/s): over docked episodes.
    - ``failures``: ``timeout`` (no contact in time), ``missed_funnel`` (contact with
      ``g <= 0``), ``too_fast`` (contact with ``g > 0`` above the speed limit).
    - ``timeouts_beyond_station``: timeouts that ended at ``x > entrance_x``, past the
      station's entrance plane (the AUV starts at ``x < 0`` and docks moving in ``+x``).
    - ``by_current_x``: episodes, success rate and failures split by ``oc_x`` at the thirds
      of ``current_range``: ``opposing`` (the lowest third: the current carries the AUV away
      from the station), ``weak`` (the middle third) and ``following`` (the highest: it
      carries the AUV towards the station); a current outside the range counts in the outer
      third on its side, so the three add up to the totals. ``oc_y`` is not split.

    Standard deviations are population ones (``ddof = 0``).
    """
    success, docked = outcomes["success"], outcomes["docked"]
    n = int(success.numel())
    seconds = outcomes["steps"].double() * dt
    score, speed = outcomes["contact_score"], outcomes["contact_speed"]
    return {
        "episodes": n,
        "success_rate": 100.0 * float(success.double().mean()),
        "time_s": _stats(seconds[docked], "docked episodes"),
        "time_success_s": _stats(seconds[success], "successful episodes"),
        "time_all_s": _stats(seconds, "all episodes"),
        "total_reward": _stats(outcomes["total_reward"], "all episodes"),
        "contact_score": _stats(score[docked], "docked episodes"),
        "contact_speed": _stats(speed[docked], "docked episodes"),
        "failures": _failures(docked, score, speed, speed_limit),
        "timeouts_beyond_station": int((~docked & (outcomes["end"][:, 0] > entrance_x)).sum()),
        "by_current_x": _by_current_x(outcomes, speed_limit, current_range),
    }


def _by_current_x(outcomes, speed_limit, current_range) -> list[dict]:
    low, high = current_range
    edges = [round(low + (high - low) * k / 3, 12) for k in range(4)]
    oc_x = outcomes["ocean_current"][:, 0]
    masks = (oc_x < edges[1], (oc_x >= edges[1]) & (oc_x < edges[2]), oc_x >= edges[2])
    thirds = []
    for k, (name, mask) in enumerate(zip(("opposing", "weak", "following"), masks, strict=True)):
        n = int(mask.sum())
        thirds.append(
            {
                "oc_x": name,
                "range": [edges[k], edges[k + 1]],
                "episodes": n,
                "success_rate": 100.0 * float(outcomes["success"][mask].double().mean())
                if n
                else None,
                "failures": _failures(
                    outcomes["docked"][mask],
                    outcomes["contact_score"][mask],
                    outcomes["contact_speed"][mask],
                    speed_limit,
                ),
            }
        )
    return thirds


def describe_machine(device: torch.device | str | None = None) -> str:
    """The CPU, its cores, torch's version and threads, and the GPU when ``device`` is CUDA."""
    import os

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    threads = torch.get_num_threads()
    text = f"{cpu}, {os.cpu_count()} cores, torch {torch.__version__}, {threads} threads"
    if device is not None and torch.device(device).type == "cuda":
        text += f", GPU {torch.cuda.get_device_name(device)}"
    return text


def evaluate(
    policy: Policy,
    scenario: str | EnvBase,
    num_episodes: int = 500,
    *,
    seed: int = 0,
    out: str | Path | None = None,
    device: torch.device | str = "cpu",
    progress: bool = False,
    stochastic: bool = False,
    **env_kwargs,
) -> dict:
    """Evaluate a policy (deterministic unless ``stochastic``) on ``num_episodes`` episodes,
    all run as one batch.

    Args:
        policy: reads a tensordict, writes ``action`` (a TorchRL actor, a
            :class:`~dockingrl.agents.managed_surge.ManagedSurgePolicy`, ...). Run under
            ``ExplorationType.DETERMINISTIC`` and ``torch.no_grad()``.
        scenario: a scenario name (see :func:`dockingrl.make_env`) or a ready env whose batch
            size is the number of episodes.
        num_episodes: number of episodes (paper: 500); ignored when an env is given.

    Keyword Args:
        seed: env seed (start poses, currents, noise).
        out: if given, the metrics are also written there as JSON (atomically).
        device: torch device for a scenario built here.
        progress: show a progress bar.
        stochastic: sample a TorchRL actor's actions (``ExplorationType.RANDOM``) instead of
            taking its mode; the paper's metrics use the deterministic policy.
        env_kwargs: passed to :func:`~dockingrl.make_env` (``config``, ``filter_params``, ...).

    Returns:
        The metrics of :func:`summarize`, plus ``scenario``, ``seed``, ``policy_mode`` and
        ``wall_clock_s``.
    """
    if isinstance(scenario, str):
        if num_episodes < 1:
            raise ValueError(f"num_episodes must be >= 1, got {num_episodes}")
        env = make_env(scenario, num_episodes, seed=seed, device=device, **env_kwargs)
        name = scenario
    else:
        env, name = scenario, "custom"
    start = time.perf_counter()
    outcomes = run_episodes(policy, env, progress=progress, stochastic=stochastic)
    sim = base_env(env)
    speed_limit = sim.config.entry_speed_max + sim.config.contact_speed_tolerance
    metrics = {
        "scenario": name,
        "seed": seed,
        "policy_mode": "stochastic" if stochastic else "deterministic",
        **summarize(
            outcomes,
            sim.config.dt,
            speed_limit,
            sim.config.ocean_current_range,
            sim.config.dock_x[1],
        ),
        "wall_clock_s": time.perf_counter() - start,
        "machine": describe_machine(sim.device),
    }
    if out is not None:
        write_json(out, metrics)
    return metrics


def current_grid(cells: int = 9, limit: float = 0.3) -> np.ndarray:
    """The ``cells`` ocean-current values per axis of Figure 9, in ``[-limit, limit]``."""
    return np.linspace(-limit, limit, cells)


def success_map(
    policy: Policy,
    scenario: str = "noise",
    *,
    cells: int = 9,
    trials: int = 10,
    limit: float = 0.3,
    seed: int = 0,
    device: torch.device | str = "cpu",
    progress: bool = False,
    **env_kwargs,
) -> dict:
    """Success rate over a ``cells x cells`` grid of ocean currents (Figure 9).

    Each cell runs ``trials`` episodes from random start poses with the current pinned to the
    cell's value; all ``cells^2 * trials`` episodes run as one batch.

    Returns:
        ``{"oc_x": [...], "oc_y": [...], "success_rate": matrix}`` with
        ``success_rate[i][j]`` (%) for ``oc_y[i]``, ``oc_x[j]``.
    """
    if cells < 1 or trials < 1:
        raise ValueError(f"success_map needs cells >= 1 and trials >= 1, got {cells} and {trials}")
    grid = current_grid(cells, limit)
    oc_y, oc_x = np.meshgrid(grid, grid, indexing="ij")
    currents = np.stack((oc_x.ravel(), oc_y.ravel()), -1).repeat(trials, axis=0)
    env = make_env(scenario, len(currents), seed=seed, device=device, **env_kwargs)
    base_env(env).set_initial_state(ocean_current=torch.as_tensor(currents))
    outcomes = run_episodes(policy, env, progress=progress)
    rate = outcomes["success"].double().reshape(cells, cells, trials).mean(-1) * 100.0
    return {
        "scenario": scenario,
        "seed": seed,
        "trials_per_cell": trials,
        "oc_x": grid.tolist(),
        "oc_y": grid.tolist(),
        "success_rate": rate.tolist(),
        "mean_success_rate": float(rate.mean()),
    }


def trajectories(
    policy: Policy,
    cases: list[dict],
    scenario: str = "noise",
    *,
    seed: int = 0,
    device: torch.device | str = "cpu",
    **env_kwargs,
) -> list[dict]:
    """Run chosen episodes (Figure 10). Each case is ``{"start": (x, y, alpha),
    "ocean_current": (oc_x, oc_y)}``; returns them with the path, ``r_g`` and the outcome."""
    if not cases:
        raise ValueError("no trajectory cases given")
    env = make_env(scenario, len(cases), seed=seed, device=device, **env_kwargs)
    base_env(env).set_initial_state(
        pose=torch.tensor([c["start"] for c in cases], dtype=torch.float64),
        ocean_current=torch.tensor([c["ocean_current"] for c in cases], dtype=torch.float64),
    )
    outcomes = run_episodes(policy, env, record_trajectories=True)
    config = base_env(env).config
    return [{**case, **episode_record(outcomes, i, config)} for i, case in enumerate(cases)]


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


def table_row(name: str, scenario: str, metrics: dict) -> str:
    """A Table 6/7-style row, beside the paper's numbers where it has them."""
    t, r = metrics["time_s"], metrics["total_reward"]
    time_text = "n/a" if t["mean"] is None else f"{t['mean']:.1f} +- {t['std']:.1f}"
    row = (
        f"| {name} | {scenario} | {metrics['success_rate']:.1f} | {time_text} | "
        f"{r['mean']:.1f} +- {r['std']:.1f} |"
    )
    paper = PAPER_RESULTS.get((name, scenario))
    if paper is not None:
        s, tm, ts, rm, rs = paper
        row += (
            f"\n| {name} (paper) | {scenario} | {s:.1f} | {tm:.1f} +- {ts:.1f} | "
            f"{rm:.1f} +- {rs:.1f} |"
        )
    header = (
        "| algorithm | scenario | success % | time s (docked) | total reward |\n"
        "|---|---|---|---|---|\n"
    )
    return header + row
