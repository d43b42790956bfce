"""The EKF with the ocean current's error in its state (not in the paper).

The paper's filter (Sec. 3.5) takes the ocean current as known. A vehicle knows it only roughly
(:class:`~dockingrl.env.DockingConfig`'s ``current_knowledge_bias`` and ``current_time_constant``:
a water-track layer that is not the water around the hull, eddies near a station), and the
filter's position then drifts with the error between fixes: the paper's filter errs by 1.09 m
with the current of stress level L2, by 0.28 m with the paper's (L0;
``results/stress/current_estimation/``). This filter adds ``b``, the velocity over ground that
eq. 24 does not predict (2 entries, m/s, DS frame), to the state of eq. 22, as the navigation
filters of real AUVs add the current (Hegrenaes and Hallingstad 2011):

- prediction: eq. 24 with the current ``c_believed + b``; ``b`` a random walk
  (``current_error_std`` m/s a step). Besides the current's error, ``b`` takes up the part of
  the velocity over ground that eq. 24 does not predict, chiefly the sway in turns (the state
  of eq. 22 has none), so its walk is faster than a current changes;
- update: eq. 26 with the current ``c_believed + b``; the DVL's ground velocities see ``b``
  directly (the sway and surge through the water being the state's), the USBL fixes through
  the drift it causes.

The update is the paper's filter's own (:func:`~dockingrl.transforms.ekf_sequential.
sequential_update`: eqs. 30-34 one decorrelated reading at a time, each linearised at the prior),
with the same asynchronous readings, chi-square gate and late-fix compensation, over the 7
entries. With ``b`` held at 0 and no uncertainty in it the filter is the paper's
(``tests/test_current_filter.py``).
"""

from __future__ import annotations

import math

import torch

from dockingrl.env.dynamics import wrap_angle
from dockingrl.transforms.ekf import STATE_DIM, _arrived_to_last, _checked_gate
from dockingrl.transforms.ekf_layout import (
    matrix_from_last,
    matrix_to_last,
    symmetric,
    vector_from_last,
    vector_to_last,
)
from dockingrl.transforms.ekf_model import (
    innovation,
    measurement_function,
    measurement_jacobian,
    motion_jacobian,
    motion_model,
)
from dockingrl.transforms.ekf_sequential import sequential_update
from dockingrl.transforms.filtering import EKFTransform, arrived_readings

#: the state of eq. 22 and the current's error ``[b_x, b_y]``
AUGMENTED_DIM = STATE_DIM + 2
#: m/s a step: the random walk of ``b`` (0.2 s steps). Fast enough to follow the sway that
#: eq. 24 leaves out as well as the current's error; at 0.005 m/s (what the current alone
#: would ask) the chi-square gate locks the filter out at stress levels L1, L4 and L5
#: (``scripts/current_filter_accuracy.py``)
CURRENT_ERROR_STD = 0.05
#: m/s: the current's error at an approach's start, per axis (a water-track layer's bias)
INITIAL_CURRENT_ERROR_STD = 0.1


def current_measurement_jacobian(alpha: torch.Tensor) -> torch.Tensor:
    """``dh/dc`` ``(..., 6, 2)``: how eq. 26's readings change with the current in the DS
    frame. Only the DVL's two ground velocities (body frame) depend on it:
    ``v_x = nu + c_x cos(alpha) + c_y sin(alpha)``, ``v_y = -c_x sin(alpha) + c_y cos(alpha)``."""
    cos, sin = torch.cos(alpha), torch.sin(alpha)
    zero = torch.zeros_like(alpha)
    rows = (
        (zero, zero),
        (zero, zero),
        (zero, zero),
        (cos, sin),
        (-sin, cos),
        (zero, zero),
    )
    return torch.stack([torch.stack(row, dim=-1) for row in rows], dim=-2)


