"""Saving a trained policy so that ``dockingrl eval --policy PATH`` can load it."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch
from torchrl.data import Bounded

from dockingrl.io import atomic_write

FORMAT = "dockingrl.policy/1"


def pipeline_options(config: Mapping) -> dict:
    """The :func:`~dockingrl.make_env` options beyond the scenario that a training config (as a
    dict, e.g. a saved policy's ``config``) fixes for whatever runs its policy:
    ``observe_current``, ``observe_command`` and ``action_repeat``, where they differ from the
    paper's. Training, ``dockingrl eval --policy`` and ``OnboardPolicy.from_file`` all take them
    from here."""
    options: dict = {}
    if config.get("observe_current"):
        options["observe_current"] = True
    if config.get("observe_command"):
        options["observe_command"] = True
    if config.get("action_repeat", 1) != 1:
        options["action_repeat"] = config["action_repeat"]
    return options


def save_policy(
    path: str | Path,
    actor: torch.nn.Module,
    config,
    obs_dim: int,
    action_spec: Bounded,
    max_dist: float,
    filter_params: Mapping | None = None,
    **metadata,
) -> Path:
    """Write the actor's weights with what is needed to rebuild it (atomically), and the
    payload of the learned filter it was trained with (``filter_params``, from
    :func:`~dockingrl.transforms.params.read_filter_params`), so that the policy file is whole
    without the filter's file."""
    payload = {
        "format": FORMAT,
        "algo": config.algo,
        "scenario": config.scenario,
        "config": config.to_dict(),
        "obs_dim": obs_dim,
        "action_low": action_spec.space.low.reshape(-1)[-2:].cpu().tolist(),
        "action_high": action_spec.space.high.reshape(-1)[-2:].cpu().tolist(),
        "max_dist": max_dist,
        "state_dict": {k: v.detach().cpu() for k, v in actor.state_dict().items()},
        "filter_params": None if filter_params is None else dict(filter_params),
        "metadata": metadata,
    }
    return atomic_write(path, lambda tmp: torch.save(payload, tmp))


def load_policy(path: str | Path, device: torch.device | str = "cpu"):
    """Rebuild a saved actor. Returns ``(actor, info)`` where ``info`` has ``algo``,
    ``scenario``, ``config``, ``metadata`` and ``filter_params`` (the learned filter's payload
    it was trained with, or ``None``: Table 1's filter, or a policy saved before policies
    carried it, whose ``config["filter_params"]`` names the file). The actor acts
    deterministically under ``ExplorationType.DETERMINISTIC`` (what :func:`dockingrl.evaluate`
    sets)."""
    from dockingrl.agents.algorithms import build_actor
    from dockingrl.agents.config import CONFIGS

    payload = torch.load(Path(path), map_location="cpu", weights_only=True)
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ValueError(f"{path} is not a dockingrl policy file ({FORMAT})")
    fields = dict(payload["config"])
    fields["hidden"] = tuple(fields["hidden"])
    config = CONFIGS[payload["algo"]](**fields)
    low = torch.tensor(payload["action_low"])
    high = torch.tensor(payload["action_high"])
    spec = Bounded(low=low, high=high, shape=low.shape)
    actor = build_actor(config, payload["obs_dim"], spec, payload["max_dist"])
    actor.load_state_dict(payload["state_dict"])
    info = {k: payload[k] for k in ("algo", "scenario", "config", "metadata")}
    info["filter_params"] = payload.get("filter_params")
    return actor.to(device).eval(), info


def training_filter(info: Mapping):
    """The learned filter a loaded policy (``info`` of :func:`load_policy`) was trained with:
    the payload it carries, else the file its config names, else ``None`` (Table 1's)."""
    return info.get("filter_params") or info["config"].get("filter_params") or None
