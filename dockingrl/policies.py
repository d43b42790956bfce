"""Policies as ``dockingrl eval`` and ``dockingrl stress`` take them: the managed surge
controller or a saved agent, the world the agent was trained in, and Figure 10's cases."""

from __future__ import annotations

from pathlib import Path

from dockingrl.env import DockingConfig

#: Figure 10's currents (caption) with a start on each side of the axis: the first of each pair
#: is pushed towards the axis by the lateral current, the second has to work against it.
FIGURE_10_CASES = [
    {"start": (-28.0, 6.0, 0.0), "ocean_current": (0.05, -0.1)},
    {"start": (-28.0, -6.0, 0.0), "ocean_current": (0.05, -0.1)},
    {"start": (-28.0, 6.0, 0.0), "ocean_current": (-0.15, -0.3)},
    {"start": (-28.0, -6.0, 0.0), "ocean_current": (-0.15, -0.3)},
    {"start": (-28.0, 6.0, 0.0), "ocean_current": (0.3, -0.3)},
    {"start": (-28.0, -6.0, 0.0), "ocean_current": (0.3, -0.3)},
]


def resolve_policy(spec: str, *, use_filter: bool = False, device: str = "cpu"):
    """``managed_surge`` or the path of a policy saved by training. Returns
    ``(policy, name, scenario or None, make_env options the policy was trained with, its
    ``info`` from :func:`dockingrl.agents.saving.load_policy`, empty for the controller)``; the
    name is the policy's recipe where its file holds one, else its algorithm."""
    if spec == "managed_surge":
        from dockingrl.agents import ManagedSurgePolicy

        return ManagedSurgePolicy(use_filter=use_filter), "managed_surge", None, {}, {}
    if not Path(spec).exists():
        raise FileNotFoundError(f"policy {spec!r}: neither 'managed_surge' nor a file")
    from dockingrl.agents.saving import load_policy as load_saved

    policy, meta = load_saved(spec, device=device)
    options = dict(meta["env_options"])
    name = meta["config"].get("recipe") or meta.get("algo", "agent")
    return policy, name, meta.get("scenario"), options, meta


def evaluation_world(
    scenario: str,
    info: dict,
    *,
    range_noise_scale: float | None = None,
    bearing_noise_scale: float | None = None,
    speed_tolerance: float = 0.0,
    filter_params: str | None = None,
    vehicle: str = "paper",
) -> tuple[dict, str]:
    """The env options of an evaluation beyond the policy's pipeline: the USBL noise scales
    and the learned filter the policy was trained with (``info`` of the saved policy), unless
    given (``filter_params="none"``: Table 1's filter); and a line saying what was taken from
    the policy. ``vehicle``: the vehicle flown (:attr:`DockingConfig.vehicle`)."""
    from dockingrl.agents.layout import saved_config, training_filter
    from dockingrl.scenarios import FILTERED_OBSERVATION_KEYS

    trained = saved_config(info["config"]) if info else None
    taken = []
    scales = []
    for name, value in (
        ("range_noise_scale", range_noise_scale),
        ("bearing_noise_scale", bearing_noise_scale),
    ):
        if value is None:
            value = float(getattr(trained, name)) if trained is not None else 1.0
            if value != 1.0:
                taken.append(f"{name} {value:g}")
        scales.append(value)
    config = DockingConfig(contact_speed_tolerance=speed_tolerance, vehicle=vehicle)
    config = config.scale_usbl_noise(*scales)
    kwargs: dict = {"config": config}
    params = filter_params
    if params is None and scenario in FILTERED_OBSERVATION_KEYS and info:
        params = training_filter(info)
        if params is not None:
            taken.append(f"filter_params {trained.filter_params}")
    if params == "none":
        params = None
    elif isinstance(params, str) and not Path(params).is_file():
        what = "a folder, not a file" if Path(params).is_dir() else "no such file"
        raise FileNotFoundError(f"--filter-params {params!r}: {what}")
    if params is not None:
        kwargs["filter_params"] = params
    line = f"as the policy was trained: {', '.join(taken)}" if taken else ""
    return kwargs, line


def trained_filter_options(trained: dict, scenario: str, options: dict) -> dict:
    """``options`` (the make_env options of a saved policy, ``info`` ``trained``) checked
    against ``scenario``'s observation, with the learned filter the policy was trained with
    where ``scenario`` filters."""
    from dockingrl.agents.layout import check_env_layout, training_filter
    from dockingrl.scenarios import FILTERED_OBSERVATION_KEYS

    check_env_layout(trained, scenario, options)
    params = training_filter(trained) if scenario in FILTERED_OBSERVATION_KEYS else None
    return {**options, "filter_params": params} if params is not None else dict(options)
