"""A second vehicle: a Fossen manoeuvring model of a thruster-driven torpedo AUV of the Sparus II
class in the horizontal plane (surge, sway, yaw), ``DockingConfig(vehicle="fossen")``.

The paper's model (eqs. 36-38) treats each axis alone, with a diagonal mass and a low-level loop
that reaches any command in about a second. This one is the 3-DOF manoeuvring model of Fossen,
*Handbook of Marine Craft Hydrodynamics and Motion Control* (2nd ed., Wiley, 2021), written in
the velocity through the water ``nu_r = (u, v, r)``, which is also the env's velocity state:

    M nu_r' + C(nu_r) nu_r + D(nu_r) nu_r = tau(thrusters),    eta' = R(alpha) nu_r + V_c

with ``M = M_RB + M_A`` (rigid body with the centre of gravity ``x_g`` ahead of the origin, plus
the added mass of a prolate spheroid), ``C`` the Coriolis-centripetal terms of both (the Munk
moment included), ``D`` linear plus quadratic damping (axial drag and the cross-flow drag of the
hull's strips), and ``tau`` the surge force and yaw moment of two horizontal thrusters at
``+-y_t``. A constant, irrotational current ``V_c`` acts through the relative velocity alone
(Fossen, Ch. 10: the kinetics in ``nu_r`` are exact for it; the env's slowly varying current of
the realism options is treated as constant over a step).

Frames: the env's (z up, ``y`` to port, ``r > 0`` turning to port); the equations of Fossen's
NED frame keep their form under that reflection (``v``, ``r``, ``Y``, ``N`` change sign
together). Every function is batched over a leading dimension of torch tensors; coefficients are
numbers, or ``(n,)`` tensors per env when the realism options draw a vehicle per episode.
``docs/vehicles.md`` derives every term and tabulates the parameters; ``tests/test_fossen.py``
checks the integration against an independent RK4 and the physics.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch

from dockingrl.env.dynamics import wrap_angle
from dockingrl.env.fossen_parameters import (
    SPARUS_II,
    FossenVehicle,
    mass_matrix,
    spheroid_added_mass,
    strip_positions,
)

__all__ = [
    "FossenVehicle",
    "Hydrodynamics",
    "SPARUS_II",
    "allocate_thrust",
    "body_acceleration",
    "command_from_thrust",
    "fossen_step",
    "hydrodynamics",
    "mass_matrix",
    "spheroid_added_mass",
    "strip_positions",
    "strip_tensors",
    "thrust_from_command",
    "velocity_controller",
]


class Hydrodynamics(NamedTuple):
    """The coefficients :func:`fossen_step` uses, numbers or ``(n,)`` tensors per env
    (:func:`hydrodynamics` derives them from a :class:`FossenVehicle`). ``m11``, ``m22``,
    ``m23`` and ``m33`` the entries of ``M = M_RB + M_A``; ``inverse`` its inverse's nine
    entries, row by row; ``surge_linear``, ``surge_quadratic``, ``sway_linear``,
    ``yaw_linear`` the damping coefficients; ``crossflow`` ``rho C_d / 2``;
    ``yaw_quadratic`` the cross-flow drag's moment per ``|r| r`` at zero sway,
    ``rho C_d / 2 int D |x|^3 dx``; ``forward`` and ``reverse`` each thruster's full thrusts
    (N, ``reverse`` > 0); ``decay`` ``exp(-h / T_thruster)`` over a substep ``h``."""

    m11: object
    m22: object
    m23: object
    m33: object
    inverse: tuple
    surge_linear: object
    surge_quadratic: object
    sway_linear: object
    yaw_linear: object
    crossflow: object
    yaw_quadratic: object
    forward: object
    reverse: object
    decay: object


def strip_tensors(vehicle: FossenVehicle, device=None, dtype=torch.float32):
    """``(positions, weights)`` ``(k,)`` tensors of the cross-flow integral of
    :func:`body_acceleration`: the strips' midpoints and their ``D dx``."""
    positions = torch.tensor(strip_positions(vehicle), device=device, dtype=dtype)
    weights = torch.full_like(positions, vehicle.diameter * vehicle.length / vehicle.strips)
    return positions, weights


