"""The paper's simulation step (Sec. 3.2, 4.1) written on the state's entries one by one, so
that it runs on one env's Python floats (the fast Gymnasium env) as on tensors of a batch
(:mod:`dockingrl.env.arrays`). ``tests/test_gym_fast.py`` checks it against
:class:`~dockingrl.env.DockingEnv`'s own step on tensors, bit for bit."""

from __future__ import annotations

from typing import NamedTuple

from dockingrl.env.arrays import ops
from dockingrl.env.config import DockingConfig
from dockingrl.env.dynamics import (
    noisy_observation,
    observation_from_state,
    pid_thrust,
    pose_update,
    velocity_update,
)
from dockingrl.env.reward import contact_score


class SimulatorState(NamedTuple):
    """The simulator's state entry by entry: pose ``(x, y, alpha)``, body velocity
    ``(u, v, r)``, ocean current ``(oc_x, oc_y)``, the PID's integrals and previous errors
    (surge, yaw) and the step count."""

    x: object
    y: object
    alpha: object
    u: object
    v: object
    r: object
    oc_x: object
    oc_y: object
    integral_u: object
    integral_r: object
    error_u: object
    error_r: object
    step_count: object


class StepOutput(NamedTuple):
    """What a step gives besides the next state: the observation of eq. 2 (noisy when noise
    was given), the reward of eq. 12, the episode flags and the contact's score and speed
    (0 off contact)."""

    observation: tuple
    reward: object
    terminated: object
    truncated: object
    success: object
    contact_score: object
    contact_speed: object


class Outcome(NamedTuple):
    """What a step ends with once the vehicle has moved: the observation of eq. 2 (noisy when
    noise was given), the reward of eq. 12, the contact with the station, success, and the
    contact's score and speed (0 off contact)."""

    observation: object
    reward: object
    contact: object
    success: object
    contact_score: object
    contact_speed: object


def step_outcome(
    config: DockingConfig, x, y, alpha, u, v, r, current, tau, reward, noise=None, noise_std=None
) -> Outcome:
    """The end of a step from the moved vehicle's pose ``(x, y, alpha)``, body velocity
    ``(u, v, r)`` and the current ``(..., 2)``: the observation of eq. 2 and Table 2's noise,
    the contact's score, the reward of eq. 12 (``reward(rho, tau, speed, score)``, ``tau`` the
    thrusts ``(..., 2)``) and success (Sec. 4.1), on a batch's tensors or one env's floats."""
    cfg = config
    xp = ops(x)
    observation = observation_from_state(x, y, alpha, u, v, r, current)
    rho, _, _, vx, vy, _ = xp.unbind(observation, -1)
    speed = xp.sqrt(vx * vx + vy * vy)
    contact = (
        (x >= cfg.dock_x[0]) & (x <= cfg.dock_x[1]) & (y >= cfg.dock_y[0]) & (y <= cfg.dock_y[1])
    )
    score = contact_score(x, y, alpha, cfg.aligned_weight, cfg.misaligned_weight)
    score = xp.where(contact, score, xp.zeros_like(score))
    reward = reward(rho, tau, speed, score)
    if noise is not None:
        observation = noisy_observation(observation, noise, noise_std)
    speed_limit = cfg.entry_speed_max + cfg.contact_speed_tolerance
    success = contact & (score > 0) & (speed <= speed_limit)
    contact_speed = xp.where(contact, speed, xp.zeros_like(speed))
    return Outcome(observation, reward, contact, success, score, contact_speed)


