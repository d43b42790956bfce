"""The EKF with the ocean current's error in its state (not in the paper).

The paper's filter (Sec. 3.5) takes the ocean current as known. A vehicle knows it only roughly
(:class:`~dockingrl.env.DockingConfig`'s ``current_knowledge_bias`` and ``current_time_constant``:
a water-track layer that is not the water around the hull, eddies near a station), and the
filter's position then drifts with the error between fixes: at stress level L5 the current's
bias alone takes the paper's filter's position error from about 0.74 to 1.28 m. This filter adds
the difference ``b = c_true - c_believed`` (2 entries, m/s, DS frame) to the state of eq. 22,
as the navigation filters of real AUVs do (Hegrenaes and Hallingstad 2011):

- prediction: eq. 24 with the current ``c_believed + b``; ``b`` a random walk
  (``current_error_std`` m/s a step). Besides the current's error, ``b`` takes up the part of
  the velocity over ground that eq. 24 does not predict, chiefly the sway in turns (the state
  of eq. 22 has none), so its walk is faster than a current changes;
- update: eq. 26 with the current ``c_believed + b``; the DVL's ground velocities see ``b``
  directly (the sway and surge through the water being the state's), the USBL fixes through
  the drift it causes.

The update is the sequential scalar update of :func:`~dockingrl.transforms.ekf.ekf_update`
(eqs. 30-34 one decorrelated reading at a time, each linearised at the prior), with the same
asynchronous readings, chi-square gate and late-fix compensation, written densely over the
7 entries (batch first). With ``b`` held at 0 and no uncertainty in it the filter is the
paper's: ``tests/test_current_filter.py`` checks both against each other.
"""

from __future__ import annotations

import math

import torch

from dockingrl.env.dynamics import wrap_angle
from dockingrl.env.realism import SENSOR_OF_ENTRY
from dockingrl.transforms.ekf import SENSOR_ENTRIES, STATE_DIM
from dockingrl.transforms.ekf_model import (
    innovation,
    measurement_function,
    measurement_jacobian,
    motion_jacobian,
    motion_model,
)
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
    state, error = mean[..., :STATE_DIM], mean[..., STATE_DIM:]
    believed = current + error
    # prediction: eq. 24 with the corrected current; d x / d b = d y / d b = dt
    A = motion_jacobian(state, dt, k_v, k_w)
    G = torch.zeros(*A.shape[:-1], 2, dtype=A.dtype, device=A.device)
    G[..., 0, 0] = dt
    G[..., 1, 1] = dt
    top = torch.cat((A, G), dim=-1)
    bottom = torch.cat(
        (
            torch.zeros(*A.shape[:-2], 2, STATE_DIM, dtype=A.dtype, device=A.device),
            torch.eye(2, dtype=A.dtype, device=A.device).expand(*A.shape[:-2], 2, 2),
        ),
        dim=-1,
    )
    F = torch.cat((top, bottom), dim=-2)
    state = motion_model(state, action, believed, dt, k_v, k_w)
    Q7 = torch.zeros(*cov.shape, dtype=cov.dtype, device=cov.device)
    Q7[..., :STATE_DIM, :STATE_DIM] = Q
    Q7[..., STATE_DIM, STATE_DIM] = current_error_std**2
    Q7[..., STATE_DIM + 1, STATE_DIM + 1] = current_error_std**2
    P = F @ cov @ F.transpose(-1, -2) + Q7
    P = 0.5 * (P + P.transpose(-1, -2))
    # update: eqs. 30-34 over the 7 entries, one reading at a time, linearised at the prior
    H = torch.cat(
        (measurement_jacobian(state, believed), current_measurement_jacobian(state[..., 2])),
        dim=-1,
    )
    y = innovation(state, z, believed, usbl_prediction=usbl_prediction)
    if gate is not None:
        accepted = (_sensor_distances(P, H, y, R) <= gate)[..., list(SENSOR_OF_ENTRY)]
        arrived = accepted if arrived is None else arrived & accepted
    shift = torch.zeros_like(mean)
    for i in range(H.shape[-2]):
        h = H[..., i, :]
        u = (P @ h.unsqueeze(-1)).squeeze(-1)
        s = (h * u).sum(-1) + R[..., i]
        K = u / s.unsqueeze(-1)
        if arrived is not None:  # a zero gain leaves mean and P as they are
            K = torch.where(arrived[..., i : i + 1], K, torch.zeros_like(K))
        shift = shift + K * (y[..., i] - (h * shift).sum(-1)).unsqueeze(-1)
        # Joseph form for one reading of variance r: P - K u^T - u K^T + s K K^T
        P = (
            P
            - K.unsqueeze(-1) * u.unsqueeze(-2)
            - u.unsqueeze(-1) * K.unsqueeze(-2)
            + s[..., None, None] * K.unsqueeze(-1) * K.unsqueeze(-2)
        )
    mean = torch.cat((state, error), dim=-1) + shift
    heading = wrap_angle(mean[..., 2:3])
    mean = torch.cat((mean[..., :2], heading, mean[..., 3:]), dim=-1)
    P = 0.5 * (P + P.transpose(-1, -2))
    filtered = measurement_function(mean[..., :STATE_DIM], current + mean[..., STATE_DIM:])
    return mean, P, filtered


def _sensor_distances(P, H, y, R):
    """Each sensor's squared Mahalanobis innovation distance ``(..., 3)`` (USBL, DVL, IMU)."""
    distances = []
    for i, j in SENSOR_ENTRIES:
        Hs = H[..., [i, j], :]
        S = Hs @ P @ Hs.transpose(-1, -2) + torch.diag_embed(R[..., [i, j]])
        ys = y[..., [i, j]].unsqueeze(-1)
        distances.append((ys.transpose(-1, -2) @ torch.linalg.solve(S, ys))[..., 0, 0])
    return torch.stack(distances, dim=-1)


class CurrentEstimatingEKF(EKFTransform):
    """:class:`EKFTransform` with the current's error in its state (:func:`augmented_step`):
    ``ekf_mean`` ``(7,)`` and ``ekf_cov`` ``(7, 7)``; ``filtered_observation`` is eq. 26 with
    the corrected current. Every option of :class:`EKFTransform` (gate, asynchronous readings,
    latency compensation, learned ``Q`` and ``R``) works the same.

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
        """The paper's start (:meth:`EKFTransform.initial_estimate`) with no current error
        and ``initial_current_error_std`` of uncertainty in it."""
        mean, cov = super().initial_estimate(observation, current)
        batch = mean.shape[:-1]
        mean = torch.cat((mean, mean.new_zeros(*batch, 2)), dim=-1)
        full = cov.new_zeros(*batch, AUGMENTED_DIM, AUGMENTED_DIM)
        full[..., :STATE_DIM, :STATE_DIM] = cov
        full[..., STATE_DIM, STATE_DIM] = self.initial_current_error_std**2
        full[..., STATE_DIM + 1, STATE_DIM + 1] = self.initial_current_error_std**2
        return mean, full

    def filtered_readings(self, mean, current):
        """Eq. 26 of the estimate, with the corrected current."""
        return measurement_function(mean[..., :STATE_DIM], current + mean[..., STATE_DIM:])
