"""The docking task's Extended Kalman Filter (Sec. 3.5, eqs. 22-34) as pure batched functions:
prediction (eqs. 28-29), update (eqs. 30-34, Joseph form, with an optional chi-square gate and
asynchronous readings) and both in one step.

The model they run (the state of eq. 22, the motion and measurement models and Jacobians of
eqs. 24-27, the innovation of eqs. 30-31, ``Q`` and ``R`` of Tables 1-2 and the start) is in
:mod:`dockingrl.transforms.ekf_model`, and importable from here too. The public functions take
any leading batch shape ``(...)`` (matrices in the last two dimensions), work in float32 and
float64 and are differentiable, with respect to the noise covariances too, which is what lets
:class:`~dockingrl.transforms.EKFTransform` learn them. Internally they run batch-last
(:mod:`dockingrl.transforms.ekf_layout`); the same batch-last step also runs on one env's
Python floats: :func:`filter_entries`.
"""

from __future__ import annotations

import math

import torch

from dockingrl.env.arrays import ops
from dockingrl.transforms.ekf_layout import (
    matrix_from_last,
    matrix_to_last,
    symmetric,
    vector_from_last,
    vector_to_last,
)
from dockingrl.transforms.ekf_model import (
    MEASUREMENT_DIM,
    MEASUREMENT_NOISE_STD,
    MIN_RANGE,
    PROCESS_NOISE_STD,
    STATE_DIM,
    initial_covariance,
    innovation,
    innovation_covariance,
    measurement_covariance,
    measurement_function,
    measurement_jacobian,
    measurement_noise_std,
    motion_jacobian,
    motion_jacobian_entries,
    motion_model,
    process_covariance,
    state_from_observation,
    wrap_heading,
)
from dockingrl.transforms.ekf_sequential import SENSOR_ENTRIES, sensor_distances, sequential_update

__all__ = [
    "CHI2_2DOF_999",
    "MEASUREMENT_DIM",
    "MEASUREMENT_NOISE_STD",
    "MIN_RANGE",
    "PROCESS_NOISE_STD",
    "SENSOR_ENTRIES",
    "STATE_DIM",
    "ekf_predict",
    "ekf_step",
    "ekf_update",
    "filter_entries",
    "initial_covariance",
    "innovation",
    "innovation_covariance",
    "measurement_covariance",
    "measurement_function",
    "measurement_jacobian",
    "measurement_noise_std",
    "motion_jacobian",
    "motion_model",
    "process_covariance",
    "sensor_innovation_distance",
    "state_from_observation",
]

#: chi-square quantiles with 2 degrees of freedom (each sensor gives two numbers): a gate at
#: 13.8 rejects 0.1 % of the readings that follow the model, at 9.21 1 %
CHI2_2DOF_999 = 13.816


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
    m, P = vector_to_last(mean), matrix_to_last(cov, batch)
    m, P = _predict(
        m,
        P,
        vector_to_last(action),
        vector_to_last(current),
        matrix_to_last(Q, batch),
        dt,
        k_v,
        k_w,
    )
    return vector_from_last(m, batch), matrix_from_last(P, batch)


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


