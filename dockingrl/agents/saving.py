"""Saving a trained policy so that ``dockingrl eval --policy PATH`` can load it."""

from __future__ import annotations

from collections.abc import Mapping
from math import inf
from pathlib import Path

import torch
from torchrl.data import Bounded

from dockingrl.agents.layout import pipeline_options, policy_layout
from dockingrl.env.checks import available_device
from dockingrl.io import (
    ArtifactError,
    first_line,
    is_count,
    read_artifact,
    read_old_artifact,
    read_to_upgrade,
    require_finite,
    require_keys,
    save_artifact,
)
from dockingrl.scenarios import (
    SCENARIOS,
    observation_size,
)

FORMAT = "dockingrl.policy/2"
#: version 1 had no content hash and no ``observation_layout``
OLD_FORMATS = ("dockingrl.policy/1",)
WHAT = "dockingrl policy file"
KEYS = (
    "algo",
    "scenario",
    "config",
    "obs_dim",
    "action_low",
    "action_high",
    "max_dist",
    "state_dict",
    "filter_params",
    "metadata",
    "observation_layout",
)


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
    """Write the actor's weights with what is needed to rebuild it and the observation layout it
    reads (:func:`~dockingrl.agents.layout.policy_layout`), as an artefact of :mod:`dockingrl.io`
    (atomically), and the payload of the learned filter it was trained with (``filter_params``, from
    :func:`~dockingrl.transforms.params.read_filter_params`), so that the policy file is whole
    without the filter's file."""
    config_dict = config.to_dict()
    payload = {
        "format": FORMAT,
        "algo": config.algo,
        "scenario": config.scenario,
        "config": config_dict,
        "obs_dim": obs_dim,
        "action_low": action_spec.space.low.reshape(-1)[-2:].cpu().tolist(),
        "action_high": action_spec.space.high.reshape(-1)[-2:].cpu().tolist(),
        "max_dist": max_dist,
        "state_dict": {k: v.detach().cpu() for k, v in actor.state_dict().items()},
        "filter_params": None if filter_params is None else dict(filter_params),
        "metadata": metadata,
        "observation_layout": policy_layout(config.scenario, obs_dim, config_dict),
    }
    return save_artifact(path, payload)


def read_policy(path: str | Path) -> dict:
    """The payload of a policy file written by :func:`save_policy`, checked: format, hash,
    keys, a known algorithm and scenario, a config its algorithm's config accepts (field
    types and ranges), the observation layout that config gives, and the learned filter it
    carries fitting the EKF. Raises :class:`~dockingrl.io.ArtifactError` naming the file."""
    from dockingrl.agents.config import CONFIGS

    payload = read_artifact(path, WHAT, FORMAT, OLD_FORMATS)
    require_keys(path, payload, WHAT, KEYS)
    _check_payload(path, payload, CONFIGS)
    layout = payload["observation_layout"]
    expected = policy_layout(payload["scenario"], payload["obs_dim"], payload["config"])
    if not isinstance(layout, dict):
        raise ArtifactError(f"{path}: observation_layout must be a dict (got {layout!r:.60})")
    for key in [*expected, *sorted(set(layout) - set(expected), key=str)]:
        if layout.get(key) != expected.get(key):
            raise ArtifactError(
                f"{path}: observation_layout {key} is {layout.get(key)!r:.80}, not the "
                f"{expected.get(key)!r:.80} its config gives"
            )
    _check_carried_filter(path, payload)
    return payload


def _check_carried_filter(path, payload: dict) -> None:
    """Refuse a policy whose carried learned filter does not load into the EKF."""
    from dockingrl.transforms.params import check_fits

    if payload["filter_params"] is not None:
        check_fits(payload["filter_params"], f"{path}: the filter it carries")


def _check_payload(path, payload: dict, configs: Mapping) -> None:
    from dockingrl.agents.config import unknown_options

    require_keys(path, payload, WHAT, KEYS[:-1])
    algo, config = payload["algo"], payload["config"]
    if not isinstance(algo, str) or algo not in configs:
        raise ArtifactError(f"{path}: unknown algorithm {algo!r} (known: {', '.join(configs)})")
    if not isinstance(payload["scenario"], str) or payload["scenario"] not in SCENARIOS:
        raise ArtifactError(f"{path}: unknown scenario {payload['scenario']!r}")
    for key in ("config", "state_dict", "metadata"):
        if not isinstance(payload[key], dict):
            raise ArtifactError(f"{path}: {key} must be a dict (got {payload[key]!r:.60})")
    extra = unknown_options(algo, set(config) - {"algo", "recipe"})
    if extra:
        raise ArtifactError(
            f"{path}: config fields unknown to dockingrl's {algo}: {', '.join(extra)}"
        )
    _check_config(path, algo, config)
    obs_dim = payload["obs_dim"]
    if not (is_count(obs_dim, 1) and obs_dim < 2**16):
        raise ArtifactError(f"{path}: obs_dim must be a whole number > 0 (got {obs_dim!r:.60})")
    require_finite(path, "state_dict", payload["state_dict"])
    low, high, max_dist = payload["action_low"], payload["action_high"], payload["max_dist"]
    try:
        low, high = torch.tensor(low, dtype=torch.float64), torch.tensor(high, dtype=torch.float64)
        bounds = low.shape == high.shape == (2,) and bool((low < high).all())
    except (TypeError, ValueError, RuntimeError):
        bounds = False
    if not bounds:  # NaN fails low < high
        raise ArtifactError(
            f"{path}: action_low and action_high must be two numbers each, low < high "
            f"(got {payload['action_low']!r}, {payload['action_high']!r})"
        )
    if (
        isinstance(max_dist, bool)
        or not isinstance(max_dist, (int, float))
        or not 0 < max_dist < inf
    ):
        raise ArtifactError(f"{path}: max_dist must be a finite number > 0 (got {max_dist!r})")
    carried = payload["filter_params"]
    if carried is not None and not isinstance(carried, dict):
        raise ArtifactError(f"{path}: filter_params must be a dict or None (got {carried!r:.60})")


