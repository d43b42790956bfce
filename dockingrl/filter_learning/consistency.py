"""How good a filter is on recorded rollouts: the RMSE of its estimate against the truth, the
consistency of its covariance (NEES) and of its innovations (NIS)."""

from __future__ import annotations

import math

import torch
from tensordict import TensorDict

from dockingrl.filter_learning.objectives import run_filter, state_error
from dockingrl.transforms.ekf import MEASUREMENT_DIM
from dockingrl.transforms.filtering import EKFTransform, arrived_readings


def filter_estimates(ekf: EKFTransform, data: TensorDict) -> torch.Tensor:
    """The estimate after each recorded step, ``(T, N, ekf.state_dim)``, of any
    :class:`EKFTransform` (the paper's or one with more states, such as
    :class:`~dockingrl.transforms.current_filter.CurrentEstimatingEKF`), run through the
    transform's own ``filter_step`` as the env runs it, each episode from its first reading;
    no gradients. :func:`run_filter` is the differentiable run of the paper's filter."""
    z, action, current = data["observation"], data["action"], data["ocean_current"]
    fresh, ages = data["step_count"] == 0, data.get("sensor_age", None)
    with torch.no_grad():
        mean, cov = ekf.initial_estimate(z[0], current[0])
        history = ekf.initial_history(ekf.filtered_readings(mean, current[0]))
        means = [mean]
        for t in range(1, z.shape[0]):
            mean, cov, _ = ekf.filter_step(
                mean,
                cov,
                action[t - 1],
                z[t],
                current[t],
                data["step_count"][t] - 1,
                sensor_age=None if ages is None else ages[t],
                usbl_prediction=ekf.late_fix_prediction(history),
            )
            mean, cov = ekf.start_where(fresh[t], mean, cov, z[t], current[t])
            history = ekf.next_history(history, ekf.filtered_readings(mean, current[t]), fresh[t])
            means.append(mean)
    return torch.stack(means)


def _chi2_quantile(p: float, dof: float) -> float:
    """Wilson-Hilferty approximation of the chi-square quantile."""
    z = math.sqrt(2) * _erfinv(2 * p - 1)
    return dof * (1 - 2 / (9 * dof) + z * math.sqrt(2 / (9 * dof))) ** 3


def _erfinv(x: float) -> float:
    return float(torch.erfinv(torch.tensor(x, dtype=torch.float64)))


def run_averaged_nees_test(nees: torch.Tensor, keep: torch.Tensor, dof: int = 5) -> float:
    """Monte-Carlo consistency test (Bar-Shalom, Li and Kirubarajan 2001, Sec. 5.4).

    ``nees`` ``(T, N)``: NEES of ``N`` independent runs at ``T`` time indices; ``keep`` marks
    the entries to use. At each time index the NEES averaged over the kept runs is compared with
    the two-sided 95 % region of the mean of that many chi-square(``dof``) samples. Returns the
    fraction of time indices inside it: about 0.95 for a consistent filter.
    """
    runs = keep.sum(-1)
    steps = runs > 0
    mean = (torch.where(keep, nees, torch.zeros_like(nees)).sum(-1) / runs.clamp_min(1))[steps]
    counts = runs[steps].tolist()
    low = torch.tensor([_chi2_quantile(0.025, dof * k) / k for k in counts], dtype=mean.dtype)
    high = torch.tensor([_chi2_quantile(0.975, dof * k) / k for k in counts], dtype=mean.dtype)
    return float(((mean >= low) & (mean <= high)).double().mean())


