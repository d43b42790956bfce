"""Every constant of the docking task, in one validated dataclass, :class:`DockingConfig`:
the task's fields (:mod:`dockingrl.env.task_options`) and the realism options
(:mod:`dockingrl.env.realism_options`) composed, with the checks that need both (the PID
velocity loops' stability, :meth:`DockingConfig.velocity_loop_radius`).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import numbers
from dataclasses import dataclass

import numpy as np

from dockingrl.env.bounds import Bound, field_problem, is_real
from dockingrl.env.realism_options import REALISM_BOUNDS, SCALE_RANGES, RealismOptions
from dockingrl.env.task_options import TASK_BOUNDS, TaskOptions

__all__ = ["BOUNDS", "SCALE_RANGES", "DockingConfig", "noise_scale_problem", "retuned_gains"]

#: The accepted range of every number of :class:`DockingConfig` (each entry of a pair), with
#: its reason. Every accepted config keeps the simulation finite in float32: the long rollouts of
#: ``tests/test_validation.py`` at the extreme values show it. The paper's values lie well inside.
BOUNDS: dict[str, Bound] = {**TASK_BOUNDS, **REALISM_BOUNDS}


@dataclass(frozen=True)
class DockingConfig(RealismOptions, TaskOptions):
    """Constants of the docking task. Angles in rad, lengths in m, times in s.

    Its fields are the task's (:class:`~dockingrl.env.task_options.TaskOptions`: the paper's
    constants and the training draws of the start state) followed by the realism options
    (:class:`~dockingrl.env.realism_options.RealismOptions`, all off by default).

    Validated on creation: every number must be finite and within its :data:`BOUNDS`, and both
    PID velocity loops must settle at ``dt`` (:meth:`velocity_loop_radius` < 1); a refusal is a
    ``ValueError`` naming the field, the valid range and the value."""

    def __post_init__(self) -> None:
        def fail(name: str, why: str) -> None:
            raise ValueError(f"DockingConfig.{name}: {why} (got {getattr(self, name)!r})")

        for field in dataclasses.fields(self):
            problem = field_problem(field.type, getattr(self, field.name), BOUNDS.get(field.name))
            if problem:
                fail(field.name, problem)
        self._check_gains(fail)
        for axis, inertia in (("surge", "mass"), ("yaw", "yaw_inertia")):
            radius = self.velocity_loop_radius(axis)
            if radius >= 1.0:
                fail(
                    f"{axis}_kp",
                    f"the {axis} PID loop diverges with these gains, dt = {self.dt:g} s and "
                    f"{inertia} = {getattr(self, inertia):g} (spectral radius {radius:.3g} >= 1): "
                    f"lower the gains or dt, or raise {inertia}",
                )
        self._check_ranges(fail)
        self._check_realism(fail)
        for axis in ("surge", "yaw") if self.dynamics_mismatch else ():
            radius = self.velocity_loop_radius(axis, worst_case=True)
            if radius >= 1.0:
                fail(
                    "pid_gain_scale",
                    f"the {axis} PID loop diverges at the extremes of the dynamics scales "
                    f"(largest gains, lightest vehicle, fastest response: spectral radius "
                    f"{radius:.3g} >= 1): narrow pid_gain_scale, mass_scale or "
                    f"response_time_scale",
                )

    def velocity_loop_radius(self, axis: str, *, worst_case: bool = False) -> float:
        """Spectral radius of the ``axis`` (``"surge"`` or ``"yaw"``) velocity loop, the PID of
        :func:`~dockingrl.env.dynamics.pid_thrust` and the explicit-Euler step of eq. 37
        linearised with the steepest damping slope ``K_dl + 2 K_qdl max_velocity``, unclipped.
        Below 1 the loop settles; at or above 1 a step-to-step oscillation grows until the
        thrust and acceleration clips hold it. A settling surge loop implies a settling
        unactuated sway (``dt * slope / mass < 2``). ``worst_case``: the largest radius over
        the corners of the per-episode scales (``pid_gain_scale``, ``mass_scale``,
        ``damping_scale``, ``response_time_scale``)."""
        kp, ki, kd = (getattr(self, f"{axis}_{gain}") for gain in ("kp", "ki", "kd"))
        inertia = self.mass if axis == "surge" else self.yaw_inertia
        corners = [(1.0, 1.0, 1.0, 1.0)]
        if worst_case:
            corners = list(
                itertools.product(
                    self.pid_gain_scale,
                    self.mass_scale,
                    self.damping_scale,
                    self.response_time_scale,
                )
            )
        radii = []
        for gain, mass, damping, response in corners:
            gains = retuned_gains(kp, ki, kd, self.linear_damping, gain, response)
            slope = damping * (
                self.linear_damping + 2.0 * self.quadratic_damping * self.max_velocity
            )
            radii.append(_loop_radius(*gains, inertia * mass, slope, self.dt))
        return max(radii)

    def replace(self, **changes) -> DockingConfig:
        """Return a copy with ``changes`` applied (validated again)."""
        return dataclasses.replace(self, **changes)

    def scale_usbl_noise(self, range_scale: float = 1.0, bearing_scale: float = 1.0):
        """A copy whose USBL range and bearing sigmas (Table 2) are multiplied by these
        factors: the sensor-mismatch world of ``--range-noise-scale`` and
        ``--bearing-noise-scale`` (the filter keeps Table 2). A scale that takes a sigma out of
        :data:`BOUNDS` is refused, named."""
        for name, scale, sigma in (
            ("range_scale", range_scale, "range_noise_fraction"),
            ("bearing_scale", bearing_scale, "bearing_noise"),
        ):
            problem = noise_scale_problem(scale, sigma, getattr(self, sigma))
            if problem:
                raise ValueError(f"DockingConfig.scale_usbl_noise: {name} {problem}")
        return self.replace(
            range_noise_fraction=self.range_noise_fraction * range_scale,
            bearing_noise=self.bearing_noise * bearing_scale,
        )


def config_or_default(config: DockingConfig | None) -> DockingConfig:
    """``config``, or the paper's constants for ``None``; a one-line ``TypeError`` for
    anything else (a path or a dict is not a config)."""
    if config is None:
        return DockingConfig()
    if not isinstance(config, DockingConfig):
        raise TypeError(f"config must be a DockingConfig, got {type(config).__name__}")
    return config


def retuned_gains(kp, ki, kd, linear_damping, gain_scale=1.0, response_time_scale=1.0):
    """PID gains ``(kp, ki, kd)`` (numbers or tensors) scaled by ``gain_scale`` after being
    retuned so that the linear closed loop of eq. 37 with damping ``linear_damping`` runs
    ``response_time_scale`` times slower: ``kp + K_dl`` / s, ``ki`` / s^2 and ``kd`` / s, ``kp``
    floored at 0 (:attr:`DockingConfig.response_time_scale`). Scales of 1 return the gains
    unchanged."""
    if isinstance(response_time_scale, numbers.Real) and response_time_scale == 1.0:
        return kp * gain_scale, ki * gain_scale, kd * gain_scale
    proportional = (kp + linear_damping) / response_time_scale - linear_damping
    if isinstance(proportional, numbers.Real):
        proportional = max(proportional, 0.0)
    else:
        proportional = proportional.clamp_min(0.0)
    return (
        proportional * gain_scale,
        ki / response_time_scale**2 * gain_scale,
        kd / response_time_scale * gain_scale,
    )


def _loop_radius(kp, ki, kd, m, slope, dt) -> float:
    # state (v, integral, previous error); error = -v for a zero set-point
    full = np.array(
        [
            [1 - dt * (kp + slope) / m - dt * dt * ki / m - kd / m, dt * ki / m, -kd / m],
            [-dt, 1.0, 0.0],
            [-1.0, 0.0, 0.0],
        ]
    )
    keep = [0, 1, 2] if ki else [0, 2]  # without ki the integral never acts
    return float(np.abs(np.linalg.eigvals(full[np.ix_(keep, keep)])).max())


def noise_scale_problem(scale, sigma: str, base: float | None = None) -> str:
    """Why ``scale`` may not multiply the sensor sigma ``sigma`` (``base``, Table 2's value by
    default) of :class:`DockingConfig`: the product must stay within :data:`BOUNDS`; ``""``
    when it may."""
    base = getattr(DockingConfig, sigma) if base is None else base
    high = BOUNDS[sigma].high
    if is_real(scale) and math.isfinite(scale) and 0 <= scale * base <= high:
        return ""
    top = f"{high / base:g}" if base else "any"
    return (
        f"must lie in [0, {top}] so that {sigma} ({base:g} x the scale) stays within "
        f"[0, {high:g}] (got {scale!r})"
    )
