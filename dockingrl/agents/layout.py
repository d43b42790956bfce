"""What a saved policy needs of the env that runs it, and the checks that an env gives it:
the :func:`~dockingrl.make_env` options its training config fixes (:func:`pipeline_options`),
the learned filter it was trained with (:func:`training_filter`), and its observation layout
(:func:`policy_layout`, checked by :func:`check_layout` and, against an env built for it,
:func:`check_env_layout`)."""

from __future__ import annotations

from collections.abc import Mapping

from dockingrl.agents.world_options import PAPER_RESPONSE_RATE
from dockingrl.io import ArtifactError
from dockingrl.scenarios import OBSERVATION_OPTIONS, layout_options, observation_layout


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
    ``observe_filter_std``, ``observe_current_error``, ``action_repeat`` and the filter's
    ``compensate_latency``, ``estimate_current``, ``filter_gate`` and ``filter_response_rate``
    (as ``ekf_kwargs``), where they differ from the paper's. Training, ``dockingrl eval
    --policy``, ``dockingrl stress`` and ``OnboardPolicy.from_file`` all take them from here."""
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


def training_filter(info: Mapping):
    """The learned filter a loaded policy (``info`` of :func:`~dockingrl.agents.saving.load_policy`)
    was trained with: the payload it carries, else the file its config names, else ``None`` (Table
    1's)."""
    return info.get("filter_params") or saved_config(info["config"]).filter_params or None


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


def reject_policy_pair(actor, name: str, hint: str) -> None:
    """Raise one ``TypeError`` when ``actor`` is the ``(actor, info)`` pair that
    :func:`~dockingrl.agents.saving.load_policy` returns rather than its actor; ``hint`` says what
    to pass instead."""
    if isinstance(actor, tuple):
        raise TypeError(
            f"{name} is a tuple (load_policy returns the pair (actor, info)): pass the actor, "
            f"{hint}"
        )


def check_layout(
    info: Mapping,
    scenario: str,
    obs_dim: int,
    *,
    observe_current: bool = False,
    observe_command: bool = False,
    observe_filter_std: bool = False,
    observe_current_error: bool = False,
    action_repeat: int | None = None,
) -> None:
    """Check that an env of ``scenario`` built with these :func:`~dockingrl.make_env` options, whose
    ``observation`` has ``obs_dim`` numbers, gives the policy of ``info`` (from
    :func:`~dockingrl.agents.saving.load_policy`) the observation it was trained on: the same
    entries in the same order, the same size, and (where ``action_repeat`` is given) the same action
    repeat. A different scenario of the same layout passes (``no_noise`` and ``noise``). Raises
    :class:`~dockingrl.io.ArtifactError` with one line saying what differs."""
    trained = info["observation_layout"]
    keys = observation_layout(
        scenario,
        observe_current=observe_current,
        observe_command=observe_command,
        observe_filter_std=observe_filter_std,
        observe_current_error=observe_current_error,
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


def check_env_layout(info: Mapping, scenario: str, options: Mapping) -> None:
    """Check that the saved policy of ``info`` (from
    :func:`~dockingrl.agents.saving.load_policy`) reads what the env of ``scenario`` built by
    :func:`~dockingrl.make_env` with ``options`` (``observe_*``, ``action_repeat``) gives:
    :func:`check_layout` against that env's observation spec. Raises
    :class:`~dockingrl.io.ArtifactError`, one line saying what differs."""
    from dockingrl.scenarios import make_env

    if options.get("observe_current_error"):  # read from the filter that estimates it
        filter_options = {**options.get("ekf_kwargs", {}), "estimate_current": True}
        options = {**options, "ekf_kwargs": filter_options}
    env = make_env(scenario, 1, **options)
    check_options_layout(info, scenario, env.observation_spec["observation"].shape[-1], options)


def check_actor_fits(actor, scenario: str, obs_dim: int, options: Mapping) -> None:
    """For an actor from :func:`~dockingrl.agents.saving.load_policy`: check
    (:func:`check_options_layout`) that the env of ``scenario`` built with ``options``, whose
    observation has ``obs_dim`` numbers, gives it the observation it was trained on. Any other
    policy (the managed surge controller, an actor built in code) passes unchecked."""
    trained = getattr(actor, "trained_on", None)
    if trained is not None:
        check_options_layout(trained, scenario, obs_dim, options)


def _describe(layout: Mapping) -> str:
    text = f"scenario {layout['scenario']!r} (observation: {', '.join(layout['keys'])}; "
    text += f"{layout['obs_dim']} numbers"
    if layout["action_repeat"] != 1:
        text += f"; action_repeat {layout['action_repeat']}"
    return text + ")"
