"""Learning the EKF's noise covariances ``Q`` and ``R`` by gradient descent, and measuring a
filter setting (RMSE against the truth, NEES consistency).

The paper tuned ``Q`` by hand (Table 1) and took ``R`` from the simulator (Table 2); on a real
vehicle neither is known. Two objectives:

- ``nll``: the negative log-likelihood of the innovations, ``0.5 (y^T S^-1 y + log det S)``,
  which needs the noisy observations only (it could run on logged vehicle data);
- ``supervised``: the negative log-likelihood of ``true_state`` under the filter's Gaussian
  estimate, ``0.5 (e^T P^-1 e + log det P)`` with ``e`` the estimate's error (simulation only).
  It rewards a small error and a covariance ``P`` that states it honestly: at its optimum the
  mean NEES of the training data is the state dimension, 5.
- ``mse``: the estimate's squared error against ``true_state`` alone,
  ``sum_i log mean(e_i^2)`` over the five state components (simulation only). The log makes it
  free of units (metres, radians, m/s, rad/s) and weighs a relative gain in each component
  alike; it asks nothing of ``P``.

Both run the differentiable filter of :mod:`dockingrl.transforms.ekf` over recorded rollouts with
truncated backpropagation through time (windows of ``window`` steps).

On an env whose sensors report at their own rates (``sensor_age`` recorded, docs/realism.md)
the filter updates with the readings that arrived only, as the env's :class:`EKFTransform`
does, and the innovation objectives and metrics (NLL, NIS, whiteness) count those readings
only: a held reading is not a new measurement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from dockingrl.env import DockingConfig, DockingEnv
from dockingrl.env.dynamics import wrap_angle
from dockingrl.transforms.ekf import (
    MEASUREMENT_DIM,
    ekf_predict,
    ekf_update,
    innovation,
    innovation_covariance,
    measurement_jacobian,
)
from dockingrl.transforms.filtering import CONTEXT_FEATURES, EKFTransform, arrived_readings

OBJECTIVES = ("nll", "supervised", "mse")
#: Which of ``R``'s six sigmas a fit learns; the others keep their values (Table 2 unless
#: loaded): ``usbl`` learns the range and bearing sigmas only, the sensor whose noise depends on
#: the acoustic conditions, and keeps the heading, DVL and IMU sigmas of their data sheets.
LEARN_R = {"all": tuple(range(MEASUREMENT_DIM)), "usbl": (0, 1), "none": ()}


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


def mismatched_config(scale: float = 2.0, config: DockingConfig | None = None) -> DockingConfig:
    """The env with its USBL range and bearing noise scaled by ``scale`` (the filter keeps
    Table 2's ``R``): the mismatched condition of the ablation."""
    config = config or DockingConfig()
    return config.replace(
        range_noise_fraction=config.range_noise_fraction * scale,
        bearing_noise=config.bearing_noise * scale,
    )


def behaviour_policy(name: str):
    """``managed_surge`` (the baseline on the noisy pose) or ``random`` (uniform actions)."""
    if name == "managed_surge":
        from dockingrl.agents.managed_surge import ManagedSurgePolicy

        return ManagedSurgePolicy()
    if name == "random":
        return None
    raise ValueError(f"unknown behaviour policy {name!r}; valid: managed_surge, random")


def record_rollouts(
    num_envs: int,
    steps: int,
    *,
    config: DockingConfig | None = None,
    behaviour: str = "managed_surge",
    seed: int = 0,
) -> TensorDict:
    """Record ``steps`` steps of ``num_envs`` noisy envs (auto-reset) under a behaviour policy.

    Returns a ``(steps, num_envs)`` tensordict of what each step saw: ``observation`` (the raw
    measurement at that step), ``action`` (applied after it, clipped), ``ocean_current``,
    ``true_state`` and ``step_count`` (0 marks the first observation of an episode); and
    ``sensor_age`` ``(steps, num_envs, 3)`` when the env reports it (a sensor option is on).
    """
    config = (config or DockingConfig()).replace(noise=True)
    env = DockingEnv(num_envs, config=config, seed=seed)
    policy = behaviour_policy(behaviour)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        data = env.rollout(steps, policy, break_when_any_done=False)
    low = torch.tensor(config.action_low)
    high = torch.tensor(config.action_high)
    action = torch.maximum(torch.minimum(data["action"], high), low)
    out = TensorDict(
        {
            "observation": data["observation"],
            "action": action,
            "ocean_current": data["ocean_current"],
            "true_state": data["true_state"],
            "step_count": data["step_count"].squeeze(-1),
        },
        batch_size=data.batch_size,
    )
    if "sensor_age" in data.keys():
        out["sensor_age"] = data["sensor_age"]
    return out.transpose(0, 1).contiguous()  # time first


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
    :class:`EKFTransform` does in the env); ``ekf.gate`` rejects outliers as there.

    Args:
        state: ``(mean, cov, action)`` after the step before ``data[0]`` (truncated BPTT
            carries it, detached); ``None`` initialises from ``data[0]``.
        objective: if given, also return the mean loss per step and env.
        nis: if a list, the normalised innovation squared ``y^T S^-1 y`` of each step ``(N,)``
            is appended to it (for the first step of an episode: NaN, no prediction), over
            the readings that arrived (NaN where none did).
        whiteness: with ``objective="nll"``, add this weight times
            :func:`innovation_whiteness` of the window's innovations over ``lags`` lags.

    The ``nll`` objective is the mean over steps and envs of the innovations' negative
    log-likelihood, each step's over the readings that arrived at it (0 where none did).

    Returns:
        ``(means, covs, (mean, cov), loss)``: the estimates after each step ``(T, N, 5)``,
        ``(T, N, 5, 5)``, the final state and the loss (``None`` without an objective).
    """
    if objective is not None and objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; valid: {', '.join(OBJECTIVES)}")
    z, action = data["observation"], data["action"]
    current, fresh = data["ocean_current"], data["step_count"] == 0
    sensor_age = data.get("sensor_age", None)
    means, covs, losses, whites, valids, arrivals = [], [], [], [], [], []
    if state is None:
        mean, cov = ekf.initial_estimate(z[0], current[0])
        previous_action, start = action[0], 1
        means.append(mean)
        covs.append(cov)
    else:
        (mean, cov, previous_action), start = state, 0
    for t in range(start, z.shape[0]):
        applied = ekf._applied_action(previous_action)
        # the filter's age before this update: the steps since its episode's first fix
        Q, R = ekf.noise_covariances(mean, applied, z[t], data["step_count"][t] - 1)
        prior_mean, prior_cov = ekf_predict(
            mean, cov, applied, current[t], Q, dt, k_v=ekf.k_v, k_w=ekf.k_w
        )
        previous_action = action[t]
        arrived = None if sensor_age is None else arrived_readings(sensor_age[t])
        if objective == "nll" or nis is not None:
            H = measurement_jacobian(prior_mean, current[t])
            S = innovation_covariance(prior_cov, H, torch.diag_embed(R))
            w, L = whiten(*masked_innovation(innovation(prior_mean, z[t], current[t]), S, arrived))
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
        )
        mean, cov = ekf.start_where(fresh[t], new_mean, new_cov, z[t], current[t])
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
    return torch.stack(means), torch.stack(covs), (mean, cov, previous_action), loss


@dataclass
class FilterFit:
    """Options of :func:`fit_filter`."""

    objective: str = "nll"
    num_envs: int = 128
    steps: int = 600
    window: int = 50
    epochs: int = 4
    lr: float = 0.03
    behaviour: str = "managed_surge"
    seed: int = 0
    whiteness: float = 0.0  # nll only: weight of the innovations' whiteness penalty
    lags: int = 5
    learn_r: str = "all"  # which of R's sigmas are fitted (LEARN_R)


def fit_filter(
    ekf: EKFTransform,
    fit: FilterFit,
    *,
    config: DockingConfig | None = None,
    data: TensorDict | None = None,
    log=None,
) -> list[float]:
    """Fit ``ekf``'s ``Q`` and ``R`` on rollouts of ``config`` by truncated BPTT; returns the
    loss per window. ``log(metrics, step)`` receives ``losses/...`` scalars."""
    if fit.objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {fit.objective!r}; valid: {', '.join(OBJECTIVES)}")
    if fit.window < 2 or fit.epochs < 1 or fit.num_envs < 1 or fit.steps <= fit.window:
        raise ValueError("need window >= 2, epochs >= 1, num_envs >= 1 and steps > window")
    if fit.whiteness < 0 or (fit.whiteness > 0 and fit.objective != "nll"):
        raise ValueError("whiteness is a non-negative weight of the nll objective only")
    if fit.learn_r not in LEARN_R:
        raise ValueError(f"unknown learn_r {fit.learn_r!r}; valid: {', '.join(LEARN_R)}")
    if fit.whiteness > 0 and not 1 <= fit.lags < fit.window:
        raise ValueError(f"need 1 <= lags < window, got lags={fit.lags}, window={fit.window}")
    if data is None:
        data = record_rollouts(
            fit.num_envs, fit.steps, config=config, behaviour=fit.behaviour, seed=fit.seed
        )
    ekf.set_learnable(True)
    optim = torch.optim.Adam(ekf.noise_parameters(), lr=fit.lr)
    frozen = torch.ones(MEASUREMENT_DIM, dtype=torch.bool)
    frozen[list(LEARN_R[fit.learn_r])] = False
    history = []
    for epoch in range(fit.epochs):
        state = None
        for start in range(0, data.shape[0], fit.window):
            window = data[start : start + fit.window]
            _, _, state, loss = run_filter(
                ekf,
                window,
                state=state,
                objective=fit.objective,
                whiteness=fit.whiteness,
                lags=fit.lags,
            )
            optim.zero_grad(set_to_none=True)
            loss.backward()
            _freeze_measurement_noise(ekf, frozen)
            optim.step()
            state = tuple(x.detach() for x in state)
            history.append(float(loss.detach()))
            if log is not None:
                log({f"losses/{fit.objective}": history[-1], "train/epoch": epoch}, len(history))
    ekf.set_learnable(False)
    return history


def _freeze_measurement_noise(ekf: EKFTransform, frozen: torch.Tensor) -> None:
    """Zero the gradients of ``R``'s ``frozen`` entries (its sigma and, with a context model,
    its context weights): Adam then leaves them where they are."""
    if not bool(frozen.any()):
        return
    grads = [(ekf.measurement_noise.log_std.grad, frozen)]
    if ekf.noise_context is not None:
        grads.append((ekf.noise_context.r_weight.grad, frozen.expand(len(CONTEXT_FEATURES), -1)))
    for grad, mask in grads:
        if grad is not None:
            grad[mask.to(grad.device)] = 0.0


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
