"""The EKF's model (Sec. 3.5, eqs. 22-27, 30-31), its noise of Tables 1-2 and its start.

State ``mean = [x, y, alpha, nu, w]`` (eq. 22): AUV position and heading in the DS frame, surge
through the water and yaw rate. Control ``[v_d, w_d]`` (eq. 23), the action applied over the
step. The ocean current is known (the paper's assumption). Measurement: the 6-vector of eq. 2.

The functions take any leading batch shape ``(...)`` (matrices in the last two dimensions),
work in float32 and float64 and are differentiable. Those with a ``dim`` (or ``batch_last``)
argument also take the batch-last layout of :mod:`dockingrl.transforms.ekf_layout`
(``dim=0``), on tensors or on one env's Python floats, which is how the filter of
:mod:`dockingrl.transforms.ekf` calls them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from dockingrl.env.arrays import ops
from dockingrl.env.dynamics import observation_from_state, pose_from_observation, wrap_angle
from dockingrl.transforms.ekf_layout import stack_matrix, symmetric

STATE_DIM = 5
MEASUREMENT_DIM = 6
#: Table 1: process-noise sigmas of x (m), y (m), alpha (rad), nu (m/s), w (rad/s).
PROCESS_NOISE_STD = (0.02, 0.02, 0.05, 0.01, 0.01)
#: Table 2: measurement sigmas; the first (range) is a fraction of the measured range.
MEASUREMENT_NOISE_STD = (0.025, math.radians(1.5), math.radians(3.0), 0.02, 0.02, math.radians(0.2))
#: Smallest range used in the measurement model, its Jacobian and R: the bearing is undefined at
#: the DS itself, so ``rho`` is floored there (the "rho -> 0 guard").
MIN_RANGE = 1e-2


def wrap_heading(mean: torch.Tensor, dim: int) -> torch.Tensor:
    """The state ``mean`` (eq. 22, along ``dim``) with its heading wrapped to (-pi, pi]."""
    xp = ops(mean)
    x, y, alpha, nu, w = xp.unbind(mean, dim)
    return xp.stack((x, y, wrap_angle(alpha), nu, w), dim=dim)


# --- the motion model: eqs. 24-25 ---------------------------------------------------------------
def motion_model(
    mean: torch.Tensor,
    action: torch.Tensor,
    current: torch.Tensor,
    dt: float,
    k_v: float = 2.5,
    k_w: float = 2.5,
    *,
    dim: int = -1,
) -> torch.Tensor:
    """State transition ``f(x, u)`` of eq. 24 (eq. 28); the heading is wrapped to (-pi, pi].
    ``dim``: the dimension of the state's entries (0: batch-last)."""
    xp = ops(mean)
    x, y, alpha, nu, w = xp.unbind(mean, dim)
    v_d, w_d = xp.unbind(action, dim)
    oc_x, oc_y = xp.unbind(current, dim)
    return xp.stack(
        (
            x + (xp.cos(alpha) * nu + oc_x) * dt,
            y + (xp.sin(alpha) * nu + oc_y) * dt,
            wrap_angle(alpha + w * dt),
            nu + k_v * (v_d - nu) * dt,
            w + k_w * (w_d - w) * dt,
        ),
        dim=dim,
    )


def motion_jacobian_entries(alpha, nu, dt, k_v, k_w):
    """The entries of eq. 25 that are not 0 or 1: ``A[0, 2], A[0, 3], A[1, 2], A[1, 3]``
    (tensors), ``A[2, 4], A[3, 3], A[4, 4]`` (numbers)."""
    xp = ops(alpha)
    cos, sin = xp.cos(alpha), xp.sin(alpha)
    return (-sin * nu * dt, cos * dt, cos * nu * dt, sin * dt), (dt, 1 - k_v * dt, 1 - k_w * dt)