def augmented_motion_jacobian(state: torch.Tensor, dt: float, k_v=2.5, k_w=2.5) -> torch.Tensor:
    """``(..., 7, 7)``: eq. 25's Jacobian of the 5 states of eq. 22 (``state`` ``(..., 5)``),
    with ``d x / d b = d y / d b = dt`` and ``b`` carried over."""
    A = motion_jacobian(state, dt, k_v, k_w)
    F = torch.zeros(*A.shape[:-2], AUGMENTED_DIM, AUGMENTED_DIM, dtype=A.dtype, device=A.device)
    F[..., :STATE_DIM, :STATE_DIM] = A
    F[..., 0, STATE_DIM] = dt
    F[..., 1, STATE_DIM + 1] = dt
    F[..., STATE_DIM, STATE_DIM] = 1.0
    F[..., STATE_DIM + 1, STATE_DIM + 1] = 1.0
    return F


def augmented_measurement_jacobian(state: torch.Tensor, corrected: torch.Tensor) -> torch.Tensor:
    """``(..., 6, 7)``: eq. 27's Jacobian at ``state`` ``(..., 5)`` under the corrected current
    ``(..., 2)``, and the readings' derivative with respect to ``b``."""
    return torch.cat(
        (measurement_jacobian(state, corrected), current_measurement_jacobian(state[..., 2])),
        dim=-1,
    )


