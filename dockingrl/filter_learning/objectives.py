"""The objectives of a filter fit and the differentiable filter run over recorded rollouts
that computes them (:func:`run_filter`): the innovations' likelihood (``nll``), the true
state's likelihood under the estimate (``supervised``) and the estimate's squared error
(``mse``), and the innovations' whiteness penalty."""

from __future__ import annotations

import torch
from tensordict import TensorDict

from dockingrl.env.dynamics import wrap_angle
from dockingrl.filter_learning.options import OBJECTIVES
from dockingrl.transforms.ekf import (
    STATE_DIM,
    ekf_predict,
    ekf_update,
    innovation,
    innovation_covariance,
    measurement_jacobian,
)
from dockingrl.transforms.filtering import EKFTransform, arrived_readings


def whiten(residual: torch.Tensor, cov: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(L^-1 r, L)`` with ``C = L L^T`` the Cholesky factor: ``residual`` ``(..., n)``,
    ``cov`` ``(..., n, n)``. ``|L^-1 r|^2 = r^T C^-1 r``."""
    L = torch.linalg.cholesky(cov)
    return torch.linalg.solve_triangular(L, residual.unsqueeze(-1), upper=False).squeeze(-1), L


def _nll_of_whitened(white: torch.Tensor, L: torch.Tensor) -> torch.Tensor:
    return 0.5 * white.pow(2).sum(-1) + torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1)


def gaussian_nll(residual: torch.Tensor, cov: torch.Tensor) -> torch.Tensor:
    """``0.5 (r^T C^-1 r + log det C)`` per batch entry (the constant dropped), through a
    Cholesky factor: ``residual`` ``(..., n)``, ``cov`` ``(..., n, n)``."""
    return _nll_of_whitened(*whiten(residual, cov))


def masked_innovation(
    residual: torch.Tensor, cov: torch.Tensor, arrived: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor]:
    """The innovation ``(..., m)`` and its covariance ``(..., m, m)`` of the ``arrived``
    entries ``(..., m)`` only: the others' residuals set to 0 and their rows and columns to
    the identity's, so that ``r^T C^-1 r`` and ``log det C`` are those of the arrived entries'
    marginal and their whitened values are 0. ``None``: unchanged."""
    if arrived is None:
        return residual, cov
    both = arrived.unsqueeze(-1) & arrived.unsqueeze(-2)
    eye = torch.eye(cov.shape[-1], dtype=cov.dtype, device=cov.device)
    return torch.where(arrived, residual, torch.zeros_like(residual)), torch.where(both, cov, eye)


def innovation_whiteness(
    white: torch.Tensor, valid: torch.Tensor, lags: int, arrived: torch.Tensor | None = None
) -> torch.Tensor:
    """Whiteness penalty of whitened innovations: ``sum_k ||C_k||_F^2``, ``k = 1..lags``, with
    ``C_k`` the mean over envs and steps of ``w_t w_{t-k}^T``.

    For the optimal gain of a correctly modelled filter the innovations are white (uncorrelated
    in time) whatever the state's trajectory, and ``w_t = L_t^-1 y_t`` (``S_t = L_t L_t^T``) are
    independent standard normals; a wrong ratio of ``Q`` to ``R`` shows as correlation between
    steps. This is the property that autocovariance least-squares methods (Odelson, Rajamani and
    Rawlings, 2006) use to tell ``Q`` from ``R`` with the measurements alone.

    Args:
        white: ``(T, N, m)`` whitened innovations.
        valid: ``(T, N)`` True where step ``t`` has an innovation (not an episode's first).
        arrived: ``(T, N, m)`` True where an entry's reading arrived (``None``: all): each
            ``C_k[i, j]`` is then the mean over the pairs where both ``i`` at ``t`` and ``j``
            at ``t - k`` arrived (the others' whitened values are 0).
    """
    run = torch.zeros_like(valid[0], dtype=torch.int64)
    runs = []
    for t in range(valid.shape[0]):  # consecutive steps with an innovation, up to t
        run = torch.where(valid[t], run + 1, torch.zeros_like(run))
        runs.append(run)
    runs = torch.stack(runs)
    penalty = white.new_zeros(())
    for k in range(1, lags + 1):
        keep = (runs[k:] > k).to(white.dtype)  # steps t-k..t of one episode, all with innovations
        count = keep.sum().clamp_min(1.0)
        cross = torch.einsum("tn,tni,tnj->ij", keep, white[k:], white[:-k])
        if arrived is not None:
            pairs = arrived.to(white.dtype)
            count = torch.einsum("tn,tni,tnj->ij", keep, pairs[k:], pairs[:-k]).clamp_min(1.0)
        cross = cross / count
        penalty = penalty + cross.pow(2).sum()
    return penalty


def state_error(mean: torch.Tensor, true_state: torch.Tensor) -> torch.Tensor:
    """Estimate minus truth, ``(..., 5)``: x, y, wrapped heading, surge, yaw rate."""
    x, y, alpha, u, _, r = true_state.unbind(-1)
    truth = torch.stack((x, y, alpha, u, r), dim=-1)
    error = mean - truth
    return torch.cat((error[..., :2], wrap_angle(error[..., 2:3]), error[..., 3:]), dim=-1)


def run_filter(
    ekf: EKFTransform,
    data: TensorDict,
    *,
    state: tuple[torch.Tensor, torch.Tensor] | None = None,
    objective: str | None = None,
    dt: float = 0.2,
    nis: list | None = None,
    whiteness: float = 0.0,
    lags: int = 5,
):
    """Run the filter over ``data`` (``(T, N)`` from :func:`record_rollouts`), re-initialising
    each env at the first step of its episodes, differentiably in ``Q`` and ``R``. With
    ``sensor_age`` in ``data`` a reading updates only at the step it arrived (as
    :class:`EKFTransform` does in the env); ``ekf.gate`` rejects outliers as there, and
    ``ekf.latency_steps`` compensates a late USBL fix as there (the innovation objectives and
    metrics then use the compensated innovation).

    Args:
        state: ``(mean, cov, action)`` after the step before ``data[0]`` (truncated BPTT
            carries it, detached), with the filter's ``ekf_usbl_history`` appended when it
            compensates a latency; ``None`` initialises from ``data[0]``.
        objective: if given, also return the mean loss per step and env.
        nis: if a list, the normalised innovation squared ``y^T S^-1 y`` of each step ``(N,)``
            is appended to it (for the first step of an episode: NaN, no prediction), over
            the readings that arrived (NaN where none did).
        whiteness: with ``objective="nll"``, add this weight times
            :func:`innovation_whiteness` of the window's innovations over ``lags`` lags.

    The ``nll`` objective is the mean over steps and envs of the innovations' negative
    log-likelihood, each step's over the readings that arrived at it (0 where none did).

    Returns:
        ``(means, covs, state, loss)``: the estimates after each step ``(T, N, 5)``,
        ``(T, N, 5, 5)``, the final state (as ``state``) and the loss (``None`` without an
        objective).
    """
    if objective is not None and objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; valid: {', '.join(OBJECTIVES)}")
    if ekf.state_dim != STATE_DIM:
        raise ValueError(
            f"run_filter runs the paper's {STATE_DIM}-state EKF; {type(ekf).__name__} keeps "
            f"{ekf.state_dim} (run it through its filter_step)"
        )
    z, action = data["observation"], data["action"]
    current, fresh = data["ocean_current"], data["step_count"] == 0
    sensor_age = data.get("sensor_age", None)
    means, covs, losses, whites, valids, arrivals = [], [], [], [], [], []
    if state is None:
        mean, cov = ekf.initial_estimate(z[0], current[0])
        previous_action, start = action[0], 1
        history = ekf.initial_history(ekf.filtered_readings(mean, current[0]))
        means.append(mean)
        covs.append(cov)
    else:
        (mean, cov, previous_action, *rest), start = state, 0
        history = rest[0] if ekf.latency_steps else None
    for t in range(start, z.shape[0]):
        applied = ekf._applied_action(previous_action)
        # the filter's age before this update: the steps since its episode's first fix
        Q, R = ekf.noise_covariances(mean, applied, z[t], data["step_count"][t] - 1)
        prior_mean, prior_cov = ekf_predict(
            mean, cov, applied, current[t], Q, dt, k_v=ekf.k_v, k_w=ekf.k_w
        )
        previous_action = action[t]
        arrived = None if sensor_age is None else arrived_readings(sensor_age[t])
        late = ekf.late_fix_prediction(history)
        if objective == "nll" or nis is not None:
            H = measurement_jacobian(prior_mean, current[t])
            S = innovation_covariance(prior_cov, H, torch.diag_embed(R))
            y = innovation(prior_mean, z[t], current[t], usbl_prediction=late)
            w, L = whiten(*masked_innovation(y, S, arrived))
        if objective == "nll":
            nll = _nll_of_whitened(w, L)
            losses.append(torch.where(fresh[t], torch.zeros_like(nll), nll))
            if whiteness > 0:
                whites.append(torch.where(fresh[t].unsqueeze(-1), torch.zeros_like(w), w))
                valids.append(~fresh[t])
                if arrived is not None:
                    arrivals.append(arrived)
        if nis is not None:
            value = w.pow(2).sum(-1)  # y^T S^-1 y
            none = fresh[t] if arrived is None else fresh[t] | ~arrived.any(-1)
            nis.append(torch.where(none, torch.full_like(value, float("nan")), value))
        new_mean, new_cov = ekf_update(
            prior_mean,
            prior_cov,
            z[t],
            current[t],
            R,
            diagonal=True,
            arrived=arrived,
            gate=ekf.gate,
            usbl_prediction=late,
        )
        mean, cov = ekf.start_where(fresh[t], new_mean, new_cov, z[t], current[t])
        if history is not None:
            history = ekf.next_history(history, ekf.filtered_readings(mean, current[t]), fresh[t])
        if objective == "supervised":
            nll = gaussian_nll(state_error(mean, data["true_state"][t]), cov)
            losses.append(torch.where(fresh[t], torch.zeros_like(nll), nll))
        if objective == "mse":
            error = state_error(mean, data["true_state"][t])
            losses.append(torch.where(fresh[t].unsqueeze(-1), torch.zeros_like(error), error))
        means.append(mean)
        covs.append(cov)
    if objective == "mse":
        errors = torch.stack(losses)  # (T, N, 5); fresh steps are zero and not counted
        counted = (~fresh[start:]).sum().clamp_min(1)
        loss = torch.log(errors.pow(2).sum((0, 1)) / counted).sum()
    else:
        loss = torch.stack(losses).mean() if losses else None
    if whites:
        loss = loss + whiteness * innovation_whiteness(
            torch.stack(whites),
            torch.stack(valids),
            lags,
            torch.stack(arrivals) if arrivals else None,
        )
    state = (mean, cov, previous_action) + (() if history is None else (history,))
    return torch.stack(means), torch.stack(covs), state, loss
