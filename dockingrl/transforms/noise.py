"""The learnable noise models of the EKF: the process noise ``Q`` (eq. 29), the measurement
noise ``R`` (eq. 31, Table 2), the context model that scales both (not in the paper), and
:class:`NoiseParameters`, what the EKF transform does with them."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Self

import torch
from torch import nn

from dockingrl.transforms.ekf import (
    MEASUREMENT_DIM,
    MEASUREMENT_NOISE_STD,
    PROCESS_NOISE_STD,
    STATE_DIM,
    measurement_noise_std,
)


class ProcessNoise(nn.Module):
    """Learnable process-noise covariance ``Q = L L^T + eps I`` (eq. 29), positive-definite by
    construction: ``L = diag(sigma) (I + C)`` with ``sigma = exp(log_diag)`` and ``C`` strictly
    lower-triangular (``off_diag``), so ``L`` has the strictly positive diagonal ``sigma``.

    ``C`` is free of units: ``off_diag`` entries are correlations-like shares relative to each
    row's sigma, so a gradient step changes a 0.01 rad/s sigma and a 0.02 m sigma by the same
    relative amount (a unit-carrying ``C`` would let steps of an optimiser's learning rate,
    ~0.01-0.1, swamp a 0.01 rad/s sigma). Initialised diagonal from Table 1 sigmas.

    With ``manoeuvre=True`` (not in the paper) ``Q`` also grows with the manoeuvre: eq. 24's
    first-order velocity model is least accurate while the vehicle's PID is saturated, that is
    when the commanded velocity is far from the present one, so

        ``Q(x, u) = L L^T + diag(sum_j (gain_j,i * (u_j - nu_j))^2) + eps I``

    with ``u = [v_d, w_d]`` the applied command, ``nu = [nu, w]`` the estimated surge and yaw
    rate before the prediction, and ``gain = exp(log_manoeuvre_gain)`` ``(2, 5)`` (units of
    each state per m/s or rad/s of gap, initialised at 10 % of the Table 1 sigma per unit of
    gap). The added term is positive semi-definite, so ``Q`` stays positive-definite."""

    def __init__(
        self,
        std: Sequence[float] = PROCESS_NOISE_STD,
        eps: float = 1e-10,
        *,
        manoeuvre: bool = False,
    ) -> None:
        super().__init__()
        std = torch.as_tensor(std, dtype=torch.float64)
        if std.shape != (STATE_DIM,) or not bool((std > 0).all()):
            raise ValueError(f"process noise needs {STATE_DIM} positive sigmas, got {std}")
        self.log_diag = nn.Parameter(std.log().float())
        self.off_diag = nn.Parameter(torch.zeros(STATE_DIM * (STATE_DIM - 1) // 2))
        self.eps = eps
        if manoeuvre:
            self.set_manoeuvre(True)

    @property
    def manoeuvre(self) -> bool:
        """Whether ``Q`` depends on the manoeuvre (see the class docstring)."""
        return hasattr(self, "log_manoeuvre_gain")

    def set_manoeuvre(self, enabled: bool) -> ProcessNoise:
        """Add (initialised at 10 % of the diagonal sigma per unit of velocity gap) or drop the
        manoeuvre gains."""
        if enabled and not self.manoeuvre:
            init = (self.log_diag.detach() + math.log(0.1)).expand(2, STATE_DIM).clone()
            self.log_manoeuvre_gain = nn.Parameter(init, requires_grad=self.log_diag.requires_grad)
        elif not enabled and self.manoeuvre:
            del self.log_manoeuvre_gain
        return self

    def cholesky_factor(self) -> torch.Tensor:
        rows, cols = torch.tril_indices(STATE_DIM, STATE_DIM, offset=-1)
        sigma = self.log_diag.exp()
        unit = torch.eye(STATE_DIM, dtype=sigma.dtype, device=sigma.device)
        unit = unit.index_put((rows.to(sigma.device), cols.to(sigma.device)), self.off_diag)
        return sigma.unsqueeze(-1) * unit

    def forward(
        self, mean: torch.Tensor | None = None, action: torch.Tensor | None = None
    ) -> torch.Tensor:
        """``Q`` ``(5, 5)``; with manoeuvre gains and the prior ``mean`` ``(..., 5)`` and
        applied ``action`` ``(..., 2)`` given, ``(..., 5, 5)``."""
        L = self.cholesky_factor()
        eye = torch.eye(STATE_DIM, dtype=L.dtype, device=L.device)
        Q = L @ L.T
        Q = 0.5 * (Q + Q.T) + self.eps * eye
        if self.manoeuvre and mean is not None:
            if action is None:
                raise ValueError("a manoeuvre-dependent Q needs the action with the mean")
            gap = (action - mean[..., 3:5]).to(L.dtype)  # (..., 2)
            extra = (gap.unsqueeze(-1) * self.log_manoeuvre_gain.exp()).pow(2).sum(-2)
            Q = Q + torch.diag_embed(extra)
        return Q


class MeasurementNoise(nn.Module):
    """Learnable diagonal measurement-noise model (eq. 31): log-sigmas of Table 2, the range
    sigma being relative to the range ``rho`` (the measured one in the paper; see
    :class:`EKFTransform`'s ``range_noise_from``). ``forward(rho)`` returns the ``(..., 6)``
    variances (a diagonal ``R``), strictly positive by construction."""

    def __init__(self, std: Sequence[float] = MEASUREMENT_NOISE_STD, eps: float = 1e-12) -> None:
        super().__init__()
        std = torch.as_tensor(std, dtype=torch.float64)
        if std.shape != (MEASUREMENT_DIM,) or not bool((std > 0).all()):
            raise ValueError(
                f"measurement noise needs {MEASUREMENT_DIM} positive sigmas, got {std}"
            )
        self.log_std = nn.Parameter(std.log().float())
        self.eps = eps

    def std(self) -> torch.Tensor:
        return self.log_std.exp()

    def forward(self, measured_range: torch.Tensor) -> torch.Tensor:
        sigma = measurement_noise_std(measured_range, self.std().to(measured_range.dtype))
        return sigma**2 + self.eps


#: Inputs of :class:`NoiseContext`, each scaled to about unit range: the velocity gaps of the
#: manoeuvre (applied command minus the estimate), the estimated yaw rate and surge, the
#: range that scales ``R`` (measured or estimated, see ``range_noise_from``) and the filter's
#: age (steps since its first fix).
CONTEXT_FEATURES = (
    "surge_gap",  # |v_d - nu| / 0.5 m/s
    "yaw_gap",  # |w_d - w| / 0.2 rad/s
    "yaw_rate",  # |w| / 0.2 rad/s
    "surge",  # |nu| / 0.5 m/s
    "log_range",  # log(max(rho, 0.5 m) / 10 m), rho the range that scales R
    "fresh",  # exp(-k / 100), k the filter's steps since its first fix
    "age",  # min(k, 600) / 300
)
#: bound on each log-scale, so that no input can drive a variance to 0 or infinity
MAX_LOG_SCALE = 12.0


class NoiseContext(nn.Module):
    """Context-dependent scaling of ``Q`` and ``R`` (not in the paper).

    Eq. 24's first-order velocity model misses the vehicle's PID saturation and integrator,
    so its error depends on the manoeuvre and on the phase of the approach; with a constant
    ``Q`` a filter is overconfident while it turns towards the DS and underconfident in the
    slow final approach. Here each variance is scaled by a log-linear function of the context
    features ``f`` (:data:`CONTEXT_FEATURES`, all known to the filter on a real vehicle):

        ``Q(f) = S_q Q S_q``, ``S_q = diag(exp(0.5 f W_q))``;
        ``R(f) = R exp(f W_r)`` (``R`` diagonal),

    with ``W_q`` ``(7, 5)`` and ``W_r`` ``(7, 6)`` learned, initialised at zero (the constant
    ``Q`` and ``R``). A congruence with a positive diagonal keeps ``Q`` positive-definite and a
    positive factor keeps ``R`` positive, whatever the weights; each log-scale is clipped to
    ``+-MAX_LOG_SCALE``."""

    def __init__(self) -> None:
        super().__init__()
        self.q_weight = nn.Parameter(torch.zeros(len(CONTEXT_FEATURES), STATE_DIM))
        self.r_weight = nn.Parameter(torch.zeros(len(CONTEXT_FEATURES), MEASUREMENT_DIM))

    @staticmethod
    def features(
        mean: torch.Tensor, action: torch.Tensor, measured_range: torch.Tensor, age: torch.Tensor
    ) -> torch.Tensor:
        """``(..., 7)`` features from the prior ``mean`` ``(..., 5)``, the applied ``action``
        ``(..., 2)``, the range that scales ``R`` ``(...)`` (the measured one unless
        ``range_noise_from="estimate"``) and the filter's ``age`` in steps ``(...)``."""
        age = age.to(mean.dtype)
        return torch.stack(
            (
                (action[..., 0] - mean[..., 3]).abs() / 0.5,
                (action[..., 1] - mean[..., 4]).abs() / 0.2,
                mean[..., 4].abs() / 0.2,
                mean[..., 3].abs() / 0.5,
                torch.log(measured_range.to(mean.dtype).clamp_min(0.5) / 10.0),
                torch.exp(-age / 100.0),
                age.clamp_max(600.0) / 300.0,
            ),
            dim=-1,
        )

    def forward(
        self, mean: torch.Tensor, action: torch.Tensor, measured_range: torch.Tensor, age
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Log-scales of ``Q``'s state components ``(..., 5)`` and of ``R``'s ``(..., 6)``."""
        f = self.features(mean, action, measured_range, age)
        q = (f @ self.q_weight.to(f.dtype)).clamp(-MAX_LOG_SCALE, MAX_LOG_SCALE)
        r = (f @ self.r_weight.to(f.dtype)).clamp(-MAX_LOG_SCALE, MAX_LOG_SCALE)
        return q, r


#: What may scale the range sigma of ``R`` (:attr:`NoiseParameters.range_noise_from`).
RANGE_NOISE_FROM = ("measurement", "estimate")


class NoiseParameters:
    """The noise models of an EKF as its transform holds them (``process_noise``,
    ``measurement_noise``, ``noise_context`` and ``range_noise_from``): their parameters,
    frozen or learned, and the ``Q`` and ``R`` of a step.
    :class:`~dockingrl.transforms.filtering.EKFTransform` is one, and saves and loads them
    (:mod:`dockingrl.transforms.params`)."""

    process_noise: ProcessNoise
    measurement_noise: MeasurementNoise
    noise_context: NoiseContext | None

    def init_noise_models(
        self,
        process_noise_std: Sequence[float] = PROCESS_NOISE_STD,
        measurement_noise_std: Sequence[float] = MEASUREMENT_NOISE_STD,
        *,
        manoeuvre_noise: bool = False,
        context_noise: bool = False,
        range_noise_from: str = "measurement",
    ) -> Self:
        """Build the noise models from their initial standard deviations (the paper's by
        default), as :class:`~dockingrl.transforms.filtering.EKFTransform` takes them."""
        self.process_noise = ProcessNoise(process_noise_std, manoeuvre=manoeuvre_noise)
        self.measurement_noise = MeasurementNoise(measurement_noise_std)
        self.noise_context = None
        self.set_context_noise(context_noise)
        self.range_noise_from = range_noise_from
        return self

    def set_learnable(self, learnable: bool = True) -> Self:
        """Freeze or unfreeze ``Q`` and ``R``."""
        for p in self.noise_parameters():
            p.requires_grad_(learnable)
        return self

    def noise_parameters(self) -> list[nn.Parameter]:
        context = [] if self.noise_context is None else list(self.noise_context.parameters())
        return [*self.process_noise.parameters(), *self.measurement_noise.parameters(), *context]

    @property
    def context_noise(self) -> bool:
        """Whether ``Q`` and ``R`` are scaled by a :class:`NoiseContext`."""
        return self.noise_context is not None

    def set_context_noise(self, enabled: bool) -> Self:
        """Add a :class:`NoiseContext` (zero weights: ``Q`` and ``R`` unchanged) or drop it."""
        if enabled and self.noise_context is None:
            learnable = self.measurement_noise.log_std.requires_grad
            device = self.measurement_noise.log_std.device
            self.noise_context = NoiseContext().to(device).requires_grad_(learnable)
        elif not enabled:
            self.noise_context = None
        return self

    @property
    def range_noise_from(self) -> str:
        """``"measurement"`` or ``"estimate"``: the range that scales the range sigma of ``R``
        (see :class:`~dockingrl.transforms.filtering.EKFTransform`)."""
        return self._range_noise_from

    @range_noise_from.setter
    def range_noise_from(self, value: str) -> None:
        if value not in RANGE_NOISE_FROM:
            raise ValueError(
                f"range_noise_from must be one of {', '.join(RANGE_NOISE_FROM)}, got {value!r}"
            )
        self._range_noise_from = value

    def noise_covariances(
        self, mean: torch.Tensor, action: torch.Tensor, z: torch.Tensor, age: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``Q`` ``(5, 5)`` or ``(..., 5, 5)`` and the diagonal of ``R`` ``(..., 6)`` for a
        step from the prior ``mean`` under the applied ``action`` to the measurement ``z``,
        the filter being ``age`` steps old (the age matters to a context model only). The
        range that scales ``R`` is ``z``'s or ``mean``'s (:attr:`range_noise_from`)."""
        Q = self.process_noise(mean, action).to(z.dtype)
        if self.range_noise_from == "estimate":
            rho = torch.linalg.vector_norm(mean[..., :2], dim=-1).to(z.dtype)
        else:
            rho = z[..., 0]
        R = self.measurement_noise(rho)
        if self.noise_context is not None:
            q_log, r_log = self.noise_context(mean, action, rho, age)
            half = torch.exp(0.5 * q_log)
            Q = Q * half.unsqueeze(-1) * half.unsqueeze(-2)
            R = R * torch.exp(r_log)
        return Q, R
