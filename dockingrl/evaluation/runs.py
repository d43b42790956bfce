"""The evaluations of the paper: a policy's metrics over a batch of episodes (Tables 6-7), its
success map over ocean currents (Figure 9) and chosen trajectories (Figure 10)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from torchrl.envs import EnvBase

from dockingrl.agents.layout import check_actor_fits, reject_policy_pair
from dockingrl.env.bounds import MAX_BATCH
from dockingrl.evaluation.episodes import Policy, base_env, episode_record, run_episodes
from dockingrl.evaluation.machine import describe_machine
from dockingrl.evaluation.metrics import summarize
from dockingrl.io import ArtifactError, write_json
from dockingrl.scenarios import make_env


def check_env_fits(actor, obs_dim: int) -> None:
    """For an actor from :func:`load_policy` and a ready env whose observation has ``obs_dim``
    numbers: check that it is the size the actor was trained on (a built env does not say which
    entries it holds, so only the size is checked). Any other policy passes unchecked."""
    trained = getattr(actor, "trained_on", None)
    if trained is None:
        return
    layout = trained["observation_layout"]
    if int(obs_dim) != layout["obs_dim"]:
        raise ArtifactError(
            f"{trained['path']}: the policy reads {layout['obs_dim']} observation numbers "
            f"({', '.join(layout['keys'])}), this env gives {int(obs_dim)}; build the env with "
            "load_policy's info['env_options']"
        )


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
    reject_policy_pair(policy, "policy", "as in `actor, info = dockingrl.load_policy(path)`")
    if isinstance(scenario, str):
        if not 1 <= num_episodes <= MAX_BATCH:
            raise ValueError(f"num_episodes must lie in [1, {MAX_BATCH}], got {num_episodes}")
        env = make_env(scenario, num_episodes, seed=seed, device=device, **env_kwargs)
        obs_dim = env.observation_spec["observation"].shape[-1]
        check_actor_fits(policy, scenario, obs_dim, env_kwargs)
        name = scenario
    else:
        env, name = scenario, "custom"
        check_env_fits(policy, env.observation_spec["observation"].shape[-1])
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