def hydrodynamics(
    vehicle: FossenVehicle,
    dt: float,
    scales: torch.Tensor | None = None,
    reverse_loss: float = 0.0,
) -> Hydrodynamics:
    """The coefficients of ``vehicle`` for steps of ``dt`` s, as numbers; with ``scales``
    ``(n, 5)`` (the realism options' per-episode factors on mass, damping, thrust, controller
    gains and response time), ``(n,)`` tensors: ``M`` and ``C`` scale with the mass factor,
    ``D`` with the damping factor, the thrusts with the thrust factor (reverse thrust further
    by ``1 - reverse_loss``), the thrusters' time constant with the response factor (the
    controller's gains are :func:`velocity_controller`'s)."""
    mass = mass_matrix(vehicle)
    inverse = np.linalg.inv(mass)
    frontal = math.pi * vehicle.diameter**2 / 4
    h = dt / vehicle.substeps
    nominal = {
        "m11": mass[0, 0],
        "m22": mass[1, 1],
        "m23": mass[1, 2],
        "m33": mass[2, 2],
        "surge_linear": vehicle.surge_linear_damping,
        "surge_quadratic": 0.5 * vehicle.water_density * vehicle.surge_drag_coefficient * frontal,
        "sway_linear": vehicle.sway_linear_damping,
        "yaw_linear": vehicle.yaw_linear_damping,
        "crossflow": 0.5 * vehicle.water_density * vehicle.crossflow_drag_coefficient,
        "yaw_quadratic": 0.5
        * vehicle.water_density
        * vehicle.crossflow_drag_coefficient
        * vehicle.diameter
        * float(np.sum(np.abs(strip_positions(vehicle)) ** 3))
        * (vehicle.length / vehicle.strips),
        "forward": vehicle.forward_thrust,
        "reverse": vehicle.forward_thrust * vehicle.reverse_thrust_ratio * (1 - reverse_loss),
    }
    if scales is None:
        values = {k: float(v) for k, v in nominal.items()}
        values["inverse"] = tuple(float(x) for x in inverse.ravel())
        values["decay"] = math.exp(-h / vehicle.thruster_time_constant)
        return Hydrodynamics(**values)
    mass_f, damping_f, thrust_f, _, response_f = scales.unbind(-1)
    groups = {"m11": mass_f, "m22": mass_f, "m23": mass_f, "m33": mass_f, "forward": thrust_f}
    groups.update(reverse=thrust_f, surge_linear=damping_f, surge_quadratic=damping_f)
    groups.update(sway_linear=damping_f, yaw_linear=damping_f, crossflow=damping_f)
    groups.update(yaw_quadratic=damping_f)
    values = {k: float(v) * groups[k] for k, v in nominal.items()}
    values["inverse"] = tuple(float(x) / mass_f for x in inverse.ravel())
    values["decay"] = torch.exp(-h / (vehicle.thruster_time_constant * response_f))
    return Hydrodynamics(**values)


def per_thruster(value):
    """A coefficient (a number, or ``(n,)`` per env) shaped to multiply ``(n, 2)`` thrusts."""
    return value.unsqueeze(-1) if isinstance(value, torch.Tensor) else value


def thrust_from_command(command: torch.Tensor, forward, reverse) -> torch.Tensor:
    """A thruster's steady thrust (N) at its command in [-1, 1], the propeller's quadratic
    thrust curve (Fossen 2021, Ch. 9: ``T = rho D^4 K_T |n| n``) scaled to its full
    ``forward`` thrust ahead and its weaker ``reverse`` thrust astern."""
    squared = command.abs() * command
    return torch.where(command >= 0, forward * squared, reverse * squared)


def command_from_thrust(thrust: torch.Tensor, forward, reverse) -> torch.Tensor:
    """The command in [-1, 1] whose steady thrust is ``thrust`` (clipped to what the thruster
    gives): the inverse of :func:`thrust_from_command`."""
    ahead = torch.sqrt((thrust / forward).clamp(0.0, 1.0))
    astern = -torch.sqrt((-thrust / reverse).clamp(0.0, 1.0))
    return torch.where(thrust >= 0, ahead, astern)


