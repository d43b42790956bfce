"""What a run collects with: the env it describes its agent from, the training env, and
TorchRL's ``Collector`` over it."""

from __future__ import annotations

from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType

from dockingrl.agents.config import TrainConfig
from dockingrl.evaluation import base_env
from dockingrl.scenarios import check_mirror_symmetric, make_env
from dockingrl.training.options import training_draws, training_transforms


def env_shapes(env) -> tuple:
    """``(obs_dim, action_spec, max_dist)`` of a run's env (:func:`training_env`): the size of
    the observation its agent reads, one env's command spec, eq. 4's distance."""
    return (
        env.observation_spec["observation"].shape[-1],
        env.action_spec[0].clone(),
        base_env(env).config.max_dist,
    )


def training_env(cfg: TrainConfig, env_kwargs: dict, frames: int):
    """The batched training env of a run that has trained ``frames`` env steps: the run's
    world with its training draws and training transforms. With ``mirror_augment`` it checks
    that the world mirrors (:func:`~dockingrl.scenarios.check_mirror_symmetric`)."""
    kwargs = dict(env_kwargs)
    kwargs["config"] = training_draws(cfg, kwargs["config"])
    env = make_env(
        cfg.scenario,
        cfg.num_envs,
        seed=cfg.seed * 1_000_003 + frames,
        device=cfg.device,
        compile=cfg.compile,
        transforms=training_transforms(cfg),
        **kwargs,
    )
    if getattr(cfg, "mirror_augment", False):
        check_mirror_symmetric(env)
    return env


def make_collector(
    cfg: TrainConfig,
    env,
    policy,
    frames: int,
    until: int | None = None,
    random_steps: int = 0,
) -> Collector:
    """The collector of a run that has trained ``frames`` env steps, to ``until`` env steps
    (``total_steps`` by default), in batches of the config's collected transitions, the first
    ``random_steps`` env steps with uniformly random actions (the agent's
    :meth:`~dockingrl.agents.base.Agent.random_steps`)."""
    # the collector counts transitions: one per action_repeat env steps
    repeat = cfg.action_repeat
    frames_per_batch = cfg.collected_transitions()
    random_frames = -(-random_steps // repeat)
    random_frames = -(-random_frames // frames_per_batch) * frames_per_batch
    until = cfg.total_steps if until is None else until
    remaining = -(-(until - frames) // repeat)
    return Collector(
        env,
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=-(-remaining // frames_per_batch) * frames_per_batch,
        init_random_frames=random_frames,
        exploration_type=ExplorationType.RANDOM,
        device=cfg.device,
        auto_register_policy_transforms=False,
    )


def episode_metrics(data) -> tuple[int, dict[str, float]]:
    """The episodes that ended in a collected batch: their number, and the mean episode
    reward and success rate (%) of those, where any ended."""
    done = data["next", "done"].squeeze(-1)
    if not bool(done.any()):
        return 0, {}
    return int(done.sum()), {
        "train/episode_reward": float(data["next", "episode_reward"][done].mean()),
        "train/success_rate": 100.0 * float(data["next", "success"][done].float().mean()),
    }
