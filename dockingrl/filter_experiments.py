"""The filter experiments behind ``dockingrl learn-filter``, ``filter-figure`` and
``filter-ablation``: a new filter fitted on recorded rollouts, and Figure 5's episode of raw,
filtered and true observations."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from dockingrl.env import DockingConfig
from dockingrl.filter_learning import (
    OBJECTIVES,
    FilterFit,
    evaluate_filter,
    fit_filter,
    mismatched_config,
    record_rollouts,
)
from dockingrl.io import atomic_write, write_json

#: seed of the held-out rollouts on which learned and hand-tuned filters are compared
HELD_OUT_SEED = 1_000


def training_rollouts(fit: FilterFit, config: DockingConfig):
    """The rollouts a filter is fitted on (seed ``fit.seed``), never the held-out ones."""
    if fit.seed == HELD_OUT_SEED:
        raise ValueError(
            f"seed {HELD_OUT_SEED} draws the held-out rollouts the filter is scored on; "
            "train on another seed"
        )
    return record_rollouts(
        fit.num_envs, fit.steps, config=config, behaviour=fit.behaviour, seed=fit.seed
    )


def held_out_rollouts(fit: FilterFit, config: DockingConfig):
    """The rollouts a fitted filter is scored on (seed :data:`HELD_OUT_SEED`)."""
    return record_rollouts(
        fit.num_envs, fit.steps, config=config, behaviour=fit.behaviour, seed=HELD_OUT_SEED
    )


def fit_new_filter(
    config,
    data,
    fit: FilterFit,
    *,
    manoeuvre_noise: bool = False,
    context_noise: bool = False,
    range_noise_from: str = "measurement",
    compensate_latency: bool = False,
    init=None,
    log=None,
):
    """A filter matched to the env config ``config`` fitted on the rollouts ``data`` as
    ``fit`` says; ``init``: a filter whose ``Q`` and ``R`` parameters to start from;
    ``compensate_latency``: it compensates ``config``'s USBL latency. Returns ``(filter, loss
    history)``."""
    from dockingrl.scenarios import make_filter

    ekf = make_filter(
        config,
        manoeuvre_noise=manoeuvre_noise,
        context_noise=context_noise,
        range_noise_from=range_noise_from,
        compensate_latency=compensate_latency,
    )
    if init is not None:
        ekf.process_noise.load_state_dict(init.process_noise.state_dict())
        ekf.measurement_noise.load_state_dict(init.measurement_noise.state_dict())
    history = fit_filter(ekf, fit, data=data, log=log)
    return ekf, history


def learn_filter(
    fit: FilterFit,
    out: str | Path,
    *,
    noise_scale: float = 1.0,
    level: str = "L0",
    manoeuvre_noise: bool = False,
    context_noise: bool = False,
    range_noise_from: str = "measurement",
    compensate_latency: bool = False,
    log=None,
    command: str = "",
) -> dict:
    """A filter fitted as ``fit`` says on rollouts of the env whose USBL noise is
    ``noise_scale`` times Table 2's, in the world of stress level ``level`` (its sensors'
    rates, delays, dropouts and outliers: the filter updates each entry when its reading
    arrives), saved as ``out/filter_params.pt`` and scored with the hand-tuned one on held-out
    rollouts (``out/eval.json``, returned). With ``compensate_latency`` both filters
    compensate the level's USBL latency."""
    from dockingrl.env.levels import level_config
    from dockingrl.scenarios import make_filter
    from dockingrl.transforms.params import save_filter_params

    out = Path(out)
    config = level_config(level, mismatched_config(noise_scale))
    start = time.perf_counter()
    data = training_rollouts(fit, config)
    ekf, history = fit_new_filter(
        config,
        data,
        fit,
        manoeuvre_noise=manoeuvre_noise,
        context_noise=context_noise,
        range_noise_from=range_noise_from,
        compensate_latency=compensate_latency,
        log=log,
    )
    params = out / "filter_params.pt"
    save_filter_params(
        ekf,
        params,
        objective=fit.objective,
        range_noise_from=range_noise_from,
        learn_r=fit.learn_r,
        compensate_latency=compensate_latency,
        command=command,
    )
    held_out = held_out_rollouts(fit, config)
    report = {
        "command": command,
        "objective": fit.objective,
        "noise_scale": noise_scale,
        "level": level,
        "range_noise_from": range_noise_from,
        "compensate_latency": compensate_latency,
        "learn_r": fit.learn_r,
        "loss_first_last": [history[0], history[-1]],
        "wall_clock_s": time.perf_counter() - start,
        "held_out_hand_tuned": evaluate_filter(
            make_filter(config, compensate_latency=compensate_latency), held_out
        ),
        "held_out_learned": evaluate_filter(ekf, held_out),
        "Q_sigma": ekf.process_noise().diagonal().sqrt().tolist(),
        "R_sigma": ekf.measurement_noise.std().tolist(),
    }
    write_json(out / "eval.json", report)
    return report


