"""The simulation step of :class:`~dockingrl.env.DockingEnv` as pure tensor functions of the
batched state: the paper vehicle's motion (the PID of Sec. 4.1, or the episode's vehicle of the
realism options, and eqs. 36-38) or the Fossen vehicle's (:func:`~dockingrl.env.fossen.fossen_step`;
with ``vehicle="mixed"`` each env its episode's), then, for either vehicle, the observation of
eq. 2 (with Table 2's noise on the paper's task; the realistic step draws its own), the reward of
eq. 12 and the episode's end."""

from __future__ import annotations

import torch

from dockingrl.env.config import DockingConfig
from dockingrl.env.fossen import SPARUS_II, fossen_step
from dockingrl.env.realism import limit_thrust
from dockingrl.env.transition import SimulatorState, paper_motion, step_outcome


def batch_motion(
    config: DockingConfig, gains, pose, velocity, current, integral, previous_error, action, vehicle
):
    """The paper's vehicle of a batch moved one step (:func:`~dockingrl.env.transition.paper_motion`
    on the batch's columns): ``gains`` ``(kp, ki, kd, inertia)`` the nominal vehicle's, used
    unless ``vehicle`` (:func:`~dockingrl.env.realism.vehicle_parameters`) is given, whose
    thrust the realism options limit further (:func:`~dockingrl.env.realism.limit_thrust`).

    Returns:
        ``(pose, velocity, integral, error, tau)``, ``tau`` the PID's ``(surge, yaw)`` thrust.
    """
    cfg = config
    state = SimulatorState(
        *pose.unbind(-1),
        *velocity.unbind(-1),
        *current.unbind(-1),
        *integral.unbind(-1),
        *previous_error.unbind(-1),
        None,
    )
    if vehicle is None:
        kp, ki, kd, inertia = gains
        thrust = damping = thrust_limit = None
    else:
        kp, ki, kd, inertia = (vehicle[k] for k in ("kp", "ki", "kd", "inertia"))
        limit = vehicle["max_thrust"]
        thrust = limit.squeeze(-1)
        damping = (vehicle["linear"].squeeze(-1), vehicle["quadratic"].squeeze(-1))

        def thrust_limit(tau_u, tau_r):
            tau = torch.stack((tau_u, tau_r), dim=-1)
            return limit_thrust(tau, limit, cfg.reverse_thrust_loss, cfg.turning_surge_loss).unbind(
                -1
            )

    columns = tuple(tuple(g.unbind(-1)) for g in (kp, ki, kd, inertia))
    moved, tau = paper_motion(
        cfg, columns, state, tuple(action.unbind(-1)), thrust, damping, thrust_limit
    )
    m = moved
    return (
        torch.stack((m.x, m.y, m.alpha), dim=-1),
        torch.stack((m.u, m.v, m.r), dim=-1),
        torch.stack((m.integral_u, m.integral_r), dim=-1),
        torch.stack((m.error_u, m.error_r), dim=-1),
        torch.stack(tau, dim=-1),
    )


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
        pose, velocity, integral, error, tau = batch_motion(
            cfg, gains, pose, velocity, current, integral, previous_error, action, vehicle
        )
        step_count, out = step_entries(
            cfg, pose, velocity, current, step_count, tau, step_reward, noise, noise_std
        )
        return pose, velocity, integral, error, step_count, out

    return transition


def make_fossen_transition(
    config: DockingConfig,
    kp: torch.Tensor,
    ki: torch.Tensor,
    kd: torch.Tensor,
    inertia: torch.Tensor,
    strips,
    step_reward,
):
    """The step ``transition(pose, velocity, thrust, current, integral, previous_error,
    step_count, action, nominal, hydro, gain, on_fossen, vehicle) -> (pose, velocity, thrust,
    integral, error, step_count, out)`` of the Fossen vehicle (``config.vehicle="fossen"``) or of
    each env's episode vehicle (``"mixed"``), what ``compile_step`` hands to ``torch.compile``
    for them: :func:`~dockingrl.env.fossen.fossen_step` of :data:`~dockingrl.env.fossen.SPARUS_II`
    with its controller's nominal coefficients ``nominal``, the episode's ``hydro`` and PI
    ``gain`` and the cross-flow ``strips``; with ``on_fossen`` ``(n, 1)`` (``"mixed"``), the
    paper's vehicle (:func:`batch_motion` with ``kp``, ``ki``, ``kd``, ``inertia`` and the
    episode's ``vehicle`` or ``None``) in the other rows, whose thrusters' state stays as it was;
    no noise (the realistic step draws its own); ``out`` the entries of :func:`step_entries`."""
    cfg = config
    gains = (kp, ki, kd, inertia)

    def transition(
        pose,
        velocity,
        thrust,
        current,
        integral,
        previous_error,
        step_count,
        action,
        nominal,
        hydro,
        gain,
        on_fossen,
        vehicle,
    ):
        moved = fossen_step(
            pose,
            velocity,
            thrust,
            integral,
            action,
            current,
            SPARUS_II,
            nominal,
            hydro,
            strips,
            cfg.dt,
            gain,
        )
        new_pose, new_velocity, new_thrust, new_integral, error, tau = moved
        if on_fossen is not None:
            paper = batch_motion(
                cfg, gains, pose, velocity, current, integral, previous_error, action, vehicle
            )
            fossen = (new_pose, new_velocity, new_integral, error, tau)
            new_pose, new_velocity, new_integral, error, tau = (
                torch.where(on_fossen, f, p) for f, p in zip(fossen, paper, strict=True)
            )
            new_thrust = torch.where(on_fossen, new_thrust, thrust)
        step_count, out = step_entries(
            cfg, new_pose, new_velocity, current, step_count, tau, step_reward, None, None
        )
        return new_pose, new_velocity, new_thrust, new_integral, error, step_count, out

    return transition
