"""What a training config adds to the env: its options for ``make_env``, the training draws of
its resets, and the transforms the agent learns from."""

from __future__ import annotations

from torchrl.envs import RewardSum

from dockingrl.agents.config import TrainConfig
from dockingrl.agents.layout import pipeline_options
from dockingrl.agents.reward_shaping import RewardShaping
from dockingrl.agents.world_options import curriculum_levels
from dockingrl.env import DockingConfig
from dockingrl.env.levels import level_config
from dockingrl.env.task_options import TRAINING_DRAWS
from dockingrl.transforms import (
    ContactSpeedPenalty,
    MissPenaltyFloor,
    PassedStationEnd,
    SuccessBonus,
)
from dockingrl.transforms.params import read_filter_params


def env_kwargs(cfg: TrainConfig, level: str | None = None) -> dict:
    """The :func:`~dockingrl.make_env` options a training config implies (sensor-noise
    scaling, the realism options of ``level``, by default its ``train_level``, learned filter
    parameters, and :func:`pipeline_options`)."""
    config = DockingConfig().scale_usbl_noise(cfg.range_noise_scale, cfg.bearing_noise_scale)
    kwargs: dict = {"config": level_config(level or cfg.train_level, config)}
    if cfg.filter_params:
        kwargs["filter_params"] = read_filter_params(cfg.filter_params)
    kwargs.update(pipeline_options(cfg))
    return kwargs


def curriculum_stages(cfg: TrainConfig) -> list[tuple[str, int]]:
    """The stages of the run's training world: ``(level, env steps at its end)`` for each
    level of ``train_curriculum`` and then ``train_level``, equal shares of ``total_steps``
    (one stage, ``train_level`` to the end, without a curriculum)."""
    levels = [*curriculum_levels(cfg.train_curriculum), cfg.train_level]
    return [(level, cfg.total_steps * (i + 1) // len(levels)) for i, level in enumerate(levels)]


def stage_at(cfg: TrainConfig, frames: int) -> tuple[str, int]:
    """The stage of :func:`curriculum_stages` that a run at ``frames`` env steps trains in:
    the first that ends after ``frames`` (the last one at or past ``total_steps``)."""
    stages = curriculum_stages(cfg)
    return next((stage for stage in stages if frames < stage[1]), stages[-1])


def training_draws(cfg: TrainConfig, config: DockingConfig) -> DockingConfig:
    """The training env's config: ``config`` with the run's curricula (``TRAINING_DRAWS``)
    that are on, and, on a level of either vehicle, the run's share of Fossen episodes.
    Evaluations keep ``config``, Sec. 4.1's draws and the level's even share."""
    curricula = {name: getattr(cfg, name) for name in TRAINING_DRAWS if getattr(cfg, name) > 0}
    if config.vehicle == "mixed" and cfg.train_fossen_fraction != config.fossen_fraction:
        curricula["fossen_fraction"] = cfg.train_fossen_fraction
    return config.replace(**curricula) if curricula else config


def training_transforms(cfg: RewardShaping) -> list:
    """What the training env adds to the scenario: ``RewardSum`` (logged episode rewards are
    the paper's eq. 12), then the optional terms the agent learns from: the floor on a miss's
    contact reward, the contact-speed penalty, the success bonus, and the end of an episode
    that passes the station."""
    base = DockingConfig()
    contact_weight = base.contact_weight
    transforms = [RewardSum()]
    if cfg.miss_penalty_floor > 0:
        transforms.append(MissPenaltyFloor(cfg.miss_penalty_floor, contact_weight))
    if cfg.contact_speed_penalty > 0:
        cap = contact_weight if cfg.contact_speed_penalty_cap else None
        transforms.append(
            ContactSpeedPenalty(cfg.contact_speed_penalty, cfg.contact_speed_target, cap)
        )
    if cfg.success_bonus > 0:
        transforms.append(SuccessBonus(cfg.success_bonus))
    if cfg.passed_station_penalty > 0:
        transforms.append(PassedStationEnd(cfg.passed_station_penalty, base.dock_x[1]))
    return transforms