def normalized_errors(
    means: torch.Tensor, covs: torch.Tensor, true_state: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """NEES ``e^T P^-1 e`` of the 5-dim state error ``(...)`` and ``e_i^2 / P_ii`` per state
    component ``(..., 5)`` (x, y, heading, surge, yaw rate), in float64. For a consistent filter
    the first is chi-square(5) (mean 5) and each of the second has mean 1."""
    error = state_error(means, true_state).double()
    cov = covs.double()
    nees = (error.unsqueeze(-2) @ torch.linalg.solve(cov, error.unsqueeze(-1)))[..., 0, 0]
    return nees, error.pow(2) / torch.diagonal(cov, dim1=-2, dim2=-1)


def evaluate_filter(ekf: EKFTransform, data: TensorDict, *, skip: int = 10) -> dict:
    """RMSE of the estimate against the truth and NEES consistency on recorded rollouts.

    The first ``skip`` steps of every episode (the filter's transient from its first fix) are
    left out. NEES ``e^T P^-1 e`` of the 5-dim state error: its mean should be 5 for a consistent
    filter; reported with the 95 % bounds of the mean of that many chi-square(5) samples (a
    strict test: it treats every step as independent), the 95 % confidence interval of the mean
    NEES from the spread of the per-env means (the envs are independent runs; a consistent
    filter's interval holds 5), the fraction of steps inside the per-step
    95 % interval, and the Monte-Carlo test of Bar-Shalom, Li and Kirubarajan (2001, Sec. 5.4):
    the fraction of time indices at which the NEES averaged over the envs (independent runs)
    lies inside the 95 % region of such an average (about 95 % for a consistent filter).
    Also the NIS of the innovations (:func:`_nis_report`; 6 for a consistent filter, or the
    number of readings that arrived with ``sensor_age`` recorded).
    """
    nis_steps: list[torch.Tensor] = []
    with torch.no_grad():
        means, covs, _, _ = run_filter(ekf, data, nis=nis_steps)
    keep = data["step_count"] >= skip
    first_nis = keep.shape[0] - len(nis_steps)
    sensor_age = data.get("sensor_age", None)
    counts = None if sensor_age is None else arrived_readings(sensor_age[first_nis:]).sum(-1)
    nees_tn, per_component = normalized_errors(means, covs, data["true_state"])
    error, nees = state_error(means, data["true_state"]).double()[keep], nees_tn[keep]
    n, dof = nees.numel(), 5
    low_step, high_step = _chi2_quantile(0.025, dof), _chi2_quantile(0.975, dof)
    runs = keep.sum(-1)
    return {
        "samples": n,
        "rmse_position_m": float(error[:, :2].pow(2).sum(-1).mean().sqrt()),
        "rmse_heading_rad": float(error[:, 2].pow(2).mean().sqrt()),
        "rmse_surge_m_s": float(error[:, 3].pow(2).mean().sqrt()),
        "rmse_yaw_rate_rad_s": float(error[:, 4].pow(2).mean().sqrt()),
        "nees_mean": float(nees.mean()),
        "nees_mean_bounds_95": [
            _chi2_quantile(0.025, dof * n) / n,
            _chi2_quantile(0.975, dof * n) / n,
        ],
        "nees_mean_ci95_over_runs": _ci95_over_runs(nees_tn, keep),
        "nees_fraction_in_step_bounds": float(
            ((nees >= low_step) & (nees <= high_step)).double().mean()
        ),
        "nees_step_bounds_95": [low_step, high_step],
        "nees_runs_per_step": float(runs[runs > 0].double().mean()),
        # e_i^2 / P_ii per state component (x, y, heading, surge, yaw rate): 1 when consistent,
        # above 1 where the filter is overconfident
        "normalized_error_per_component": per_component[keep].mean(0).tolist(),
        "nees_fraction_of_steps_in_run_mean_bounds": run_averaged_nees_test(nees_tn, keep, dof),
        **_nis_report(torch.stack(nis_steps).double(), keep[first_nis:], counts),
    }


def _ci95_over_runs(values: torch.Tensor, keep: torch.Tensor) -> list[float]:
    """95 % confidence interval of the mean of ``values`` ``(T, N)`` over the kept entries,
    from the spread of the per-env means: the envs are independent runs, the steps of one run
    are not."""
    counts = keep.sum(0)
    per_run = (torch.where(keep, values, torch.zeros_like(values)).sum(0) / counts)[counts > 0]
    half = 1.96 * float(per_run.std()) / math.sqrt(per_run.numel()) if per_run.numel() > 1 else 0.0
    return [float(per_run.mean()) - half, float(per_run.mean()) + half]


def _nis_report(nis: torch.Tensor, keep: torch.Tensor, dof: torch.Tensor | None = None) -> dict:
    """Consistency of the innovations, the test that needs no ground truth (so it runs on
    logged vehicle data): NIS ``y^T S^-1 y`` is chi-square(6) for a consistent filter. Its
    mean with the 95 % confidence interval over the runs (envs), and the fraction of steps in
    the per-step 95 % interval.

    ``dof`` ``(T, N)``: the number of readings that arrived at each step (sensors at their own
    rates); each step's NIS is then chi-square(``dof``), the steps where none arrived are left
    out, each step is checked against its own interval and ``nis_dof_mean`` is the mean that a
    consistent filter's ``nis_mean`` has."""
    if dof is None:
        low, high = _chi2_quantile(0.025, MEASUREMENT_DIM), _chi2_quantile(0.975, MEASUREMENT_DIM)
        values = nis[keep]
        inside = (values >= low) & (values <= high)
        extra = {"nis_step_bounds_95": [low, high]}
    else:
        keep = keep & (dof > 0)
        values, counts = nis[keep], dof[keep]
        inside = torch.zeros_like(values, dtype=torch.bool)
        for k in counts.unique().tolist():
            low, high = _chi2_quantile(0.025, k), _chi2_quantile(0.975, k)
            inside |= (counts == k) & (values >= low) & (values <= high)
        extra = {"nis_dof_mean": float(counts.double().mean())}
    return {
        "nis_mean": float(values.mean()),
        "nis_mean_ci95_over_runs": _ci95_over_runs(nis, keep),
        "nis_fraction_in_step_bounds": float(inside.double().mean()),
        **extra,
    }
