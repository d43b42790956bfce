"""The paper's four scenarios (Sec. 4) as ready-made TorchRL pipelines."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported where used: the names and layouts here load without torch
    import torch
    from torchrl.envs import Transform, TransformedEnv

    from dockingrl.env import DockingConfig
    from dockingrl.transforms import EKFTransform

#: scenario name -> what the policy reads as ``observation`` (number of entries)
SCENARIOS = {
    "no_noise": "the true observation (6)",
    "noise": "the noisy observation (6)",
    "filtered": "h(EKF estimate) of the noisy observation (6)",
    "compound": "[noisy, h(EKF estimate)], raw first (12)",
}
#: the scenarios that run the EKF, and the keys their ``observation`` concatenates, in order
#: (``observation``: the raw reading; ``filtered_observation``: ``h`` of the estimate)
FILTERED_OBSERVATION_KEYS = {
    "filtered": ("filtered_observation",),
    "compound": ("observation", "filtered_observation"),
}


#: how the mirror ``y -> -y`` acts on one 6-number observation of eq. 2
#: ``[rho, psi, alpha, vx, vy, w]``: bearing, heading, sway and yaw rate change sign
MIRROR_OBSERVATION = (1.0, -1.0, -1.0, 1.0, -1.0, -1.0)
#: ... and on a command ``(v_d, w_d)`` or a current ``(oc_x, oc_y)``: the second entry changes sign
MIRROR_PAIR = (1.0, -1.0)
#: ... and on the EKF's state ``[x, y, alpha, nu, w]`` (eq. 22)
MIRROR_STATE = (1.0, -1.0, -1.0, 1.0, -1.0)
#: every entry the policy's ``observation`` may concatenate, with the mirror's signs on it
#: (their lengths are the entries' widths)
OBSERVATION_PARTS = {
    "observation": MIRROR_OBSERVATION,  # the reading, eq. 2 (raw, or true in ``no_noise``)
    "filtered_observation": MIRROR_OBSERVATION,  # h(EKF estimate), eq. 34
    "filter_std": (1.0, 1.0),  # ``observe_filter_std``: the estimate's std of x and y
    "ocean_current": MIRROR_PAIR,  # ``observe_current``
    "current_error": MIRROR_PAIR,  # ``observe_current_error``: the EKF's estimate of its error
    "previous_action": MIRROR_PAIR,  # ``observe_command``
}


#: the :func:`make_env` options that add entries to the policy's ``observation``
OBSERVATION_OPTIONS = (
    "observe_filter_std",
    "observe_current",
    "observe_current_error",
    "observe_command",
)


def layout_options(options) -> dict[str, bool]:
    """The :data:`OBSERVATION_OPTIONS` of ``options`` (a dict of :func:`make_env` options, a
    training config or its config.json's dict; an absent one is off), each ``True`` or
    ``False``: the keyword arguments of :func:`observation_layout` and :func:`mirror_signs`."""
    if isinstance(options, Mapping):
        return {name: bool(options.get(name)) for name in OBSERVATION_OPTIONS}
    return {name: bool(getattr(options, name, False)) for name in OBSERVATION_OPTIONS}


def observation_layout(
    scenario: str,
    *,
    observe_current: bool = False,
    observe_command: bool = False,
    observe_filter_std: bool = False,
    observe_current_error: bool = False,
) -> tuple[str, ...]:
    """The entries the policy's ``observation`` concatenates, in order, for ``scenario`` with
    the options of :func:`make_env`: the scenario's own (``FILTERED_OBSERVATION_KEYS``, or the
    reading alone), then the filter's position uncertainty, then the current, then the filter's
    estimate of the current's error, then the previous command. :func:`make_env`,
    :func:`mirror_signs` and :class:`dockingrl.onboard.OnboardStep` all read it."""
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; valid: {', '.join(SCENARIOS)}")
    for name, on in (
        ("observe_filter_std", observe_filter_std),
        ("observe_current_error", observe_current_error),
    ):
        if on and scenario not in FILTERED_OBSERVATION_KEYS:
            raise ValueError(
                f"{name} needs a scenario with the EKF "
                f"({', '.join(FILTERED_OBSERVATION_KEYS)}), not {scenario!r}"
            )
    keys = FILTERED_OBSERVATION_KEYS.get(scenario, ("observation",))
    return (
        keys
        + (("filter_std",) if observe_filter_std else ())
        + (("ocean_current",) if observe_current else ())
        + (("current_error",) if observe_current_error else ())
        + (("previous_action",) if observe_command else ())
    )


def observation_size(keys) -> int:
    """How many numbers an observation that concatenates the entries ``keys`` (an
    :func:`observation_layout`) holds."""
    return sum(len(OBSERVATION_PARTS[key]) for key in keys)


def mirror_signs(scenario: str, **options: bool) -> torch.Tensor:
    """The signs that mirror the policy's ``observation`` of ``scenario`` (with the
    :data:`OBSERVATION_OPTIONS` of :func:`make_env`, as :func:`observation_layout` takes them)
    through the docking axis, ``y -> -y``.

    The task is symmetric under that mirror: with heading, sway, yaw rate, turn command and
    ``oc_y`` negated, the dynamics (eqs. 36-38), the sensor noise (Table 2, zero-mean and
    symmetric), the EKF (eqs. 22-34, diagonal ``Q`` and ``R``), the start distribution
    (Sec. 4.1) and the reward (eqs. 4-12: ``e_alpha`` and ``y`` change sign together) are all
    unchanged. So a transition mirrored entry by entry (observations by these signs, the action
    by ``MIRROR_PAIR``, reward and flags as they are) is a transition of the same task."""
    import torch

    layout = observation_layout(scenario, **options)
    return torch.tensor([sign for key in layout for sign in OBSERVATION_PARTS[key]])


def check_mirror_symmetric(env: TransformedEnv) -> None:
    """Raise ``ValueError`` where the task of ``env`` (built by :func:`make_env`) is not
    symmetric under the mirror of :func:`mirror_signs`: a start area, station or current
    range not centred on the docking axis, or an EKF whose constant ``Q`` couples states the
    mirror negates with states it keeps (a learned full ``Q``, ``dockingrl learn-filter``).
    The manoeuvre and context terms of a learned ``Q`` and ``R`` are diagonal and read
    mirror-invariant features, so they keep the symmetry."""
    import torch

    from dockingrl.transforms import EKFTransform

    config = env.base_env.config
    for name in ("init_y", "init_heading", "dock_y", "ocean_current_range"):
        low, high = getattr(config, name)
        if not math.isclose(low, -high, abs_tol=1e-9):
            raise ValueError(f"not mirror-symmetric: {name} = {(low, high)} is not centred on 0")
    for stage in env.transform:
        if isinstance(stage, EKFTransform):
            with torch.no_grad():
                Q = stage.process_noise().double()
            signs = torch.tensor(MIRROR_STATE, dtype=Q.dtype)
            coupling = (Q * (signs.unsqueeze(-1) * signs) < 0) * Q.abs()
            if coupling.max() > 1e-6 * Q.diagonal().max():
                raise ValueError(
                    "not mirror-symmetric: the filter's Q couples y, heading or yaw rate with "
                    f"x or surge (largest such entry {coupling.max():.3g}); a learned full Q "
                    "breaks the mirror"
                )


def make_filter(
    config: DockingConfig,
    *,
    compensate_latency: bool = False,
    estimate_current: bool = False,
    **ekf_kwargs,
) -> EKFTransform:
    """The EKF transform matched to an env config (step length, action bounds); with
    ``compensate_latency`` it compensates the config's ``usbl_latency`` (``latency_steps``
    of :class:`EKFTransform`; nothing changes where the latency is 0); with
    ``estimate_current`` it is the filter that estimates the current's error
    (:class:`~dockingrl.transforms.current_filter.CurrentEstimatingEKF`, not in the paper)."""
    from dockingrl.transforms import EKFTransform
    from dockingrl.transforms.current_filter import CurrentEstimatingEKF

    if compensate_latency:
        ekf_kwargs.setdefault("latency_steps", config.usbl_latency_steps)
    ekf_kwargs.setdefault("dt", config.dt)
    ekf_kwargs.setdefault("action_low", config.action_low)
    ekf_kwargs.setdefault("action_high", config.action_high)
    return (CurrentEstimatingEKF if estimate_current else EKFTransform)(**ekf_kwargs)


def make_env(
    scenario: str,
    num_envs: int = 1,
    *,
    seed: int | None = None,
    device: torch.device | str = "cpu",
    config: DockingConfig | None = None,
    filter_params: str | Path | Mapping | None = None,
    ekf_kwargs: dict | None = None,
    transforms: Sequence[Transform] = (),
    compile: bool = False,
    observe_current: bool = False,
    observe_command: bool = False,
    observe_filter_std: bool = False,
    observe_current_error: bool = False,
    action_repeat: int = 1,
) -> TransformedEnv:
    """Build one of the paper's four scenarios (Sec. 4) as a ``TransformedEnv``.

    The policy always reads ``observation``: 6 numbers in ``no_noise``, ``noise`` and
    ``filtered``, 12 in ``compound`` (raw first). In the filtered scenarios the raw noisy
    observation stays available to the filter, and ``filtered_observation``, ``ekf_mean`` and
    ``ekf_cov`` are in the tensordict too.

    Args:
        scenario: one of ``no_noise``, ``noise``, ``filtered``, ``compound``.
        num_envs: batch size.

    Keyword Args:
        seed: env seed (see :class:`DockingEnv`).
        device: torch device.
        config: env constants; ``noise`` is set by the scenario.
        filter_params: learned ``Q`` and ``R`` (``dockingrl learn-filter``): a file, or its
            payload (:func:`~dockingrl.transforms.params.read_filter_params`; a saved
            policy carries its own).
        ekf_kwargs: extra :class:`EKFTransform` options (e.g. ``learnable=True``).
        transforms: more transforms appended after the scenario's own (e.g. a normaliser).
        compile: ``torch.compile`` the simulation and filter steps (faster for thousands of
            envs; the first step compiles, about half a minute on a 2-core CPU).
        observe_current: append the ocean current ``(oc_x, oc_y)`` (DS frame, m/s) to
            ``observation`` (+2 entries, last). Not in the paper: its policies see ground
            velocities only, although its EKF assumes the current known (Sec. 3.5, from the
            DVL's water track); this gives the policy the same knowledge.
        observe_command: append the command applied at the previous step (zeros at an
            episode's start; :class:`~dockingrl.transforms.PreviousAction`) to ``observation``
            (+2 entries, last, after the current's). Not in the paper: the vehicle knows
            what it commanded, and with it the ground velocity tells its own speed through
            the water from the current's drift.
        observe_filter_std: append the standard deviations (m) of the EKF's ``x`` and ``y``
            (:class:`~dockingrl.transforms.observations.FilterStd`) to ``observation`` (+2
            entries, after the scenario's; ``filtered`` and ``compound`` only). Not in the
            paper: with slow, late or lost fixes (docs/realism.md) it tells the policy how
            far its estimate may be off.
        observe_current_error: append the filter's estimate of the error of the believed
            current (:class:`~dockingrl.transforms.observations.CurrentError`; +2 entries,
            after the current's), from the filter that estimates it
            (``ekf_kwargs={"estimate_current": True}``). Not in the paper: with a biased
            belief about the current (docs/realism.md) it tells the policy what the fixes
            say of that bias.
        action_repeat: hold each action for this many steps of ``dt``
            (:class:`~dockingrl.transforms.ActionRepeat`, not in the paper): one env step is
            then ``action_repeat`` simulation steps, with their rewards summed. Placed before
            ``transforms``.
    """
    from torchrl.envs import Compose, TransformedEnv

    from dockingrl.env import DockingEnv
    from dockingrl.env.config import config_or_default
    from dockingrl.transforms import ActionRepeat, CompoundObservation, PreviousAction
    from dockingrl.transforms.observations import CurrentError, FilterStd
    from dockingrl.transforms.repeat import check_action_repeat

    layout = observation_layout(
        scenario,
        observe_current=observe_current,
        observe_command=observe_command,
        observe_filter_std=observe_filter_std,
        observe_current_error=observe_current_error,
    )
    config = config_or_default(config).replace(noise=scenario != "no_noise")
    base = DockingEnv(num_envs, config=config, device=device, seed=seed, compile_step=compile)
    stages: list[Transform] = []
    if scenario in FILTERED_OBSERVATION_KEYS:
        ekf = make_filter(config, **{"compile": compile, **(ekf_kwargs or {})})
        if filter_params is not None:
            ekf.load_filter_params(filter_params)
        stages.append(ekf)
        if observe_filter_std:
            stages.append(FilterStd(cov_key=ekf.cov_key))
        if observe_current_error:
            stages.append(CurrentError(ekf))
    elif filter_params is not None or ekf_kwargs:
        raise ValueError(f"scenario {scenario!r} has no filter: filter options do not apply")
    if observe_command:
        stages.append(PreviousAction(config.action_low, config.action_high))
    if layout != ("observation",):
        stages.append(CompoundObservation(layout))
    if check_action_repeat(action_repeat) > 1:
        stages.append(ActionRepeat(action_repeat))
    stages += list(transforms)
    return TransformedEnv(base, Compose(*stages))
