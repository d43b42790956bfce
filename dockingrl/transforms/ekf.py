"""The docking task's Extended Kalman Filter (Sec. 3.5, eqs. 22-34) as pure batched functions.

State ``mean = [x, y, alpha, nu, w]`` (eq. 22): AUV position and heading in the DS frame, surge
through the water and yaw rate. Control ``[v_d, w_d]`` (eq. 23), the action applied over the
step. The ocean current is known (the paper's assumption). Measurement: the 6-vector of eq. 2.

The public functions take any leading batch shape ``(...)`` (matrices in the last two
dimensions), work in float32 and float64 and are differentiable, with respect to the noise
covariances too, which is what lets :class:`~dockingrl.transforms.EKFTransform` learn them.

Implementation note: thousands of 5 x 5 filters are small matrices, for which batched matrix
kernels and broadcasting over a size-5 innermost dimension are slow on a CPU. Internally the
filter therefore runs "batch-last" (``mean`` as ``(5, N)``, ``cov`` as ``(5, 5, N)``), where every
matrix entry is a contiguous vector over the envs, and converts at the boundary. Written with
the operations of :mod:`dockingrl.env.arrays`, the same batch-last functions also run on one
env's Python floats (``mean`` a tuple of 5, ``cov`` a tuple of 5 rows): :func:`filter_entries`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from dockingrl.env.arrays import ops
from dockingrl.env.dynamics import observation_from_state, pose_from_observation, wrap_angle
from dockingrl.env.realism import SENSOR_OF_ENTRY, SENSORS

STATE_DIM = 5
MEASUREMENT_DIM = 6
#: Table 1: process-noise sigmas of x (m), y (m), alpha (rad), nu (m/s), w (rad/s).
PROCESS_NOISE_STD = (0.02, 0.02, 0.05, 0.01, 0.01)
#: Table 2: measurement sigmas; the first (range) is a fraction of the measured range.
MEASUREMENT_NOISE_STD = (0.025, math.radians(1.5), math.radians(3.0), 0.02, 0.02, math.radians(0.2))
#: Smallest range used in the measurement model, its Jacobian and R: the bearing is undefined at
#: the DS itself, so ``rho`` is floored there (the "rho -> 0 guard").
MIN_RANGE = 1e-2
#: the measurement entries of each sensor, in :data:`~dockingrl.env.realism.SENSORS`' order
#: (USBL: range and bearing; DVL: the two ground velocities; IMU: heading and yaw rate)
SENSOR_ENTRIES = tuple(
    tuple(i for i, s in enumerate(SENSOR_OF_ENTRY) if s == sensor) for sensor in range(len(SENSORS))
)
#: chi-square quantiles with 2 degrees of freedom (each sensor gives two numbers): a gate at
#: 13.8 rejects 0.1 % of the readings that follow the model, at 9.21 1 %
CHI2_2DOF_999 = 13.816


# --- layout helpers ----------------------------------------------------------------------------
def _stack_matrix(rows: Sequence[Sequence[torch.Tensor]], batch_last: bool) -> torch.Tensor:
    if batch_last:
        xp = ops(rows[0][0])
        return xp.stack([xp.stack(row, dim=0) for row in rows], dim=0)
    return torch.stack([torch.stack(list(row), dim=-1) for row in rows], dim=-2)


def _vector_to_last(v: torch.Tensor) -> torch.Tensor:
    """``(..., k)`` -> ``(k, N)``, contiguous."""
    return v.reshape(-1, v.shape[-1]).T.contiguous()


def _matrix_to_last(m: torch.Tensor, batch_shape: torch.Size) -> torch.Tensor:
    """``(..., r, c)`` (broadcastable to ``batch_shape``) -> ``(r, c, N)`` or ``(r, c, 1)``."""
    if m.dim() == 2:
        return m.unsqueeze(-1)
    m = m.expand(*batch_shape, *m.shape[-2:])
    return m.reshape(-1, *m.shape[-2:]).permute(1, 2, 0).contiguous()


def _vector_from_last(v: torch.Tensor, batch_shape: torch.Size) -> torch.Tensor:
    return v.T.contiguous().reshape(*batch_shape, v.shape[0])


def _matrix_from_last(m: torch.Tensor, batch_shape: torch.Size) -> torch.Tensor:
    return m.permute(2, 0, 1).contiguous().reshape(*batch_shape, *m.shape[:2])


def _symmetric(matrix: torch.Tensor, batch_last: bool = False) -> torch.Tensor:
    if batch_last:
        return ops(matrix).symmetric(matrix)
    return 0.5 * (matrix + matrix.transpose(-1, -2))


def _wrap_heading(mean: torch.Tensor, dim: int) -> torch.Tensor:
    xp = ops(mean)
    x, y, alpha, nu, w = xp.unbind(mean, dim)
    return xp.stack((x, y, wrap_angle(alpha), nu, w), dim=dim)


# --- the model: eqs. 24-27 ---------------------------------------------------------------------
def _motion_model(state, action, current, dt, k_v, k_w, dim):
    xp = ops(state)
    x, y, alpha, nu, w = xp.unbind(state, dim)
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


def motion_model(
    mean: torch.Tensor,
    action: torch.Tensor,
    current: torch.Tensor,
    dt: float,
    k_v: float = 2.5,
    k_w: float = 2.5,
) -> torch.Tensor:
    """State transition ``f(x, u)`` of eq. 24 (eq. 28); the heading is wrapped to (-pi, pi]."""
    return _motion_model(mean, action, current, dt, k_v, k_w, dim=-1)


def _motion_jacobian_entries(alpha, nu, dt, k_v, k_w):
    """The entries of eq. 25 that are not 0 or 1: ``A[0, 2], A[0, 3], A[1, 2], A[1, 3]``
    (tensors), ``A[2, 4], A[3, 3], A[4, 4]`` (numbers)."""
    xp = ops(alpha)
    cos, sin = xp.cos(alpha), xp.sin(alpha)
    return (-sin * nu * dt, cos * dt, cos * nu * dt, sin * dt), (dt, 1 - k_v * dt, 1 - k_w * dt)


def motion_jacobian(
    mean: torch.Tensor, dt: float, k_v: float = 2.5, k_w: float = 2.5
) -> torch.Tensor:
    """Jacobian ``A = df/dx`` of eq. 25, ``(..., 5, 5)``."""
    (a02, a03, a12, a13), (a24, a33, a44) = _motion_jacobian_entries(
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
    return _stack_matrix(rows, batch_last=False)


def _apply_motion_jacobian(A, P):
    """``A @ P`` for the sparse ``A`` of eq. 25 given by its entries, batch-last ``P``
    ``(5, c, N)``: row operations instead of a dense product."""
    (a02, a03, a12, a13), (a24, a33, a44) = A
    xp = ops(P)
    p0, p1, p2, p3, p4 = xp.unbind(P, 0)
    return xp.stack(
        (
            xp.add_scaled(p0, p2, a02, p3, a03),
            xp.add_scaled(p1, p2, a12, p3, a13),
            xp.add_scaled(p2, p4, a24),
            xp.multiply(p3, a33),
            xp.multiply(p4, a44),
        ),
        dim=0,
    )


def _measurement_function(state, current, dim):
    xp = ops(state)
    x, y, alpha, nu, w = xp.unbind(state, dim)
    return observation_from_state(x, y, alpha, nu, xp.zeros_like(nu), w, current, MIN_RANGE, dim)


def measurement_function(mean: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
    """Measurement model ``h(x)`` of eq. 26, ``(..., 6)``: the observation of eq. 2 of the
    estimated state (the EKF state has no sway). The range is floored at :data:`MIN_RANGE`."""
    return _measurement_function(mean, current, dim=-1)


def _measurement_jacobian(state, current, batch_last):
    d = 0 if batch_last else -1
    xp = ops(state)
    x, y, alpha = xp.unbind(state, d)[:3]
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
    return _stack_matrix(rows, batch_last)


def measurement_jacobian(mean: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
    """Jacobian ``H = dh/dx`` of eq. 27, ``(..., 6, 5)``; ``rho`` floored at :data:`MIN_RANGE`."""
    return _measurement_jacobian(mean, current, batch_last=False)


def _innovation(state, z, current, dim):
    xp = ops(state)
    y = xp.sub(z, _measurement_function(state, current, dim))
    rho, psi, alpha, vx, vy, w = xp.unbind(y, dim)
    return xp.stack((rho, wrap_angle(psi), wrap_angle(alpha), vx, vy, w), dim=dim)


def innovation(mean: torch.Tensor, z: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
    """Eq. 30: ``y = z - h(x)``, with the bearing and heading residuals wrapped."""
    return _innovation(mean, z, current, dim=-1)


def innovation_covariance(cov: torch.Tensor, H: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """Eq. 31: ``S = H P H^T + R``, ``(..., 6, 6)``."""
    return _symmetric(H @ cov @ H.transpose(-1, -2) + R)


# --- noise covariances ---------------------------------------------------------------------------
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
    J = _stack_matrix(rows, batch_last=False)
    return _symmetric(J @ R @ J.transpose(-1, -2))


# --- the filter: eqs. 28-34 ----------------------------------------------------------------------
def ekf_predict(
    mean: torch.Tensor,
    cov: torch.Tensor,
    action: torch.Tensor,
    current: torch.Tensor,
    Q: torch.Tensor,
    dt: float,
    *,
    k_v: float = 2.5,
    k_w: float = 2.5,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Prediction step, eqs. 28-29: ``x = f(x, u)``, ``P = A P A^T + Q``.

    Args:
        mean: ``(..., 5)`` state estimate.
        cov: ``(..., 5, 5)`` its covariance.
        action: ``(..., 2)`` the control ``[v_d, w_d]`` applied over the step.
        current: ``(..., 2)`` ocean current in the DS frame.
        Q: ``(5, 5)`` or broadcastable process-noise covariance.
        dt: step length (s).
        k_v, k_w: first-order velocity-model rates of eq. 24 (1/s).

    Returns:
        The predicted ``(mean, cov)``, ``cov`` symmetric.
    """
    batch = mean.shape[:-1]
    m, P = _vector_to_last(mean), _matrix_to_last(cov, batch)
    m, P = _predict(
        m,
        P,
        _vector_to_last(action),
        _vector_to_last(current),
        _matrix_to_last(Q, batch),
        dt,
        k_v,
        k_w,
    )
    return _vector_from_last(m, batch), _matrix_from_last(P, batch)