def motion_jacobian(
    mean: torch.Tensor, dt: float, k_v: float = 2.5, k_w: float = 2.5
) -> torch.Tensor:
    """Jacobian ``A = df/dx`` of eq. 25, ``(..., 5, 5)``."""
    (a02, a03, a12, a13), (a24, a33, a44) = motion_jacobian_entries(
        mean[..., 2], mean[..., 3], dt, k_v, k_w
    )
    zero, one = torch.zeros_like(a02), torch.ones_like(a02)
    rows = (
        (one, zero, a02, a03, zero),
        (zero, one, a12, a13, zero),
        (zero, zero, one, zero, a24 * one),
        (zero, zero, zero, a33 * one, zero),
        (zero, zero, zero, zero, a44 * one),
    )
    return stack_matrix(rows, batch_last=False)


# --- the measurement model: eqs. 26-27, 30-31 ---------------------------------------------------
def measurement_function(
    mean: torch.Tensor, current: torch.Tensor, *, dim: int = -1
) -> torch.Tensor:
    """Measurement model ``h(x)`` of eq. 26, ``(..., 6)``: the observation of eq. 2 of the
    estimated state (the EKF state has no sway). The range is floored at :data:`MIN_RANGE`.
    ``dim``: the dimension of the entries (0: batch-last)."""
    xp = ops(mean)
    x, y, alpha, nu, w = xp.unbind(mean, dim)
    return observation_from_state(x, y, alpha, nu, xp.zeros_like(nu), w, current, MIN_RANGE, dim)


def measurement_jacobian(
    mean: torch.Tensor, current: torch.Tensor, *, batch_last: bool = False
) -> torch.Tensor:
    """Jacobian ``H = dh/dx`` of eq. 27, ``(..., 6, 5)`` (batch-last: ``(6, 5, N)``); ``rho``
    floored at :data:`MIN_RANGE`."""
    d = 0 if batch_last else -1
    xp = ops(mean)
    x, y, alpha = xp.unbind(mean, d)[:3]
    oc_x, oc_y = xp.unbind(current, d)
    rho2 = xp.clamp_min(x * x + y * y, MIN_RANGE**2)
    rho = xp.sqrt(rho2)
    cos, sin = xp.cos(alpha), xp.sin(alpha)
    zero, one = xp.zeros_like(x), xp.ones_like(x)
    rows = (
        (x / rho, y / rho, zero, zero, zero),
        (-y / rho2, x / rho2, -one, zero, zero),
        (zero, zero, one, zero, zero),
        (zero, zero, -oc_x * sin + oc_y * cos, one, zero),
        (zero, zero, -oc_y * sin - oc_x * cos, zero, zero),
        (zero, zero, zero, zero, one),
    )
    return stack_matrix(rows, batch_last)


def innovation(
    mean: torch.Tensor,
    z: torch.Tensor,
    current: torch.Tensor,
    *,
    dim: int = -1,
    usbl_prediction: torch.Tensor | None = None,
) -> torch.Tensor:
    """Eq. 30: ``y = z - h(x)``, with the bearing and heading residuals wrapped. ``dim``: the
    dimension of the entries (0: batch-last).

    ``usbl_prediction`` (not in the paper): the range and bearing ``h(x_s)`` the filter
    predicted for the instant ``s`` that a late USBL fix in ``z`` describes; the fix's
    residuals are then taken against it. This is the measurement extrapolation of a fix
    delayed by a known latency (Larsen et al. 1998): fusing ``z + h(x) - h(x_s)`` against
    ``h(x)``, the late fix shifted by the change the filter's own estimate predicts over the
    delay."""
    xp = ops(mean)
    predicted = measurement_function(mean, current, dim=dim)
    if usbl_prediction is not None:
        predicted = torch.cat((usbl_prediction, predicted.narrow(dim, 2, 4)), dim=dim)
    y = xp.sub(z, predicted)
    rho, psi, alpha, vx, vy, w = xp.unbind(y, dim)
    return xp.stack((rho, wrap_angle(psi), wrap_angle(alpha), vx, vy, w), dim=dim)


