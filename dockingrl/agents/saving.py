"""Saving a trained policy so that ``dockingrl eval --policy PATH`` can load it."""

from __future__ import annotations

from collections.abc import Mapping
from math import inf
from pathlib import Path

import torch
from torchrl.data import Bounded

from dockingrl.agents.world_options import PAPER_RESPONSE_RATE
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
    OBSERVATION_OPTIONS,
    SCENARIOS,
    layout_options,
    observation_layout,
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


def saved_config(config):
    """The typed config of a training config saved as a dict (a run's ``config.json``, a
    policy file's ``config``), type-checked; a config passes through."""
    from dockingrl.agents.config import TrainConfig, config_class, saved_fields

    if isinstance(config, TrainConfig):
        return config
    return config_class(config["algo"])(**saved_fields(config["algo"], config))


def pipeline_options(config) -> dict:
    """The :func:`~dockingrl.make_env` options beyond the scenario that a training config (a
    config, or one saved as a dict: a saved policy's ``config``, :func:`saved_config`) fixes
    for whatever runs its policy: ``observe_current``, ``observe_command``,
    ``observe_filter_std``, ``action_repeat`` and the filter's ``compensate_latency``,
    ``estimate_current``, ``filter_gate`` and ``filter_response_rate`` (as ``ekf_kwargs``),
    where they differ from the paper's. Training, ``dockingrl eval --policy``,
    ``dockingrl stress`` and ``OnboardPolicy.from_file`` all take them from here."""
    cfg = saved_config(config)
    options: dict = {}
    ekf_kwargs = {k: True for k in ("compensate_latency", "estimate_current") if getattr(cfg, k)}
    if cfg.filter_gate:
        ekf_kwargs["gate"] = float(cfg.filter_gate)
    if cfg.filter_response_rate != PAPER_RESPONSE_RATE:
        ekf_kwargs["k_v"] = ekf_kwargs["k_w"] = float(cfg.filter_response_rate)
    if ekf_kwargs:
        options["ekf_kwargs"] = ekf_kwargs
    for name in OBSERVATION_OPTIONS:
        if getattr(cfg, name):
            options[name] = True
    if cfg.action_repeat != 1:
        options["action_repeat"] = cfg.action_repeat
    return options


def policy_layout(scenario: str, obs_dim: int, config: Mapping) -> dict:
    """The observation layout a policy declares: the ``scenario`` it was trained on, the
    entries of its observation (:func:`~dockingrl.scenarios.observation_layout` with the
    options of its training ``config``, a dict), ``obs_dim`` and ``action_repeat``."""
    options = pipeline_options(config)
    keys = observation_layout(scenario, **layout_options(options))
    return {
        "scenario": scenario,
        "keys": list(keys),
        "obs_dim": int(obs_dim),
        "action_repeat": int(options.get("action_repeat", 1)),
    }


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
    """Write the actor's weights with what is needed to rebuild it and the observation
    layout it reads (:func:`policy_layout`), as an artefact of :mod:`dockingrl.io`
    (atomically), and the payload of the learned filter it was trained with
    (``filter_params``, from :func:`~dockingrl.transforms.params.read_filter_params`), so that
    the policy file is whole without the filter's file."""
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


def reject_policy_pair(actor, name: str, hint: str) -> None:
    """Raise one ``TypeError`` when ``actor`` is the ``(actor, info)`` pair that
    :func:`load_policy` returns rather than its actor; ``hint`` says what to pass instead."""
    if isinstance(actor, tuple):
        raise TypeError(
            f"{name} is a tuple (load_policy returns the pair (actor, info)): pass the actor, "
            f"{hint}"
        )


def load_policy(path: str | Path, device: torch.device | str = "cpu"):
    """Rebuild a saved actor. Returns ``(actor, info)`` where ``info`` has ``algo``,
    ``scenario``, ``config``, ``metadata``, ``observation_layout`` (see :func:`check_layout`),
    ``path`` and ``filter_params`` (the learned filter's payload it was trained with, or
    ``None``: Table 1's filter, or a policy saved before policies carried it, whose
    ``config["filter_params"]`` names the file) and ``env_options``, the
    :func:`~dockingrl.make_env` options its pipeline needs (:func:`pipeline_options`). The
    actor acts deterministically under
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
    # what :func:`check_actor_fits` checks an env against
    actor.trained_on = {"path": str(path), "observation_layout": payload["observation_layout"]}
    return actor.to(device).eval(), info


def check_options_layout(info: Mapping, scenario: str, obs_dim: int, options: Mapping) -> None:
    """:func:`check_layout` for the env of ``scenario`` built with the :func:`~dockingrl.make_env`
    ``options`` (its ``observe_*`` and ``action_repeat``), whose observation has ``obs_dim``
    numbers."""
    check_layout(
        info,
        scenario,
        obs_dim,
        **layout_options(options),
        action_repeat=options.get("action_repeat", 1),
    )


def check_actor_fits(actor, scenario: str, obs_dim: int, options: Mapping) -> None:
    """For an actor from :func:`load_policy`: check (:func:`check_options_layout`) that the env
    of ``scenario`` built with ``options``, whose observation has ``obs_dim`` numbers, gives it
    the observation it was trained on. Any other policy (the managed surge controller, an actor
    built in code) passes unchecked."""
    trained = getattr(actor, "trained_on", None)
    if trained is not None:
        check_options_layout(trained, scenario, obs_dim, options)


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


def check_layout(
    info: Mapping,
    scenario: str,
    obs_dim: int,
    *,
    observe_current: bool = False,
    observe_command: bool = False,
    observe_filter_std: bool = False,
    action_repeat: int | None = None,
) -> None:
    """Check that an env of ``scenario`` built with these :func:`~dockingrl.make_env` options,
    whose ``observation`` has ``obs_dim`` numbers, gives the policy of ``info`` (from
    :func:`load_policy`) the observation it was trained on: the same entries in the same
    order, the same size, and (where ``action_repeat`` is given) the same action repeat. A
    different scenario of the same layout passes (``no_noise`` and ``noise``). Raises
    :class:`~dockingrl.io.ArtifactError` with one line saying what differs."""
    trained = info["observation_layout"]
    keys = observation_layout(
        scenario,
        observe_current=observe_current,
        observe_command=observe_command,
        observe_filter_std=observe_filter_std,
    )
    given = {
        "scenario": scenario,
        "keys": list(keys),
        "obs_dim": int(obs_dim),
        "action_repeat": trained["action_repeat"] if action_repeat is None else action_repeat,
    }
    if all(given[k] == trained[k] for k in ("keys", "obs_dim", "action_repeat")):
        return
    name = info.get("path", "the policy")
    raise ArtifactError(
        f"policy {name} was trained on {_describe(trained)} but the env gives {_describe(given)}"
    )


def _describe(layout: Mapping) -> str:
    text = f"scenario {layout['scenario']!r} (observation: {', '.join(layout['keys'])}; "
    text += f"{layout['obs_dim']} numbers"
    if layout["action_repeat"] != 1:
        text += f"; action_repeat {layout['action_repeat']}"
    return text + ")"


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


def training_filter(info: Mapping):
    """The learned filter a loaded policy (``info`` of :func:`load_policy`) was trained with:
    the payload it carries, else the file its config names, else ``None`` (Table 1's)."""
    return info.get("filter_params") or saved_config(info["config"]).filter_params or None
