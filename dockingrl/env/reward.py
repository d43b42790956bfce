"""Reward terms of the docking task (Sec. 3.2, eqs. 4-12), on tensors of any batch or on one
env's Python floats (:mod:`dockingrl.env.arrays`)."""

from __future__ import annotations

import math

import torch

from dockingrl.env.arrays import ops
from dockingrl.env.dynamics import wrap_angle


def distance_reward(rho: torch.Tensor, max_dist: float) -> torch.Tensor:
    """Eq. 4: ``r_dist = -rho / max_dist``."""
    return -rho / max_dist


def thrust_reward(tau: torch.Tensor, thrust_weight: float) -> torch.Tensor:
    """Eq. 5: ``r_tau = -||tau|| / w_tau`` over the (surge, yaw) command ``tau`` ``(..., 2)``."""
    return -ops(tau).norm(tau) / thrust_weight


def entry_velocity_reward(
    speed: torch.Tensor,
    rho: torch.Tensor,
    speed_max: float,
    approach_distance: float,
    weight: float,
) -> torch.Tensor:
    """Eq. 6: penalise ground speed above ``v_max`` inside the approach distance.

    ``-w_vel * max(V - v_max, 0) * (d_appro - rho) / d_appro`` when ``rho < d_appro``, else 0.
    """
    xp = ops(speed)
    excess = xp.clamp_min(speed - speed_max, 0.0)
    closeness = xp.clamp_min((approach_distance - rho) / approach_distance, 0.0)
    return -weight * excess * closeness


def contact_score(
    x: torch.Tensor,
    y: torch.Tensor,
    alpha: torch.Tensor,
    aligned_weight: float = 1.0,
    misaligned_weight: float = 3.05,
) -> torch.Tensor:
    """Entry quality ``g`` of Esteba et al. (eqs. 7-10). ``g = 1`` for a perfect entry.

    ``alpha_0 = atan2(y, x) - pi`` (eq. 7) is the heading that points from the AUV at the DS
    origin; ``e_alpha = alpha - alpha_0`` (eq. 8); ``w = w_1`` if ``sign(e_alpha) == sign(y)``
    else ``w_2`` (eq. 9, ``sign(0) = 0`` as numpy); ``g = 1 - w |e_alpha| (1 + |alpha_0|)``
    (eq. 10). Both angles are wrapped to (-pi, pi] so that a heading just across +-pi scores
    like its twin. ``0 < g <= 1`` when the AUV enters the funnel, ``g <= 0`` when it misses.
    """
    xp = ops(x)
    alpha_0 = wrap_angle(xp.atan2(y, x) - math.pi)
    e_alpha = wrap_angle(alpha - alpha_0)
    aligned = xp.sign(e_alpha) == xp.sign(y)
    weight = xp.where(aligned, aligned_weight, misaligned_weight)
    return 1.0 - weight * abs(e_alpha) * (1.0 + abs(alpha_0))


def contact_reward(score: torch.Tensor, contact_weight: float) -> torch.Tensor:
    """Eq. 11: ``r_g = g * w_contact``."""
    return score * contact_weight