def innovation_covariance(cov: torch.Tensor, H: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """Eq. 31: ``S = H P H^T + R``, ``(..., 6, 6)``."""
    return symmetric(H @ cov @ H.transpose(-1, -2) + R)


# --- noise covariances: Tables 1-2 --------------------------------------------------------------
def measurement_noise_std(
    measured_range: torch.Tensor, noise_std: torch.Tensor | Sequence[float] | None = None
) -> torch.Tensor:
    """Table 2 sigmas per measurement, ``(..., 6)``: the range sigma is ``noise_std[0] * rho``
    with the *measured* ``rho`` (floored at :data:`MIN_RANGE`), the others are constant. For
    one env's float ``measured_range``, a tuple of 6 floats."""
    if noise_std is None:
        noise_std = MEASUREMENT_NOISE_STD
    if not isinstance(measured_range, torch.Tensor):  # one env's float: a tuple of 6
        return (noise_std[0] * max(measured_range, MIN_RANGE), *noise_std[1:])
    noise_std = torch.as_tensor(noise_std, dtype=measured_range.dtype, device=measured_range.device)
    rho = measured_range.clamp_min(MIN_RANGE).unsqueeze(-1)
    return torch.cat((noise_std[..., :1] * rho, noise_std[..., 1:].expand(*rho.shape[:-1], 5)), -1)


def measurement_covariance(
    measured_range: torch.Tensor, noise_std: torch.Tensor | Sequence[float] | None = None
) -> torch.Tensor:
    """``R = diag(sigma^2)`` of Table 2 (see :func:`measurement_noise_std`), ``(..., 6, 6)``."""
    return torch.diag_embed(measurement_noise_std(measured_range, noise_std) ** 2)


def process_covariance(
    noise_std: torch.Tensor | Sequence[float] | None = None,
    *,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """``Q = diag(sigma^2)`` of Table 1, ``(5, 5)``."""
    if noise_std is None:
        noise_std = PROCESS_NOISE_STD
    return torch.diag_embed(torch.as_tensor(noise_std, dtype=dtype, device=device) ** 2)


# --- initialisation ----------------------------------------------------------------------------
def state_from_observation(observation: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
    """Invert eq. 26: the state ``[x, y, alpha, nu, w]`` that explains a measurement exactly."""
    pose = pose_from_observation(observation)
    alpha = pose[..., 2]
    along_current = current[..., 0] * torch.cos(alpha) + current[..., 1] * torch.sin(alpha)
    nu = observation[..., 3] - along_current
    return torch.cat((pose, nu.unsqueeze(-1), observation[..., 5:6]), dim=-1)


def initial_covariance(
    observation: torch.Tensor, current: torch.Tensor, R: torch.Tensor
) -> torch.Tensor:
    """``P0 = J R J^T``: the measurement covariance carried through the inverse of eq. 26
    (``J`` = d state / d measurement at ``observation``), so that the first estimate is exactly
    as uncertain as the measurement that made it. ``R`` is ``(..., 6, 6)``; returns
    ``(..., 5, 5)``."""
    rho, psi, alpha = observation[..., 0], observation[..., 1], observation[..., 2]
    direction = psi + alpha
    cos_d, sin_d = torch.cos(direction), torch.sin(direction)
    cos_a, sin_a = torch.cos(alpha), torch.sin(alpha)
    zero, one = torch.zeros_like(rho), torch.ones_like(rho)
    d_nu_d_alpha = current[..., 0] * sin_a - current[..., 1] * cos_a
    rows = (
        (-cos_d, rho * sin_d, rho * sin_d, zero, zero, zero),
        (-sin_d, -rho * cos_d, -rho * cos_d, zero, zero, zero),
        (zero, zero, one, zero, zero, zero),
        (zero, zero, d_nu_d_alpha, one, zero, zero),
        (zero, zero, zero, zero, zero, one),
    )
    J = stack_matrix(rows, batch_last=False)
    return symmetric(J @ R @ J.transpose(-1, -2))
