"""The simulation step of :class:`~dockingrl.env.DockingEnv` as pure tensor functions of the
batched state: the paper vehicle's motion (the PID of Sec. 4.1, or the episode's vehicle of the
realism options, and eqs. 36-38), then, for either vehicle, the observation of eq. 2 and Table
2's noise, the reward of eq. 12 and the episode's end."""

from __future__ import annotations

import torch

from dockingrl.env.config import DockingConfig
from dockingrl.env.dynamics import pid_thrust, pose_update, velocity_update
from dockingrl.env.realism import limit_thrust
from dockingrl.env.transition import step_outcome


def paper_motion(
    config: DockingConfig, gains, pose, velocity, current, integral, previous_error, action, vehicle
):
    """The paper's vehicle moved one step: the PID (Sec. 4.1, or the episode's vehicle of the
    realism options), eqs. 36-38. ``gains`` ``(kp, ki, kd, inertia)`` the nominal vehicle's,
    used unless ``vehicle`` (:func:`~dockingrl.env.realism.vehicle_parameters`) is given.

    Returns:
        ``(pose, velocity, integral, error, tau)``, ``tau`` the PID's ``(surge, yaw)`` thrust.
    """
    cfg = config
    kp, ki, kd, inertia = gains
    error = action - velocity[:, 0::2]
    if vehicle is None:
        tau, integral = pid_thrust(
            error, integral, previous_error, kp, ki, kd, cfg.dt, cfg.max_thrust
        )
        masses, damping = inertia, (cfg.linear_damping, cfg.quadratic_damping)
    else:
        thrust = vehicle["max_thrust"]
        tau, integral = pid_thrust(
            error,
            integral,
            previous_error,
            vehicle["kp"],
            vehicle["ki"],
            vehicle["kd"],
            cfg.dt,
            thrust,
        )
        tau = limit_thrust(tau, thrust, cfg.reverse_thrust_loss, cfg.turning_surge_loss)
        masses, damping = vehicle["inertia"], (vehicle["linear"], vehicle["quadratic"])
    tau3 = torch.stack((tau[:, 0], torch.zeros_like(tau[:, 0]), tau[:, 1]), dim=-1)
    velocity = velocity_update(
        velocity,
        tau3,
        masses,
        *damping,
        cfg.max_acceleration,
        cfg.max_velocity,
        cfg.dt,
    )
    pose = pose_update(pose, velocity, current, cfg.dt)
    return pose, velocity, integral, error, tau


def step_entries(
    config: DockingConfig, pose, velocity, current, step_count, tau, step_reward, noise, noise_std
):
    """The end of a step of either vehicle from its moved state: the step count, the observation
    of eq. 2 and Table 2's noise (with ``noise``), the reward of eq. 12 and the episode's end
    (:func:`~dockingrl.env.transition.step_outcome`).

    Returns:
        ``(step_count, out)``, ``out`` the step's entries (``observation``, ``true_state``,
        ``reward``, the done flags, ``success``, ``contact_score``, ``contact_speed``).
    """
    cfg = config
    step_count = step_count + 1
    x, y, alpha = pose.unbind(-1)
    u, v, r = velocity.unbind(-1)
    end = step_outcome(cfg, x, y, alpha, u, v, r, current, tau, step_reward, noise, noise_std)
    terminated = end.contact.unsqueeze(-1)
    truncated = (step_count >= cfg.max_steps) & ~terminated
    out = {
        "observation": end.observation,
        "true_state": torch.cat((pose, velocity), dim=-1),
        "reward": end.reward.unsqueeze(-1),
        "done": terminated | truncated,
        "terminated": terminated,
        "truncated": truncated,
        "success": end.success.unsqueeze(-1),
        "contact_score": end.contact_score.unsqueeze(-1),
        "contact_speed": end.contact_speed.unsqueeze(-1),
    }
    return step_count, out


def make_transition(
    config: DockingConfig,
    kp: torch.Tensor,
    ki: torch.Tensor,
    kd: torch.Tensor,
    inertia: torch.Tensor,
    noise_std: torch.Tensor,
    step_reward,
):
    """The step ``transition(pose, velocity, current, integral, previous_error, step_count,
    action, noise, vehicle=None) -> (pose, velocity, integral, error, step_count, out)`` of the
    paper's vehicle, what ``compile_step`` hands to ``torch.compile``: ``kp``, ``ki``, ``kd``
    ``(2,)`` (surge, yaw) and ``inertia`` ``(3,)`` the nominal vehicle's, unless ``vehicle``
    (the episode's, of :func:`~dockingrl.env.realism.vehicle_parameters`) is given; ``noise``
    the step's standard-normal draws of Table 2 (sigmas ``noise_std``) or ``None``;
    ``step_reward`` eq. 12 (:meth:`DockingEnv.step_reward
    <dockingrl.env.DockingEnv.step_reward>`); ``out`` the entries of :func:`step_entries`."""
    cfg = config
    gains = (kp, ki, kd, inertia)

    def transition(
        pose,
        velocity,
        current,
        integral,
        previous_error,
        step_count,
        action,
        noise,
        vehicle=None,
    ):
        pose, velocity, integral, error, tau = paper_motion(
            cfg, gains, pose, velocity, current, integral, previous_error, action, vehicle
        )
        step_count, out = step_entries(
            cfg, pose, velocity, current, step_count, tau, step_reward, noise, noise_std
        )
        return pose, velocity, integral, error, step_count, out

    return transition