def filter_episode(start, current, seed: int = 0, steps: int = 600) -> dict:
    """One episode of the managed surge controller (on the EKF estimate) in the compound
    scenario from pose ``start`` in the current ``current`` (Figure 5): its ``seconds`` and the
    ``raw``, ``filtered`` and ``true`` observations (arrays), and the RMSE of rho, psi and
    alpha of the raw and filtered ones (``rmse_raw``, ``rmse_filtered``)."""
    from dockingrl.agents import ManagedSurgePolicy
    from dockingrl.env import observation_from_state
    from dockingrl.evaluation import base_env
    from dockingrl.scenarios import make_env

    env = make_env("compound", 1, seed=seed)
    base_env(env).set_initial_state(pose=torch.tensor(start), ocean_current=torch.tensor(current))
    policy = ManagedSurgePolicy(use_filter=True)
    with torch.no_grad():
        td = env.rollout(steps, policy)
    nxt = td["next"][0]
    x, y, alpha, u, v, r = nxt["true_state"].unbind(-1)
    true = observation_from_state(x, y, alpha, u, v, r, nxt["ocean_current"]).numpy()
    raw = nxt["observation"][:, :6].numpy()
    filtered = nxt["filtered_observation"].numpy()
    seconds = nxt["step_count"].squeeze(-1).numpy() * base_env(env).config.dt

    def rmse(a):
        e = a - true
        e[:, 1:3] = (e[:, 1:3] + np.pi) % (2 * np.pi) - np.pi
        values = np.sqrt((e**2).mean(0))[:3].tolist()
        return dict(zip(["rho", "psi", "alpha"], values, strict=True))

    return {
        "seconds": seconds,
        "raw": raw,
        "filtered": filtered,
        "true": true,
        "rmse_raw": rmse(raw),
        "rmse_filtered": rmse(filtered),
    }


ROWS = (
    "rmse_position_m",
    "rmse_heading_rad",
    "rmse_surge_m_s",
    "rmse_yaw_rate_rad_s",
    "nees_mean",
    "nees_fraction_in_step_bounds",
    "nees_fraction_of_steps_in_run_mean_bounds",
)


_LEARN_R_WORDS = {
    "all": "all six",
    "usbl": "range and bearing; heading, DVL and IMU keep Table 2's",
    "none": "none, Table 2's",
}