def paper_motion(
    config: DockingConfig,
    gains: tuple,
    state: SimulatorState,
    action: tuple,
    max_thrust=None,
    damping: tuple | None = None,
    thrust_limit=None,
) -> tuple[SimulatorState, tuple]:
    """The paper's vehicle moved one step: the PID of Sec. 4.1, then eqs. 36-38, on the state's
    entries (a batch's tensors or one env's floats).

    Args:
        config: the task's constants.
        gains: ``((kp_u, kp_r), (ki_u, ki_r), (kd_u, kd_r), (m_u, m_v, m_r))``, the PID gains
            and the inertia per axis.
        state: the :class:`SimulatorState` before the step.
        action: ``(v_d, w_d)``, already clipped to the bounds of eq. 3.
        max_thrust: the PID's limit (default ``config.max_thrust``).
        damping: ``(linear, quadratic)`` of eq. 36 (default the config's).
        thrust_limit: ``(tau_u, tau_r) -> (tau_u, tau_r)`` applied after the PID's clip (the
            realism options' :func:`~dockingrl.env.realism.limit_thrust`), or ``None``.

    Returns:
        ``(state, (tau_u, tau_r))``: the moved state (the step count as it was) and the thrusts.
    """
    cfg = config
    xp = ops(state.x)
    (kp_u, kp_r), (ki_u, ki_r), (kd_u, kd_r), (m_u, m_v, m_r) = gains
    max_thrust = cfg.max_thrust if max_thrust is None else max_thrust
    linear, quadratic = (cfg.linear_damping, cfg.quadratic_damping) if damping is None else damping
    v_d, w_d = action
    error_u, error_r = v_d - state.u, w_d - state.r
    tau_u, integral_u = pid_thrust(
        error_u, state.integral_u, state.error_u, kp_u, ki_u, kd_u, cfg.dt, max_thrust
    )
    tau_r, integral_r = pid_thrust(
        error_r, state.integral_r, state.error_r, kp_r, ki_r, kd_r, cfg.dt, max_thrust
    )
    if thrust_limit is not None:
        tau_u, tau_r = thrust_limit(tau_u, tau_r)
    limits = (linear, quadratic, cfg.max_acceleration, cfg.max_velocity)
    u = velocity_update(state.u, tau_u, m_u, *limits, cfg.dt)
    v = velocity_update(state.v, xp.zeros_like(tau_u), m_v, *limits, cfg.dt)
    r = velocity_update(state.r, tau_r, m_r, *limits, cfg.dt)
    current = xp.stack((state.oc_x, state.oc_y), dim=-1)
    pose = xp.stack((state.x, state.y, state.alpha), dim=-1)
    x, y, alpha = xp.unbind(pose_update(pose, xp.stack((u, v, r), dim=-1), current, cfg.dt), -1)
    moved = state._replace(
        x=x,
        y=y,
        alpha=alpha,
        u=u,
        v=v,
        r=r,
        integral_u=integral_u,
        integral_r=integral_r,
        error_u=error_u,
        error_r=error_r,
    )
    return moved, (tau_u, tau_r)


def paper_step(
    config: DockingConfig,
    gains: tuple,
    state: SimulatorState,
    action: tuple,
    reward,
    noise=None,
    noise_std=None,
) -> tuple[SimulatorState, StepOutput]:
    """One step of the paper's task: the vehicle's motion (:func:`paper_motion`), the
    observation of eq. 2, the reward of eq. 12 and the episode's end (Sec. 4.1).

    Args:
        config: the task's constants.
        gains: as :func:`paper_motion`'s.
        state: the :class:`SimulatorState` before the step.
        action: ``(v_d, w_d)``, already clipped to the bounds of eq. 3.
        reward: eq. 12 as ``reward(rho, tau, speed, score)``, ``tau`` stacked ``(surge, yaw)``:
            :meth:`DockingEnv.step_reward <dockingrl.env.DockingEnv.step_reward>`.
        noise: the step's six standard-normal draws of Table 2's sensor noise, or ``None``.
        noise_std: the six sigmas of Table 2 (with ``noise``).

    Returns:
        ``(state, output)`` after the step.
    """
    cfg = config
    xp = ops(state.x)
    moved, tau = paper_motion(cfg, gains, state, action)
    step_count = state.step_count + 1
    current = xp.stack((state.oc_x, state.oc_y), dim=-1)
    m = moved
    end = step_outcome(
        cfg,
        m.x,
        m.y,
        m.alpha,
        m.u,
        m.v,
        m.r,
        current,
        xp.stack(tau, dim=-1),
        reward,
        noise,
        noise_std,
    )
    truncated = (step_count >= cfg.max_steps) & xp.logical_not(end.contact)
    output = StepOutput(
        end.observation,
        end.reward,
        end.contact,
        truncated,
        end.success,
        end.contact_score,
        end.contact_speed,
    )
    return moved._replace(step_count=step_count), output