def allocate_thrust(surge_force, yaw_moment, thruster_y: float, forward, reverse):
    """Thrust allocation of two horizontal thrusters at ``+-thruster_y`` (port, starboard):
    ``X = T_p + T_s``, ``N = y_t (T_s - T_p)``, saturated with the yaw moment first (a
    torpedo AUV that cannot turn cannot dock): the differential thrust is clipped to what the
    thrusters give, then the common thrust to what is left.

    Returns:
        ``(thrust, surge_force, yaw_moment)``: ``(n, 2)`` the thrusters' thrust targets
        (port, starboard) and the force and moment they give.
    """
    span = (forward + reverse) / 2
    half_moment = torch.clamp(yaw_moment / (2 * thruster_y), -span, span)
    common = surge_force / 2
    low, high = -reverse + half_moment.abs(), forward - half_moment.abs()
    common = torch.maximum(torch.minimum(common, high), low)
    port, starboard = common - half_moment, common + half_moment
    return torch.stack((port, starboard), -1), 2 * common, 2 * thruster_y * half_moment


def velocity_controller(
    action: torch.Tensor,
    velocity: torch.Tensor,
    integral: torch.Tensor,
    vehicle: FossenVehicle,
    nominal: Hydrodynamics,
    hydro: Hydrodynamics,
    h: float,
    gain_scale=1.0,
):
    """The low-level velocity controller that turns ``(v_d, w_d)`` into thruster targets, run
    at the substep ``h``: a feedforward of the (nominal) model's steady damping at the set
    point plus a PI on the surge and yaw-rate errors, allocated to the thrusters
    (:func:`allocate_thrust`), then quantised by the thrusters' commands
    (:func:`command_from_thrust`, :func:`thrust_from_command`). Anti-windup by conditional
    integration: an axis's integral holds while its demand saturates and its error would push
    it further. ``gain_scale`` ``(n,)`` or a number multiplies both PI's gains.

    Returns:
        ``(targets, integral, error, tau)``: the thrusters' targets ``(n, 2)``, the integrals
        and errors ``(n, 2)`` (surge, yaw) and the allocated ``(X, N)`` ``(n, 2)``.
    """
    v_d, w_d = action.unbind(-1)
    u, r = velocity[:, 0], velocity[:, 2]
    error = torch.stack((v_d - u, w_d - r), -1)
    e_u, e_r = error.unbind(-1)
    i_u, i_r = integral.unbind(-1)
    ff_x = nominal.surge_linear * v_d + nominal.surge_quadratic * v_d.abs() * v_d
    ff_n = nominal.yaw_linear * w_d + nominal.yaw_quadratic * w_d.abs() * w_d
    kp_u, ki_u = vehicle.surge_kp * gain_scale, vehicle.surge_ki * gain_scale
    kp_r, ki_r = vehicle.yaw_kp * gain_scale, vehicle.yaw_ki * gain_scale
    want_x = ff_x + kp_u * e_u + ki_u * i_u
    want_n = ff_n + kp_r * e_r + ki_r * i_r
    targets, got_x, got_n = allocate_thrust(
        want_x, want_n, vehicle.thruster_y, hydro.forward, hydro.reverse
    )
    forward, reverse = per_thruster(hydro.forward), per_thruster(hydro.reverse)
    targets = thrust_from_command(command_from_thrust(targets, forward, reverse), forward, reverse)
    hold_u = ((want_x - got_x) * e_u) > 0
    hold_r = ((want_n - got_n) * e_r) > 0
    i_u = torch.where(hold_u, i_u, i_u + h * e_u)
    i_r = torch.where(hold_r, i_r, i_r + h * e_r)
    tau = torch.stack((got_x, got_n), -1)
    return targets, torch.stack((i_u, i_r), -1), error, tau