def _predict(m, P, action, current, Q, dt, k_v, k_w):
    xp = ops(m)
    A = motion_jacobian_entries(m[2], m[3], dt, k_v, k_w)
    m = motion_model(m, action, current, dt, k_v, k_w, dim=0)
    # A P A^T = A (A P)^T, P symmetric
    P = xp.add_matrix(_apply_motion_jacobian(A, xp.transpose(_apply_motion_jacobian(A, P))), Q)
    return m, symmetric(P, batch_last=True)


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
    usbl_prediction: torch.Tensor | None = None,
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
        usbl_prediction: ``(..., 2)`` the range and bearing predicted for the instant a late
            USBL fix in ``z`` describes (latency compensation, not in the paper; see
            :func:`~dockingrl.transforms.ekf_model.innovation`). ``None``: it describes now.

    Returns:
        The corrected ``(mean, cov)``, ``cov`` symmetric.
    """
    batch = mean.shape[:-1]
    m, P = _update(
        vector_to_last(mean),
        matrix_to_last(cov, batch),
        vector_to_last(z),
        vector_to_last(current),
        *_noise_to_last(R, batch, diagonal),
        _arrived_to_last(arrived, batch),
        _checked_gate(gate),
        _usbl_prediction_to_last(usbl_prediction, batch),
    )
    return vector_from_last(m, batch), matrix_from_last(P, batch)


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
    return vector_to_last(arrived.expand(*batch, MEASUREMENT_DIM))


def _usbl_prediction_to_last(prediction, batch: torch.Size) -> torch.Tensor | None:
    if prediction is not None and prediction.shape[-1] != 2:
        raise ValueError(f"usbl_prediction must be (..., 2), got {tuple(prediction.shape)}")
    return None if prediction is None else vector_to_last(prediction.expand(*batch, 2))


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
    m, cur = vector_to_last(mean), vector_to_last(current)
    H = measurement_jacobian(m, cur, batch_last=True)
    y = innovation(m, vector_to_last(z), cur, dim=0)
    noise, full = _noise_to_last(R, batch, diagonal)
    P = matrix_to_last(cov, batch)
    return vector_from_last(sensor_distances(P, H, y, noise, full), batch)


def _noise_to_last(R: torch.Tensor, batch: torch.Size, diagonal: bool) -> tuple[torch.Tensor, bool]:
    """Batch-last Cholesky factor ``(6, 6, N)`` of a full ``R``, or sigmas ``(6, N)`` of a
    diagonal one given as variances; and whether ``R`` was full."""
    if diagonal:
        if R.shape[-1] != MEASUREMENT_DIM:
            raise ValueError(f"diagonal R must be (..., {MEASUREMENT_DIM}), got {tuple(R.shape)}")
        return vector_to_last(torch.sqrt(R.expand(*batch, MEASUREMENT_DIM))), False
    if R.dim() < 2 or R.shape[-2:] != (MEASUREMENT_DIM, MEASUREMENT_DIM):
        raise ValueError(
            f"R must be (..., {MEASUREMENT_DIM}, {MEASUREMENT_DIM}), got {tuple(R.shape)}"
        )
    return matrix_to_last(torch.linalg.cholesky(R), batch), True


def _update(m, P, z, current, noise, full, arrived=None, gate=None, usbl_prediction=None):
    H = measurement_jacobian(m, current, batch_last=True)  # (6, 5, N)
    y = innovation(m, z, current, dim=0, usbl_prediction=usbl_prediction)  # (6, N)
    shift, P = sequential_update(P, H, y, noise, full, arrived, gate)
    return wrap_heading(ops(m).add(m, shift), dim=0), P


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
    usbl_prediction: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`ekf_predict` then :func:`ekf_update` in one pass (no layout round trip between
    them); ``R``, ``diagonal``, ``arrived``, ``gate`` and ``usbl_prediction`` as in
    :func:`ekf_update`: the
    prediction runs every step, each reading updates only when it arrived and passed the gate.
    Returns ``(mean, cov, h(mean))``, the last being the filtered observation (eq. 26 of the
    estimate)."""
    batch = mean.shape[:-1]
    noise, full = _noise_to_last(R, batch, diagonal)
    m, P, filtered = filter_entries(
        vector_to_last(mean),
        matrix_to_last(cov, batch),
        vector_to_last(action),
        vector_to_last(z),
        vector_to_last(current),
        matrix_to_last(Q, batch),
        noise,
        dt,
        k_v=k_v,
        k_w=k_w,
        full=full,
        arrived=_arrived_to_last(arrived, batch),
        gate=_checked_gate(gate),
        usbl_prediction=_usbl_prediction_to_last(usbl_prediction, batch),
    )
    return (
        vector_from_last(m, batch),
        matrix_from_last(P, batch),
        vector_from_last(filtered, batch),
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
    usbl_prediction=None,
):
    """:func:`ekf_step` on batch-last entries, or on one env's Python floats.

    ``mean`` ``(5, N)``, ``cov`` ``(5, 5, N)``, ``action`` ``(2, N)``, ``z`` ``(6, N)``,
    ``current`` ``(2, N)``, ``Q`` ``(5, 5, N or 1)`` and ``sigma`` ``(6, N)``, the measurement
    sigmas of a diagonal ``R`` (``full``: the ``(6, 6, N)`` Cholesky factor of a full one); or
    the same as tuples of floats (vectors) and tuples of rows (matrices), diagonal ``R``, no
    ``arrived``, no ``gate`` and no ``usbl_prediction`` (``(2, N)``). Returns ``(mean, cov,
    h(mean))`` in the same form."""
    m, P = _predict(mean, cov, action, current, Q, dt, k_v, k_w)
    m, P = _update(m, P, z, current, sigma, full, arrived, gate, usbl_prediction)
    return m, P, measurement_function(m, current, dim=0)
