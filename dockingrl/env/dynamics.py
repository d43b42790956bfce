"""Vehicle model and sensor geometry of the docking task.

Every function works on tensors of any leading batch shape (differentiable where the maths is)
and on one env's Python floats, vectors as tuples (:mod:`dockingrl.env.arrays`); an
element-wise function takes one axis's floats. Frames: the world frame is the docking-station
(DS) frame, DS at the origin, funnel mouth towards -x; ``alpha`` is the AUV heading in that
frame (0 = pointing at the DS along +x). Body-frame velocities ``(u, v, r)`` are surge, sway
and yaw rate through the water.
"""

from __future__ import annotations

import math

import torch

from dockingrl.env.arrays import ops

TWO_PI = 2.0 * math.pi


def wrap_angle(angle: torch.Tensor) -> torch.Tensor:
    """Wrap angles to (-pi, pi]."""
    return math.pi - ops(angle).remainder(math.pi - angle, TWO_PI)


def clip_action(action: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """The command the vehicle applies (eq. 3): ``action`` ``(..., 2)`` clipped to the bounds
    ``low`` and ``high`` ``(2,)``. The env steps with it; the EKF predicts with it and the
    previous-command observation reports it, so that both see what the env applied."""
    return torch.maximum(torch.minimum(action, high), low)


def pid_thrust(
    error: torch.Tensor,
    integral: torch.Tensor,
    previous_error: torch.Tensor,
    kp: torch.Tensor,
    ki: torch.Tensor,
    kd: torch.Tensor,
    dt: float,
    max_thrust: float | torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Low-level PID velocity controller of Sec. 4.1: velocity error -> tau.

    The paper gives no gains; see :class:`~dockingrl.env.DockingConfig`. The output is clipped to
    ``+-max_thrust`` (Sec. 3.2.1). Anti-windup: the integral term alone never exceeds the thrust
    limit, so a long saturation does not cause a large overshoot.

    Args:
        error: ``(..., k)`` commanded minus measured velocity, one column per actuated axis.
        integral: ``(..., k)`` running integral of the error.
        previous_error: ``(..., k)`` error at the previous step (derivative term).
        kp, ki, kd: ``(k,)`` gains per axis, or ``(..., k)`` per env.
        max_thrust: the limit, a number or a ``(..., 1)`` tensor per env.

    Returns:
        ``(tau, integral)``: the clipped thrust ``(..., k)`` and the updated integral.
    """
    xp = ops(error)
    integral = integral + error * dt
    limit = max_thrust / xp.clamp_min(ki, 1e-12)
    integral = xp.maximum(xp.minimum(integral, limit), -limit)
    tau = kp * error + ki * integral + kd * (error - previous_error) / dt
    return xp.clamp(tau, -max_thrust, max_thrust), integral


def hydrodynamic_damping(
    velocity: torch.Tensor, linear: float | torch.Tensor, quadratic: float | torch.Tensor
) -> torch.Tensor:
    """Damping force of eq. 36: ``d = K_dl * v + K_qdl * |v| * v``."""
    return linear * velocity + quadratic * abs(velocity) * velocity


def velocity_update(
    velocity: torch.Tensor,
    tau: torch.Tensor,
    inertia: torch.Tensor,
    linear_damping: float | torch.Tensor,
    quadratic_damping: float | torch.Tensor,
    max_acceleration: float,
    max_velocity: float,
    dt: float,
) -> torch.Tensor:
    """Eqs. 36-37: ``acc = (tau - d) / m``; ``v = clip(v + dt * clip(acc), -max_v, max_v)``.

    Args:
        velocity: ``(..., 3)`` body velocity ``(u, v, r)`` through the water.
        tau: ``(..., 3)`` force / moment per axis (sway has no actuator: 0).
        inertia: ``(3,)`` mass (surge, sway) and yaw inertia, or ``(..., 3)`` per env.
        linear_damping, quadratic_damping: numbers, or ``(..., 1)`` tensors per env.
    """
    xp = ops(velocity)
    damping = hydrodynamic_damping(velocity, linear_damping, quadratic_damping)
    acceleration = xp.clamp((tau - damping) / inertia, -max_acceleration, max_acceleration)
    return xp.clamp(velocity + dt * acceleration, -max_velocity, max_velocity)


def pose_update(
    pose: torch.Tensor, velocity: torch.Tensor, current: torch.Tensor, dt: float
) -> torch.Tensor:
    """Eq. 38: integrate the body velocity, rotated to the DS frame, plus the ocean current.

    Args:
        pose: ``(..., 3)`` ``(x, y, alpha)``.
        velocity: ``(..., 3)`` ``(u, v, r)``.
        current: ``(..., 2)`` ocean current ``(oc_x, oc_y)`` in the DS frame.

    Returns:
        The next pose, heading wrapped to (-pi, pi].
    """
    xp = ops(pose)
    x, y, alpha = xp.unbind(pose, -1)
    u, v, r = xp.unbind(velocity, -1)
    oc_x, oc_y = xp.unbind(current, -1)
    cos, sin = xp.cos(alpha), xp.sin(alpha)
    x = x + (cos * u - sin * v + oc_x) * dt
    y = y + (sin * u + cos * v + oc_y) * dt
    alpha = wrap_angle(alpha + r * dt)
    return xp.stack((x, y, alpha), dim=-1)


def ground_velocity_body(
    alpha: torch.Tensor,
    surge: torch.Tensor,
    sway: torch.Tensor,
    current: torch.Tensor,
    dim: int = -1,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Velocity over ground in the body frame, what a bottom-locked DVL measures (eq. 2).

    ``(vx, vy) = (u, v) + R(alpha)^T oc``; ``current`` holds ``(oc_x, oc_y)`` along ``dim``.
    """
    xp = ops(alpha)
    cos, sin = xp.cos(alpha), xp.sin(alpha)
    oc_x, oc_y = xp.unbind(current, dim)
    vx = surge + oc_x * cos + oc_y * sin
    vy = sway + oc_y * cos - oc_x * sin
    return vx, vy


def observation_from_state(
    x: torch.Tensor,
    y: torch.Tensor,
    alpha: torch.Tensor,
    surge: torch.Tensor,
    sway: torch.Tensor,
    yaw_rate: torch.Tensor,
    current: torch.Tensor,
    min_range: float = 0.0,
    dim: int = -1,
) -> torch.Tensor:
    """The noise-free observation of eq. 2, which is also the EKF measurement model h (eq. 26).

    ``o = [rho, psi, alpha, vx, vy, w]``: range and bearing to the DS (USBL), heading, velocity
    over ground in the body frame (DVL) and yaw rate (IMU). Eq. 26 is this function with zero
    sway, as the EKF state has none.

    Args:
        min_range: lower bound on rho inside the bearing's ``atan2``; 0 reproduces eq. 2
            exactly, the EKF passes a small positive value so that gradients stay finite.
        current: ``(..., 2)`` ocean current, or ``(2, ...)`` when ``dim=0``.
        dim: where the six entries are stacked (-1: ``(..., 6)``; 0: ``(6, ...)``).

    Returns:
        The observation, angles wrapped to (-pi, pi].
    """
    xp = ops(x)
    rho = xp.sqrt(x * x + y * y)
    if min_range > 0:
        rho = xp.clamp_min(rho, min_range)
    psi = wrap_angle(xp.atan2(-y, -x) - alpha)
    vx, vy = ground_velocity_body(alpha, surge, sway, current, dim)
    return xp.stack((rho, psi, wrap_angle(alpha), vx, vy, yaw_rate), dim=dim)


def noisy_observation(
    observation: torch.Tensor, standard_normal: torch.Tensor, noise_std: torch.Tensor
) -> torch.Tensor:
    """Add the Gaussian sensor noise of Table 2 to an observation of eq. 2, ``(..., 6)``.

    ``noise_std`` holds the six sigmas, the first being a fraction of the true range; the
    bearing and heading are wrapped back to (-pi, pi] afterwards.
    """
    xp = ops(observation)
    rho = xp.unbind(observation, -1)[0]
    one = xp.ones_like(rho)
    scale = xp.stack((rho, one, one, one, one, one), dim=-1)
    noise = xp.multiply(xp.multiply(noise_std, scale), standard_normal)
    rho, psi, alpha, vx, vy, w = xp.unbind(xp.add(observation, noise), -1)
    return xp.stack((rho, wrap_angle(psi), wrap_angle(alpha), vx, vy, w), dim=-1)


def pose_from_observation(observation: torch.Tensor) -> torch.Tensor:
    """Invert the geometric part of eq. 2 (eq. 26): ``(rho, psi, alpha) -> (x, y, alpha)``.

    The DS is seen at bearing ``psi`` from the AUV, so the AUV is at ``-rho`` along the world
    direction ``psi + alpha``.

    Args:
        observation: ``(..., k >= 3)`` whose first three entries are ``rho, psi, alpha``.

    Returns:
        ``(..., 3)`` pose ``(x, y, alpha)``.
    """
    rho, psi, alpha = observation[..., 0], observation[..., 1], observation[..., 2]
    direction = psi + alpha
    return torch.stack((-rho * torch.cos(direction), -rho * torch.sin(direction), alpha), dim=-1)