def body_acceleration(velocity: torch.Tensor, force: torch.Tensor, hydro: Hydrodynamics, strips):
    """``nu_r' = M^-1 (tau - C(nu_r) nu_r - D(nu_r) nu_r)`` (Fossen 2021, Ch. 6-8) for the
    velocity through the water ``(n, 3)`` under the thrusters' ``(X, N)`` ``force`` ``(n, 2)``:
    ``C nu = (-(m22 v + m23 r) r, m11 u r, (m22 v + m23 r) u - m11 u v)``, whose last entry
    holds the Munk moment ``(X_udot - Y_vdot) u v``; ``D nu`` the linear terms, the axial drag
    ``X_|u|u |u| u`` and the cross-flow drag of the hull's strips, ``Y = rho C_d / 2 int D
    |v + x r| (v + x r) dx`` and ``N = rho C_d / 2 int x D |v + x r| (v + x r) dx`` (Fossen,
    Ch. 6, the cross-flow drag principle). ``strips``: ``(positions, weights)`` tensors
    ``(k,)`` of the integral, the weights holding ``D dx``."""
    u, v, r = velocity.unbind(-1)
    x_force, n_moment = force.unbind(-1)
    positions, weights = strips
    local = v.unsqueeze(-1) + r.unsqueeze(-1) * positions
    drag = local.abs() * local
    cross_y = hydro.crossflow * (drag @ weights)
    cross_n = hydro.crossflow * (drag @ (weights * positions))
    sway_momentum = hydro.m22 * v + hydro.m23 * r
    rhs_x = x_force + sway_momentum * r - (hydro.surge_linear + hydro.surge_quadratic * u.abs()) * u
    rhs_y = -hydro.m11 * u * r - hydro.sway_linear * v - cross_y
    rhs_n = n_moment - (sway_momentum - hydro.m11 * v) * u - hydro.yaw_linear * r - cross_n
    a = hydro.inverse
    return torch.stack(
        (
            a[0] * rhs_x + a[1] * rhs_y + a[2] * rhs_n,
            a[3] * rhs_x + a[4] * rhs_y + a[5] * rhs_n,
            a[6] * rhs_x + a[7] * rhs_y + a[8] * rhs_n,
        ),
        -1,
    )


def thruster_force(thrust: torch.Tensor, thruster_y: float) -> torch.Tensor:
    """``(X, N)`` ``(n, 2)`` of the thrusters' thrusts ``(n, 2)`` (port, starboard)."""
    port, starboard = thrust.unbind(-1)
    return torch.stack((port + starboard, thruster_y * (starboard - port)), -1)


def fossen_step(
    pose: torch.Tensor,
    velocity: torch.Tensor,
    thrust: torch.Tensor,
    integral: torch.Tensor,
    action: torch.Tensor,
    current: torch.Tensor,
    vehicle: FossenVehicle,
    nominal: Hydrodynamics,
    hydro: Hydrodynamics,
    strips,
    dt: float,
    gain_scale=1.0,
):
    """One env step of ``dt`` s of the Fossen vehicle under the set points ``action``
    ``(n, 2)``: ``vehicle.substeps`` times, the controller (:func:`velocity_controller`, held
    over the substep), the thrusters' exact first-order response to its targets, Heun's method
    on :func:`body_acceleration` (the thrust at both ends of the substep) and the pose of
    ``eta' = R(alpha) nu_r + V_c`` at the substep's mean velocity and heading.

    Returns:
        ``(pose, velocity, thrust, integral, error, tau)``: the state after the step, the last
        substep's errors ``(n, 2)`` and the allocated ``(X, N)`` ``(n, 2)`` (the reward's
        ``tau``, eq. 5).
    """
    h = dt / vehicle.substeps
    oc_x, oc_y = current.unbind(-1)
    decay = per_thruster(hydro.decay)
    for _ in range(vehicle.substeps):
        targets, integral, error, tau = velocity_controller(
            action, velocity, integral, vehicle, nominal, hydro, h, gain_scale
        )
        after = targets + (thrust - targets) * decay
        y_t = vehicle.thruster_y
        start = body_acceleration(velocity, thruster_force(thrust, y_t), hydro, strips)
        guess = velocity + h * start
        end = body_acceleration(guess, thruster_force(after, y_t), hydro, strips)
        moved = velocity + (0.5 * h) * (start + end)
        mean = 0.5 * (velocity + moved)
        x, y, alpha = pose.unbind(-1)
        u, v, r = mean.unbind(-1)
        heading = alpha + (0.5 * h) * r
        cos, sin = torch.cos(heading), torch.sin(heading)
        x = x + h * (cos * u - sin * v + oc_x)
        y = y + h * (sin * u + cos * v + oc_y)
        alpha = wrap_angle(alpha + h * r)
        pose = torch.stack((x, y, alpha), -1)
        velocity, thrust = moved, after
    return pose, velocity, thrust, integral, error, tau