def filter_ablation(
    fit: FilterFit,
    out: str | Path,
    *,
    mismatch: float = 2.0,
    manoeuvre_noise: bool = False,
    context_noise: bool = False,
    range_noise_from: str = "measurement",
    context_epochs: int | None = None,
    command: str = "",
) -> str:
    """The filter ablation: in the nominal env and one whose USBL noise is ``mismatch`` times
    larger, the hand-tuned filter (Tables 1-2) against filters fitted as ``fit`` says (each
    objective; with ``manoeuvre_noise`` / ``context_noise`` also those noise models, a
    context fit starting from its objective's constant one, for ``context_epochs`` passes),
    scored on held-out rollouts. Writes each learned filter, ``ablation.json`` and
    ``table.md`` to ``out``; returns the table's text."""
    from dockingrl.scenarios import make_filter
    from dockingrl.transforms.params import save_filter_params

    out = Path(out)
    start = time.perf_counter()
    results = {
        "command": command,
        "range_noise_from": range_noise_from,
        "learn_r": fit.learn_r,
        "conditions": {},
    }
    lines = [
        f"Command: `{command}`",
        "",
        "| condition | filter | position RMSE m | heading RMSE rad | surge RMSE m/s | "
        "yaw-rate RMSE rad/s | mean NEES (5 = consistent) | its 95 % CI over the runs | "
        "steps in 95 % NEES interval | "
        "time steps whose run-averaged NEES is in its 95 % region | "
        "mean NIS (6 = consistent), its 95 % CI over the runs | "
        "e_i^2/P_ii: x / y / heading / surge / yaw rate (1 = consistent) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for condition, scale in (("nominal", 1.0), ("mismatched", mismatch)):
        config = mismatched_config(scale)
        data = training_rollouts(fit, config)
        held_out = held_out_rollouts(fit, config)
        filters = {"hand-tuned (Tables 1-2)": make_filter(config)}
        if range_noise_from == "estimate":  # the control: Table 2's R, estimated range
            filters["hand-tuned, R from the estimated range"] = make_filter(
                config, range_noise_from="estimate"
            )
        variants = [(objective, "") for objective in OBJECTIVES]
        for flag, kind in ((manoeuvre_noise, "manoeuvre"), (context_noise, "context")):
            if flag:
                variants += [(objective, kind) for objective in ("nll", "supervised")]
        constant = {}
        for objective, kind in variants:
            init = constant.get(objective) if kind == "context" else None
            this_fit = replace(
                fit,
                objective=objective,
                epochs=context_epochs if init is not None and context_epochs else fit.epochs,
                whiteness=fit.whiteness if objective == "nll" else 0.0,
            )
            ekf, _ = fit_new_filter(
                config,
                data,
                this_fit,
                manoeuvre_noise=kind == "manoeuvre",
                context_noise=kind == "context",
                range_noise_from=range_noise_from,
                init=init,
            )
            if not kind:
                constant[objective] = ekf
            save_filter_params(
                ekf,
                out / f"{condition}_{objective}{'_' + kind if kind else ''}.pt",
                objective=objective,
                condition=condition,
                manoeuvre_noise=kind == "manoeuvre",
                context_noise=kind == "context",
                range_noise_from=range_noise_from,
                learn_r=fit.learn_r,
                command=command,
            )
            label = (
                f"learned, {objective}"
                + {
                    "": "",
                    "manoeuvre": ", manoeuvre Q",
                    "context": ", context Q and R",
                }[kind]
            )
            filters[label] = ekf
        rows = {}
        for name, ekf in filters.items():
            rows[name] = evaluate_filter(ekf, held_out)
            r = rows[name]
            lines.append(
                f"| {condition} (x{scale:g} range/bearing noise) | {name} | "
                + " | ".join(
                    f"{r[k]:.2f} | {r['nees_mean_ci95_over_runs'][0]:.2f}-"
                    f"{r['nees_mean_ci95_over_runs'][1]:.2f}"
                    if k == "nees_mean"
                    else f"{r[k]:.4f}"
                    for k in ROWS
                )
                + f" | {r['nis_mean']:.2f}, {r['nis_mean_ci95_over_runs'][0]:.2f}-"
                f"{r['nis_mean_ci95_over_runs'][1]:.2f} | "
                + " / ".join(f"{v:.2f}" for v in r["normalized_error_per_component"])
                + " |"
            )
        results["conditions"][condition] = {"noise_scale": scale, "filters": rows}
    results["wall_clock_s"] = time.perf_counter() - start
    bounds = rows[next(iter(rows))]["nees_mean_bounds_95"]
    lines += [
        "",
        f"Held-out rollouts: {fit.num_envs} envs x {fit.steps} steps, seed {HELD_OUT_SEED} "
        f"(training rollouts: seed {fit.seed}), behaviour `{fit.behaviour}`; the first 10 steps "
        f"of each episode are left out. 95 % bounds of the mean NEES over this many samples: "
        f"[{bounds[0]:.2f}, {bounds[1]:.2f}] (they treat the correlated steps of a run as "
        f"independent); the CI column: mean NEES +- 1.96 standard errors of the "
        f"{fit.num_envs} per-env means (the envs are independent runs; a consistent filter's "
        f"CI holds 5); per-step 95 % interval of chi-square(5): "
        f"[0.83, 12.83]. Monte-Carlo column: the consistency test of Bar-Shalom, "
        f"Li and Kirubarajan (2001, Sec. 5.4): at each time index the NEES averaged over the "
        f"{fit.num_envs} envs against the 95 % region of such an average (a consistent filter "
        f"scores about 0.95). NIS: the normalised innovation squared, chi-square(6) for a "
        f"consistent filter, the one test that needs no ground truth. Last column: the mean "
        f"of e_i^2 / P_ii per state component (above 1: overconfident there). "
        f"Learned filters: the range sigma of R scales with the {range_noise_from}'s "
        f"range; R's sigmas fitted: {fit.learn_r} ({_LEARN_R_WORDS[fit.learn_r]}). "
        f"Wall-clock {results['wall_clock_s']:.0f} s.",
    ]
    write_json(out / "ablation.json", results)
    text = "\n".join(lines) + "\n"
    atomic_write(out / "table.md", lambda tmp: tmp.write_text(text))
    return text
