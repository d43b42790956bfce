"""The realism options of :class:`~dockingrl.env.DockingConfig` (not in the paper), as pure
batched tensor functions: slow and late USBL fixes with dropouts and outliers, sensors at their
own rates, a slowly varying ocean current known only approximately, and a vehicle whose
dynamics differ from the nominal ones per episode. :class:`~dockingrl.env.DockingEnv` keeps
their per-env state and draws their randomness from its own realism generator, so that turning
an option on leaves the start states and Table 2's noise of every episode as they were.
docs/realism.md gives each option's physical reason and a typical value.
"""

from __future__ import annotations

import math

import torch

from dockingrl.env.config import DockingConfig, retuned_gains
from dockingrl.env.dynamics import wrap_angle
from dockingrl.env.realism_options import SCALE_RANGES

#: the sensors whose readings' ages ``sensor_age`` reports, in its column order
SENSORS = ("usbl", "dvl", "imu")
#: which sensor each of the six observation entries (eq. 2) comes from
SENSOR_OF_ENTRY = (0, 0, 2, 1, 1, 2)


def ou_current_step(
    current: torch.Tensor,
    mean: torch.Tensor,
    dt: float,
    time_constant: float,
    std: float,
    standard_normal: torch.Tensor,
) -> torch.Tensor:
    """One exact step of an Ornstein-Uhlenbeck process around ``mean`` (both ``(..., 2)``,
    m/s) with time constant ``time_constant`` (s) and stationary standard deviation ``std``
    (m/s): ``c' = mean + (c - mean) e^(-dt/T) + std sqrt(1 - e^(-2 dt/T)) N``."""
    decay = math.exp(-dt / time_constant)
    return mean + (current - mean) * decay + std * math.sqrt(1.0 - decay * decay) * standard_normal


def dropout_transition(lost_probability: float, burst: float) -> tuple[float, float]:
    """``(p_lose, p_stay_lost)``: the two-state Markov chain over scheduled fixes that loses a
    fraction ``lost_probability`` of them in bursts of ``burst`` fixes on average (0:
    independent losses, ``p_lose = p_stay_lost = lost_probability``)."""
    if burst == 0:
        return lost_probability, lost_probability
    stay = 1.0 - 1.0 / burst
    return lost_probability / (burst * (1.0 - lost_probability)), stay


def dropout_step(
    lost: torch.Tensor, uniform: torch.Tensor, p_lose: float, p_stay_lost: float
) -> torch.Tensor:
    """The chain's next state (``lost`` bool) from a ``uniform`` draw in [0, 1)."""
    return torch.where(lost, uniform < p_stay_lost, uniform < p_lose)


def usbl_outlier(
    usbl: torch.Tensor, distance: float, direction: torch.Tensor, is_outlier: torch.Tensor
) -> torch.Tensor:
    """USBL readings ``(..., 2)`` ``(rho, psi)`` whose fix is moved ``distance`` m in the
    direction ``direction`` (rad, ``(...)``) where ``is_outlier`` (bool ``(...)``). The move is
    made in the vehicle's frame, so the heading is not needed; the position the reading
    describes is then exactly ``distance`` from the original one."""
    rho, psi = usbl.unbind(-1)
    # the DS is at bearing psi, so the vehicle sits at -rho (cos psi, sin psi) from it
    x = -rho * torch.cos(psi) + distance * torch.cos(direction)
    y = -rho * torch.sin(psi) + distance * torch.sin(direction)
    moved = torch.stack((torch.sqrt(x * x + y * y), wrap_angle(torch.atan2(-y, -x))), dim=-1)
    return torch.where(is_outlier.unsqueeze(-1), moved, usbl)


def limit_thrust(
    tau: torch.Tensor, max_thrust: torch.Tensor, reverse_loss: float, turning_loss: float
) -> torch.Tensor:
    """The surge thrust ``tau[..., 0]`` limited to ``(1 - reverse_loss) max_thrust`` in
    reverse and, in both directions, to ``(1 - turning_loss |tau_r| / max_thrust)`` of its
    limit: a propeller weaker backwards, a vectored thruster that pushes less forward while it
    turns. ``tau`` ``(..., 2)`` is PID-clipped to ``+-max_thrust`` (``(..., 1)``) already."""
    surge, yaw = tau.unbind(-1)
    limit = max_thrust.squeeze(-1)
    authority = 1.0 - turning_loss * (yaw.abs() / limit).clamp_max(1.0)
    surge = torch.minimum(surge, limit * authority)
    surge = torch.maximum(surge, -(1.0 - reverse_loss) * limit * authority)
    return torch.stack((surge, yaw), dim=-1)


def draw_scales(config: DockingConfig, n: int, generator, device, dtype) -> torch.Tensor:
    """``(n, 5)`` per-episode factors, uniform within the ranges of
    :data:`~dockingrl.env.realism_options.SCALE_RANGES`, in that order (mass, damping, thrust,
    PID gains, response time)."""
    low = torch.tensor([getattr(config, k)[0] for k in SCALE_RANGES], device=device, dtype=dtype)
    high = torch.tensor([getattr(config, k)[1] for k in SCALE_RANGES], device=device, dtype=dtype)
    u = torch.rand(n, len(SCALE_RANGES), generator=generator, device=device, dtype=dtype)
    return low + (high - low) * u


def vehicle_parameters(config: DockingConfig, scales: torch.Tensor) -> dict[str, torch.Tensor]:
    """The per-env vehicle of the factors ``scales`` ``(n, 5)`` (:func:`draw_scales`): PID gains
    ``kp``, ``ki``, ``kd`` ``(n, 2)`` (surge, yaw), ``inertia`` ``(n, 3)``, damping ``linear``
    and ``quadratic`` ``(n, 1)`` and ``max_thrust`` ``(n, 1)``."""
    mass, damping, thrust, gain, response = (s.unsqueeze(-1) for s in scales.unbind(-1))
    dtype, device = scales.dtype, scales.device

    def pair(*values: float) -> torch.Tensor:
        return torch.tensor(values, dtype=dtype, device=device)

    kp, ki, kd = retuned_gains(
        pair(config.surge_kp, config.yaw_kp),
        pair(config.surge_ki, config.yaw_ki),
        pair(config.surge_kd, config.yaw_kd),
        config.linear_damping,
        gain,
        response,
    )
    return {
        "kp": kp,
        "ki": ki,
        "kd": kd,
        "inertia": pair(config.mass, config.mass, config.yaw_inertia) * mass,
        "linear": config.linear_damping * damping,
        "quadratic": config.quadratic_damping * damping,
        "max_thrust": config.max_thrust * thrust,
    }