def _predict(m, P, action, current, Q, dt, k_v, k_w):
    xp = ops(m)
    A = _motion_jacobian_entries(m[2], m[3], dt, k_v, k_w)
    m = _motion_model(m, action, current, dt, k_v, k_w, dim=0)
    # A P A^T = A (A P)^T, P symmetric
    P = xp.add_matrix(_apply_motion_jacobian(A, xp.transpose(_apply_motion_jacobian(A, P))), Q)
    return m, _symmetric(P, batch_last=True)


def ekf_update(
    mean: torch.Tensor,
    cov: torch.Tensor,
    z: torch.Tensor,
    current: torch.Tensor,
    R: torch.Tensor,
    *,
    diagonal: bool = False,
    arrived: torch.Tensor | None = None,
    gate: float | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Update step, eqs. 30-34, with the covariance in Joseph form.

    ``y = z - h(x)`` (bearing and heading residuals wrapped), ``S = H P H^T + R``,
    ``K = P H^T S^-1``, ``x = x + K y`` (heading wrapped), and
    ``P = (I - K H) P (I - K H)^T + K R K^T``: the Joseph form of eq. 34, a sum of
    positive semi-definite terms for any gain, so ``P`` stays positive-definite under rounding.

    The six measurements are first decorrelated (``R = L L^T``: ``L^-1 y`` and ``L^-1 H`` have
    unit, independent noise) and then applied one scalar at a time, each with its own Joseph
    update, linearised at the prior throughout. This gives the same estimate and covariance as
    the joint update written above without a 6 x 6 inverse per env.

    Args:
        mean: ``(..., 5)`` predicted state.
        cov: ``(..., 5, 5)`` predicted covariance.
        z: ``(..., 6)`` measurement (the raw observation).
        current: ``(..., 2)`` ocean current.
        R: ``(..., 6, 6)`` measurement covariance, broadcastable against the batch.
        diagonal: ``R`` is diagonal and given as its ``(..., 6)`` variances (cheaper).
        arrived: ``(..., 6)`` bool, which entries of ``z`` are new readings (not in the paper;
            sensors at their own rates): the others do not update, so an env whose sensors all
            held their readings keeps its predicted ``(mean, cov)`` exactly. ``None``: all.
        gate: reject a sensor's two readings when their innovation's squared Mahalanobis
            distance ``y_s^T S_s^-1 y_s`` (:func:`sensor_innovation_distance`) exceeds this
            chi-square threshold (2 degrees of freedom, e.g. :data:`CHI2_2DOF_999`): an
            outlier then leaves the estimate as predicted. ``None``: no gate.

    Returns:
        The corrected ``(mean, cov)``, ``cov`` symmetric.
    """
    batch = mean.shape[:-1]
    m, P = _update(
        _vector_to_last(mean),
        _matrix_to_last(cov, batch),
        _vector_to_last(z),
        _vector_to_last(current),
        *_noise_to_last(R, batch, diagonal),
        _arrived_to_last(arrived, batch),
        _checked_gate(gate),
    )
    return _vector_from_last(m, batch), _matrix_from_last(P, batch)


def _checked_gate(gate: float | None) -> float | None:
    if gate is not None and not (isinstance(gate, int | float) and 0 < gate < math.inf):
        raise ValueError(f"gate must be a positive chi-square threshold or None, got {gate!r}")
    return gate


def _arrived_to_last(arrived: torch.Tensor | None, batch: torch.Size) -> torch.Tensor | None:
    if arrived is None:
        return None
    if arrived.dtype != torch.bool or arrived.shape[-1] != MEASUREMENT_DIM:
        raise ValueError(
            f"arrived must be a bool (..., {MEASUREMENT_DIM}) tensor, got {arrived.dtype} "
            f"{tuple(arrived.shape)}"
        )
    return _vector_to_last(arrived.expand(*batch, MEASUREMENT_DIM))


def _sensor_distances(P, H, y, noise, full):
    """Squared Mahalanobis distance of each sensor's two innovations, ``(3, N)``, batch-last,
    before whitening: ``S_s = H_s P H_s^T + R_s``."""
    distances = []
    for i, j in SENSOR_ENTRIES:
        Ph_i = (P * H[i].unsqueeze(0)).sum(1)
        Ph_j = (P * H[j].unsqueeze(0)).sum(1)
        if full:
            r_ii, r_ij, r_jj = ((noise[a] * noise[b]).sum(0) for a, b in ((i, i), (i, j), (j, j)))
        else:
            r_ii, r_ij, r_jj = noise[i] ** 2, torch.zeros_like(noise[i]), noise[j] ** 2
        s_ii = (H[i] * Ph_i).sum(0) + r_ii
        s_ij = (H[i] * Ph_j).sum(0) + r_ij
        s_jj = (H[j] * Ph_j).sum(0) + r_jj
        det = s_ii * s_jj - s_ij * s_ij
        distances.append((s_jj * y[i] ** 2 - 2.0 * s_ij * y[i] * y[j] + s_ii * y[j] ** 2) / det)
    return torch.stack(distances, dim=0)


def sensor_innovation_distance(
    mean: torch.Tensor,
    cov: torch.Tensor,
    z: torch.Tensor,
    current: torch.Tensor,
    R: torch.Tensor,
    *,
    diagonal: bool = False,
) -> torch.Tensor:
    """Each sensor's squared Mahalanobis innovation distance ``y_s^T S_s^-1 y_s``, ``(..., 3)``
    in :data:`~dockingrl.env.realism.SENSORS`' order (USBL, DVL, IMU), with ``y_s`` and ``S_s``
    the sensor's two entries of eqs. 30-31 at the prior ``(mean, cov)``; chi-square with 2
    degrees of freedom when the filter's model holds. What ``gate`` compares."""
    batch = mean.shape[:-1]
    m, cur = _vector_to_last(mean), _vector_to_last(current)
    H = _measurement_jacobian(m, cur, batch_last=True)
    y = _innovation(m, _vector_to_last(z), cur, dim=0)
    noise, full = _noise_to_last(R, batch, diagonal)
    P = _matrix_to_last(cov, batch)
    return _vector_from_last(_sensor_distances(P, H, y, noise, full), batch)


def _noise_to_last(R: torch.Tensor, batch: torch.Size, diagonal: bool) -> tuple[torch.Tensor, bool]:
    """Batch-last Cholesky factor ``(6, 6, N)`` of a full ``R``, or sigmas ``(6, N)`` of a
    diagonal one given as variances; and whether ``R`` was full."""
    if diagonal:
        if R.shape[-1] != MEASUREMENT_DIM:
            raise ValueError(f"diagonal R must be (..., {MEASUREMENT_DIM}), got {tuple(R.shape)}")
        return _vector_to_last(torch.sqrt(R.expand(*batch, MEASUREMENT_DIM))), False
    if R.dim() < 2 or R.shape[-2:] != (MEASUREMENT_DIM, MEASUREMENT_DIM):
        raise ValueError(
            f"R must be (..., {MEASUREMENT_DIM}, {MEASUREMENT_DIM}), got {tuple(R.shape)}"
        )
    return _matrix_to_last(torch.linalg.cholesky(R), batch), True


def _update(m, P, z, current, noise, full, arrived=None, gate=None):
    xp = ops(m)
    H = _measurement_jacobian(m, current, batch_last=True)  # (6, 5, N)
    y = _innovation(m, z, current, dim=0)  # (6, N)
    if gate is not None:
        accepted = _sensor_distances(P, H, y, noise, full) <= gate  # (3, N)
        accepted = accepted[list(SENSOR_OF_ENTRY)]
        arrived = accepted if arrived is None else arrived & accepted
    if full:  # whiten with the Cholesky factor L of R: L y' = y, L H' = H
        L = noise.permute(2, 0, 1)
        y = torch.linalg.solve_triangular(L, y.T.unsqueeze(-1), upper=False).squeeze(-1).T
        H = torch.linalg.solve_triangular(L, H.permute(2, 0, 1), upper=False).permute(1, 2, 0)
    else:
        y = xp.divide(y, noise)
        H = xp.divide_rows(H, noise)
    shift = xp.zeros_like(m)  # x - x_prior: every scalar update linearises at the prior
    for i in range(MEASUREMENT_DIM):
        h = H[i]  # (5, N)
        u = xp.matvec(P, h)  # P h
        hu = xp.dot(h, u)
        K = xp.divide(u, hu + 1.0)  # eqs. 31-32 for one unit-variance measurement
        if arrived is not None:  # a zero gain leaves mean and P exactly as they are
            K = xp.where(arrived[i], K, xp.zeros_like(K))
        shift = xp.add_scaled(shift, K, y[i] - xp.dot(h, shift))  # eq. 33
        # eq. 34 in Joseph form, M P M^T + K K^T with M = I - K h^T, without forming M:
        # M P = P - K u^T and (M P) M^T = M P - w K^T, w = (M P) h = u - K (h . u);
        # so P <- P - K (u - K)^T - w K^T
        w = xp.sub(u, xp.multiply(K, hu))
        P = xp.rank2_sub(P, K, xp.sub(u, K), w, K)
    return _wrap_heading(xp.add(m, shift), dim=0), _symmetric(P, batch_last=True)


def ekf_step(
    mean: torch.Tensor,
    cov: torch.Tensor,
    action: torch.Tensor,
    z: torch.Tensor,
    current: torch.Tensor,
    Q: torch.Tensor,
    R: torch.Tensor,
    dt: float,
    *,
    k_v: float = 2.5,
    k_w: float = 2.5,
    diagonal: bool = False,
    arrived: torch.Tensor | None = None,
    gate: float | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`ekf_predict` then :func:`ekf_update` in one pass (no layout round trip between
    them); ``R``, ``diagonal``, ``arrived`` and ``gate`` as in :func:`ekf_update`: the
    prediction runs every step, each reading updates only when it arrived and passed the gate.
    Returns ``(mean, cov, h(mean))``, the last being the filtered observation (eq. 26 of the
    estimate)."""
    batch = mean.shape[:-1]
    noise, full = _noise_to_last(R, batch, diagonal)
    m, P, filtered = filter_entries(
        _vector_to_last(mean),
        _matrix_to_last(cov, batch),
        _vector_to_last(action),
        _vector_to_last(z),
        _vector_to_last(current),
        _matrix_to_last(Q, batch),
        noise,
        dt,
        k_v=k_v,
        k_w=k_w,
        full=full,
        arrived=_arrived_to_last(arrived, batch),
        gate=_checked_gate(gate),
    )
    return (
        _vector_from_last(m, batch),
        _matrix_from_last(P, batch),
        _vector_from_last(filtered, batch),
    )


def filter_entries(
    mean,
    cov,
    action,
    z,
    current,
    Q,
    sigma,
    dt,
    *,
    k_v=2.5,
    k_w=2.5,
    full=False,
    arrived=None,
    gate=None,
):
    """:func:`ekf_step` on batch-last entries, or on one env's Python floats.

    ``mean`` ``(5, N)``, ``cov`` ``(5, 5, N)``, ``action`` ``(2, N)``, ``z`` ``(6, N)``,
    ``current`` ``(2, N)``, ``Q`` ``(5, 5, N or 1)`` and ``sigma`` ``(6, N)``, the measurement
    sigmas of a diagonal ``R`` (``full``: the ``(6, 6, N)`` Cholesky factor of a full one); or
    the same as tuples of floats (vectors) and tuples of rows (matrices), diagonal ``R``, no
    ``arrived`` and no ``gate``. Returns ``(mean, cov, h(mean))`` in the same form."""
    m, P = _predict(mean, cov, action, current, Q, dt, k_v, k_w)
    m, P = _update(m, P, z, current, sigma, full, arrived, gate)
    return m, P, _measurement_function(m, current, dim=0)
