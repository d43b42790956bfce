"""The managed surge controller (Sec. 3.3, eqs. 13-21), the paper's model-based baseline.

It follows a straight line towards the docking station, offset by ``y_g`` and crabbed against
the current by ``theta_crab``, while it regulates the surge so that the ground speed along the
axis approaches ``v_max``. Implemented literally: see ``docs/fidelity.md`` for what that implies
against Table 7.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from dockingrl.env.dynamics import pose_from_observation


@dataclass(frozen=True)
class ManagedSurgeConstants:
    """Constants of Sec. 3.3 (paper values)."""

    funnel_half_width: float = 0.5  # F_y, m
    funnel_length: float = 2.0  # F_x, m
    auv_length: float = 1.6  # l, m
    look_ahead: float = 6.0  # Delta_d, m
    yaw_gain: float = 0.5  # K_w, 1/s
    surge_gain: float = 0.5  # k_1, m/s
    cross_track_gain: float = 1.0  # k_2, 1/m
    entry_speed: float = 0.3  # v_max, m/s
    surge_min: float = -0.4  # m/s, eq. 21 clip
    surge_max: float = 0.8  # m/s, eq. 21 clip
    yaw_rate_max: float = 0.3  # rad/s, eq. 19 clip

    @property
    def funnel_diagonal(self) -> float:
        """``F = sqrt(F_x^2 + F_y^2)``."""
        return math.hypot(self.funnel_length, self.funnel_half_width)


def managed_surge_action(
    x: torch.Tensor,
    y: torch.Tensor,
    alpha: torch.Tensor,
    current: torch.Tensor,
    constants: ManagedSurgeConstants | None = None,
    **overrides: float,
) -> torch.Tensor:
    """Desired ``[v_d, w_d]`` of the managed surge controller, eqs. 13-21, batched.

    Args:
        x, y, alpha: AUV position (m) and heading (rad) in the DS frame, any batch shape.
        current: ``(..., 2)`` ocean current ``(oc_x, oc_y)`` in the DS frame (m/s).
        constants: :class:`ManagedSurgeConstants` (paper values by default); single constants
            can be overridden by keyword (e.g. ``look_ahead=8.0``).

    Returns:
        ``(..., 2)`` action.
    """
    c = constants or ManagedSurgeConstants()
    if overrides:
        c = ManagedSurgeConstants(**{**c.__dict__, **overrides})
    oc_x, oc_y = current[..., 0], current[..., 1]
    x_ss = c.entry_speed - oc_x  # eq. 13: stream sign
    direction = torch.sign(x_ss)  # numpy convention: sign(0) = 0
    theta_crab = torch.atan2(-oc_y, c.entry_speed - oc_x)  # eq. 14
    theta_limit = math.atan(c.funnel_half_width / c.funnel_length)  # eq. 15
    y_g = torch.where(  # eq. 16
        theta_crab.abs() <= theta_limit,
        -(c.funnel_diagonal + c.auv_length / 2) * torch.sin(theta_crab),
        -torch.sign(theta_crab) * c.funnel_half_width / 2,
    )
    e = y - y_g * direction  # eq. 17
    beta = torch.atan2(e, c.look_ahead * direction)  # eq. 18
    w_d = (((theta_crab - beta) - alpha) * c.yaw_gain).clamp(-c.yaw_rate_max, c.yaw_rate_max)
    speed_correction = c.surge_gain * torch.atan(c.cross_track_gain * e) * torch.sign(alpha)
    v_d = (x_ss / torch.cos(alpha) - speed_correction).clamp(c.surge_min, c.surge_max)  # 20-21
    return torch.stack((v_d, w_d), dim=-1)


class ManagedSurgePolicy(TensorDictModuleBase):
    """The controller as a TorchRL policy: reads a tensordict, writes ``action``.

    By default it recovers ``(x, y, alpha)`` from the noisy ``observation`` (eq. 26 inverted), as
    in the paper's Table 7; ``use_filter=True`` reads the EKF estimate ``ekf_mean`` instead
    (scenarios ``filtered`` and ``compound``). The current comes from ``ocean_current``.
    Deterministic; usable wherever a learned policy is (``env.rollout(n, policy)``,
    :func:`dockingrl.evaluate`).
    """

    def __init__(
        self, *, use_filter: bool = False, constants: ManagedSurgeConstants | None = None
    ) -> None:
        super().__init__()
        self.use_filter = use_filter
        self.constants = constants or ManagedSurgeConstants()
        self.in_keys = ["ekf_mean" if use_filter else "observation", "ocean_current"]
        self.out_keys = ["action"]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self.use_filter:
            if "ekf_mean" not in tensordict.keys():
                raise KeyError(
                    "use_filter=True needs 'ekf_mean': evaluate in the 'filtered' or "
                    "'compound' scenario"
                )
            pose = tensordict.get("ekf_mean")[..., :3]
        else:
            pose = pose_from_observation(tensordict.get("observation"))
        x, y, alpha = pose.unbind(-1)
        action = managed_surge_action(x, y, alpha, tensordict.get("ocean_current"), self.constants)
        tensordict.set("action", action)
        return tensordict