def augmented_readings(mean: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
    """Eq. 26 of the estimate ``mean`` ``(..., 7)``: the readings its 5 states predict under the
    corrected current ``current + b``, ``(..., 6)``."""
    return measurement_function(mean[..., :STATE_DIM], current + mean[..., STATE_DIM:])


def augmented_step(
    mean: torch.Tensor,
    cov: torch.Tensor,
    action: torch.Tensor,
    z: torch.Tensor,
    current: torch.Tensor,
    Q: torch.Tensor,
    R: torch.Tensor,
    dt: float,
    *,
    current_error_std: float = CURRENT_ERROR_STD,
    k_v: float = 2.5,
    k_w: float = 2.5,
    arrived: torch.Tensor | None = None,
    gate: float | None = None,
    usbl_prediction: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One prediction and update of the filter that estimates the current's error.

    Args:
        mean: ``(..., 7)``: ``[x, y, alpha, nu, w]`` of eq. 22 and the current's error ``b``.
        cov: ``(..., 7, 7)``.
        action: ``(..., 2)`` the applied control.
        z: ``(..., 6)`` the readings of eq. 2.
        current: ``(..., 2)`` the current the vehicle believes (DS frame).
        Q: ``(5, 5)`` or ``(..., 5, 5)``, the process noise of eq. 22's state (Table 1).
        R: ``(..., 6)`` the measurement variances (diagonal ``R``, Table 2).
        dt: step length (s).
        current_error_std: m/s a step, the random walk of ``b``.
        arrived, gate, usbl_prediction: as in :func:`~dockingrl.transforms.ekf.ekf_update`.

    Returns:
        ``(mean, cov, h(mean))``, the last the readings the estimate predicts (eq. 26 with the
        current ``current + b``).
    """
    batch = mean.shape[:-1]
    state, error = mean[..., :STATE_DIM], mean[..., STATE_DIM:]
    corrected = current + error
    # prediction: eqs. 28-29 with the corrected current, b a random walk
    F = augmented_motion_jacobian(state, dt, k_v, k_w)
    state = motion_model(state, action, corrected, dt, k_v, k_w)
    Q7 = torch.zeros(*cov.shape, dtype=cov.dtype, device=cov.device)
    Q7[..., :STATE_DIM, :STATE_DIM] = Q
    Q7[..., STATE_DIM, STATE_DIM] = current_error_std**2
    Q7[..., STATE_DIM + 1, STATE_DIM + 1] = current_error_std**2
    P = symmetric(F @ cov @ F.transpose(-1, -2) + Q7)
    # update: eqs. 30-34, the paper's filter's sequential update over the 7 entries
    H = augmented_measurement_jacobian(state, corrected)
    y = innovation(state, z, corrected, usbl_prediction=usbl_prediction)
    shift, P = sequential_update(
        matrix_to_last(P, batch),
        matrix_to_last(H, batch),
        vector_to_last(y),
        vector_to_last(torch.sqrt(R.expand(*batch, R.shape[-1]))),
        False,
        _arrived_to_last(arrived, batch),
        _checked_gate(gate),
    )
    mean = torch.cat((state, error), dim=-1) + vector_from_last(shift, batch)
    mean = torch.cat((mean[..., :2], wrap_angle(mean[..., 2:3]), mean[..., 3:]), dim=-1)
    return mean, matrix_from_last(P, batch), augmented_readings(mean, current)


class CurrentEstimatingEKF(EKFTransform):
    """:class:`EKFTransform` with the current's error in its state (:func:`augmented_step`):
    ``ekf_mean`` ``(7,)`` and ``ekf_cov`` ``(7, 7)``; ``filtered_observation`` is eq. 26 with
    the corrected current. The gate, asynchronous readings and latency compensation of
    :class:`EKFTransform` work the same; learned ``Q`` and ``R`` files, fitted for the paper's
    filter, are refused.

    Keyword Args:
        current_error_std: m/s a step, the random walk of the current's error.
        initial_current_error_std: m/s, its standard deviation at an approach's start.
        **kwargs: as :class:`EKFTransform` (``compile`` is not supported).
    """

    state_dim = AUGMENTED_DIM

    def __init__(
        self,
        *,
        current_error_std: float = CURRENT_ERROR_STD,
        initial_current_error_std: float = INITIAL_CURRENT_ERROR_STD,
        **kwargs,
    ) -> None:
        if kwargs.get("compile"):
            raise ValueError("CurrentEstimatingEKF does not support compile=True")
        for name, value in (
            ("current_error_std", current_error_std),
            ("initial_current_error_std", initial_current_error_std),
        ):
            if not (isinstance(value, int | float) and 0 <= value < math.inf):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        super().__init__(**kwargs)
        self.current_error_std = float(current_error_std)
        self.initial_current_error_std = float(initial_current_error_std)

    def filter_step(
        self, mean, cov, action, z, current, age, *, sensor_age=None, usbl_prediction=None
    ):
        """One predict + update (:func:`augmented_step`) with the current ``Q`` and ``R``;
        the arguments and result as :meth:`EKFTransform.filter_step`'s, the state 7 wide."""
        action = self._applied_action(action).to(z.dtype)
        Q, R = self.noise_covariances(mean[..., :STATE_DIM], action, z, age)
        return augmented_step(
            mean,
            cov,
            action,
            z,
            current,
            Q,
            R,
            self.dt,
            current_error_std=self.current_error_std,
            k_v=self.k_v,
            k_w=self.k_w,
            arrived=arrived_readings(sensor_age),
            gate=self.gate,
            usbl_prediction=usbl_prediction,
        )

    def initial_estimate(self, observation, current):
        """The paper's start (:meth:`EKFTransform.initial_estimate`) with no current error,
        ``initial_current_error_std`` of uncertainty in it, and the surge's share of it: the
        first surge ``v_x - (c + b) . d`` (``d`` the heading's unit vector) is taken at
        ``b = 0``, so its variance grows by ``sigma_b^2`` and it covaries with ``b`` by
        ``-sigma_b^2 d``."""
        mean, cov = super().initial_estimate(observation, current)
        batch, var = mean.shape[:-1], self.initial_current_error_std**2
        heading = torch.stack((torch.cos(mean[..., 2]), torch.sin(mean[..., 2])), dim=-1)
        full = cov.new_zeros(*batch, AUGMENTED_DIM, AUGMENTED_DIM)
        full[..., :STATE_DIM, :STATE_DIM] = cov
        full[..., 3, 3] += var
        full[..., 3, STATE_DIM:] = -var * heading
        full[..., STATE_DIM:, 3] = -var * heading
        full[..., STATE_DIM, STATE_DIM] = var
        full[..., STATE_DIM + 1, STATE_DIM + 1] = var
        return torch.cat((mean, mean.new_zeros(*batch, 2)), dim=-1), full

    def load_filter_params(self, *args, **kwargs):
        """Refused: learned ``Q`` and ``R`` are fitted for the paper's filter, whose ``Q``
        already takes up the current's error that this filter estimates."""
        raise ValueError(
            "learned filter parameters are fitted for the paper's EKF; they do not apply to the "
            "filter that estimates the current (estimate_current)"
        )

    def filtered_readings(self, mean, current):
        """Eq. 26 of the estimate, with the corrected current (:func:`augmented_readings`)."""
        return augmented_readings(mean, current)