def _check_config(path, algo: str, config: dict) -> None:
    """Refuse (one line naming ``path``) a saved config whose fields have the wrong type or
    lie out of their range, as training would have refused them."""
    from dockingrl.agents.config import CONFIGS, saved_fields

    try:
        if config.get("algo", algo) != algo:
            raise ValueError(f"algo {config['algo']!r} is not the file's {algo!r}")
        if not isinstance(config.get("recipe", ""), str):
            raise ValueError(f"recipe must be a name (got {config['recipe']!r})")
        CONFIGS[algo](**saved_fields(algo, config)).validate()
    except ValueError as exc:
        raise ArtifactError(f"{path}: its config: {first_line(exc)}") from None


def load_policy(path: str | Path, device: torch.device | str = "cpu"):
    """Rebuild a saved actor. Returns ``(actor, info)`` where ``info`` has ``algo``, ``scenario``,
    ``config``, ``metadata``, ``observation_layout`` (see
    :func:`~dockingrl.agents.layout.check_layout`), ``path`` and ``filter_params`` (the learned
    filter's payload it was trained with, or ``None``: Table 1's filter, or a policy saved before
    policies carried it, whose ``config["filter_params"]`` names the file) and ``env_options``, the
    :func:`~dockingrl.make_env` options its pipeline needs
    (:func:`~dockingrl.agents.layout.pipeline_options`). The actor acts deterministically under
    ``ExplorationType.DETERMINISTIC`` (what :func:`dockingrl.evaluate` sets). Raises
    :class:`~dockingrl.io.ArtifactError` for a missing, damaged, crafted or older file."""
    available_device(str(device))
    payload = read_policy(path)
    actor = _rebuild(path, payload)
    info = {k: payload[k] for k in ("algo", "scenario", "config", "metadata")}
    info["filter_params"] = payload["filter_params"]
    info["observation_layout"] = payload["observation_layout"]
    info["path"] = str(path)
    info["env_options"] = pipeline_options(payload["config"])
    # what :func:`~dockingrl.agents.layout.check_actor_fits` checks an env against
    actor.trained_on = {"path": str(path), "observation_layout": payload["observation_layout"]}
    return actor.to(device).eval(), info


def _rebuild(path, payload: dict) -> torch.nn.Module:
    """The actor of a checked policy payload, its weights loaded."""
    from dockingrl.agents.config import CONFIGS
    from dockingrl.agents.registry import build_actor

    config = dict(payload["config"])
    if isinstance(payload["state_dict"], Mapping):
        odd = sorted(
            f"{name} ({value.dtype})"
            for name, value in payload["state_dict"].items()
            if isinstance(value, torch.Tensor) and not value.is_floating_point()
        )
        if odd:
            raise ArtifactError(f"{path}: weights that are not floating point: {', '.join(odd)}")
    try:
        config["hidden"] = tuple(config["hidden"])
        cfg = CONFIGS[payload["algo"]](**config)
        low = torch.tensor(payload["action_low"], dtype=torch.float32)
        high = torch.tensor(payload["action_high"], dtype=torch.float32)
        spec = Bounded(low=low, high=high, shape=low.shape)
        actor = build_actor(cfg, payload["obs_dim"], spec, payload["max_dist"])
        actor.load_state_dict(payload["state_dict"])
    except (KeyError, RuntimeError, TypeError, ValueError) as exc:
        raise ArtifactError(
            f"{path}: does not rebuild a {payload['algo']} actor ({first_line(exc)})"
        ) from None
    return actor


def upgrade_policy(path: str | Path) -> str:
    """Rewrite the policy file ``path`` of an older format, or one carrying a learned filter of
    an older format, in the current ones (atomically): its observation layout derived from its
    config, the learned filter it carries upgraded too. Returns what was done."""
    from dockingrl.agents.config import CONFIGS
    from dockingrl.transforms.params import FORMAT as FILTER_FORMAT
    from dockingrl.transforms.params import OLD_FORMATS as OLD_FILTER_FORMATS
    from dockingrl.transforms.params import upgrade_payload

    payload = read_to_upgrade(path, WHAT, FORMAT, OLD_FORMATS)
    if payload is None:  # the current format, whose carried filter may be of an older one
        payload = read_old_artifact(path, WHAT)
        carried = payload.get("filter_params")
        if not isinstance(carried, dict) or carried.get("format") not in OLD_FILTER_FORMATS:
            return f"{path}: already {FORMAT}"
        found = f"{FORMAT} carrying {carried['format']}"
    else:
        found = payload["format"]
    payload.setdefault("filter_params", None)
    payload.setdefault("metadata", {})
    _check_payload(path, payload, CONFIGS)
    carried = payload["filter_params"]
    if carried is not None and carried.get("format") != FILTER_FORMAT:
        payload["filter_params"] = upgrade_payload(carried)
    _check_carried_filter(path, payload)
    layout = policy_layout(payload["scenario"], payload["obs_dim"], payload["config"])
    numbers = observation_size(layout["keys"])
    if numbers != layout["obs_dim"]:
        raise ArtifactError(
            f"{path}: its config gives an observation of {numbers} numbers "
            f"({', '.join(layout['keys'])}), its actor reads {layout['obs_dim']}"
        )
    payload["observation_layout"] = layout
    payload["format"] = FORMAT
    _rebuild(path, payload)
    save_artifact(path, payload)
    return f"{path}: {found} -> {FORMAT}"
