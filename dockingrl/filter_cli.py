"""``dockingrl learn-filter`` and ``dockingrl filter-ablation``: fit the EKF's ``Q`` and ``R``
and compare learned filters with the hand-tuned one (Tables 1-2)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from dockingrl.arguments import COUNT, NON_NEGATIVE, NON_NEGATIVE_INT, POSITIVE, UsageError, integer
from dockingrl.filter_learning import (
    LEARN_R,
    OBJECTIVES,
    FilterFit,
    evaluate_filter,
    fit_filter,
    mismatched_config,
    record_rollouts,
)
from dockingrl.transforms.filtering import RANGE_NOISE_FROM

HELD_OUT_SEED = 1_000


def _add_fit_arguments(parser: argparse.ArgumentParser) -> None:
    d = FilterFit()
    parser.add_argument("--num-envs", type=COUNT, default=d.num_envs, help="envs per rollout batch")
    parser.add_argument("--steps", type=COUNT, default=d.steps, help="steps recorded per env")
    parser.add_argument("--window", type=integer(2), default=d.window, help="truncated-BPTT window")
    parser.add_argument("--epochs", type=COUNT, default=d.epochs, help="passes over the rollouts")
    parser.add_argument("--lr", type=POSITIVE, default=d.lr, help="Adam learning rate (log-params)")
    parser.add_argument(
        "--behaviour",
        choices=["managed_surge", "random"],
        default=d.behaviour,
        help="behaviour policy of the rollouts",
    )
    parser.add_argument(
        "--seed", type=NON_NEGATIVE_INT, default=d.seed, help="seed of the training rollouts"
    )
    parser.add_argument(
        "--noise-scale",
        type=POSITIVE,
        default=1.0,
        help="env's USBL range and bearing noise x this (the mismatch; the "
        "hand-tuned filter keeps Table 2's R)",
    )
    parser.add_argument("--threads", type=COUNT, default=2, help="torch CPU threads")
    parser.add_argument(
        "--manoeuvre-noise",
        action="store_true",
        help="learn a Q that grows with the gap between commanded and estimated velocity "
        "(not in the paper; see dockingrl.transforms.ProcessNoise)",
    )
    parser.add_argument(
        "--context-noise",
        action="store_true",
        help="learn Q and R scaled by the manoeuvre, the range and the filter's age (not in "
        "the paper; see dockingrl.transforms.NoiseContext); filter-ablation adds such rows, "
        "each starting from the constant fit of its objective",
    )
    parser.add_argument(
        "--whiteness",
        type=NON_NEGATIVE,
        default=d.whiteness,
        help="nll: weight of a penalty on the whitened innovations' correlation between steps "
        "(see dockingrl.filter_learning.innovation_whiteness; 0: none)",
    )
    parser.add_argument(
        "--lags", type=COUNT, default=d.lags, help="lags of the whiteness penalty (1..window-1)"
    )
    parser.add_argument(
        "--range-noise-from",
        choices=list(RANGE_NOISE_FROM),
        default=RANGE_NOISE_FROM[0],
        help="the range that scales the learned filters' range sigma: the measured one "
        "(Table 2 as the paper uses it) or the estimate's, which does not bias the range "
        "short (see dockingrl.transforms.EKFTransform; not in the paper)",
    )
    parser.add_argument(
        "--learn-r",
        choices=list(LEARN_R),
        default=FilterFit().learn_r,
        help="which sigmas of R are fitted: all six, the USBL's range and bearing (the "
        "heading, DVL and IMU keep Table 2's, their data-sheet values) or none",
    )
    parser.add_argument(
        "--context-epochs",
        type=COUNT,
        default=None,
        help="filter-ablation: passes of the context fits, after the constant fit they start "
        "from (default: --epochs)",
    )


def _check_fit_arguments(args: argparse.Namespace) -> None:
    """Refuse, before any rollout, a window the recorded steps cannot fill and whiteness lags
    the window cannot hold."""
    if args.steps <= args.window:
        raise UsageError(f"--steps ({args.steps}) must exceed --window ({args.window})")
    if args.whiteness > 0 and args.lags >= args.window:
        raise UsageError(f"--lags ({args.lags}) must be below --window ({args.window})")


def _fit(
    args,
    objective: str,
    config,
    data,
    log=None,
    manoeuvre: bool | None = None,
    context: bool | None = None,
    init=None,
):
    """Fit a filter; ``init``: a filter whose ``Q`` and ``R`` parameters to start from."""
    from dockingrl.scenarios import make_filter

    if manoeuvre is None:
        manoeuvre = args.manoeuvre_noise
    if context is None:
        context = args.context_noise
    ekf = make_filter(
        config,
        manoeuvre_noise=manoeuvre,
        context_noise=context,
        range_noise_from=args.range_noise_from,
    )
    if init is not None:
        ekf.process_noise.load_state_dict(init.process_noise.state_dict())
        ekf.measurement_noise.load_state_dict(init.measurement_noise.state_dict())
    fit = FilterFit(
        objective=objective,
        num_envs=args.num_envs,
        steps=args.steps,
        window=args.window,
        epochs=args.context_epochs if init is not None and args.context_epochs else args.epochs,
        lr=args.lr,
        behaviour=args.behaviour,
        seed=args.seed,
        whiteness=args.whiteness if objective == "nll" else 0.0,
        lags=args.lags,
        learn_r=args.learn_r,
    )
    history = fit_filter(ekf, fit, data=data, log=log)
    return ekf, history


def cmd_learn_filter(args: argparse.Namespace) -> int:
    from dockingrl.cli import command_line
    from dockingrl.io import write_json
    from dockingrl.scenarios import make_filter
    from dockingrl.training import RunLogger

    _check_fit_arguments(args)
    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    config = mismatched_config(args.noise_scale)
    options = {k: v for k, v in vars(args).items() if k != "func"}
    logger = RunLogger(options, args.logger, out, f"filter-{args.objective}-{int(time.time())}")
    start = time.perf_counter()
    data = record_rollouts(
        args.num_envs, args.steps, config=config, behaviour=args.behaviour, seed=args.seed
    )
    ekf, history = _fit(args, args.objective, config, data, log=logger.log)
    params = out / "filter_params.pt"
    from dockingrl.transforms.params import save_filter_params

    save_filter_params(
        ekf,
        params,
        objective=args.objective,
        range_noise_from=args.range_noise_from,
        learn_r=args.learn_r,
        command=command_line(),
    )
    held_out = record_rollouts(
        args.num_envs, args.steps, config=config, behaviour=args.behaviour, seed=HELD_OUT_SEED
    )
    report = {
        "command": command_line(),
        "objective": args.objective,
        "noise_scale": args.noise_scale,
        "range_noise_from": args.range_noise_from,
        "learn_r": args.learn_r,
        "loss_first_last": [history[0], history[-1]],
        "wall_clock_s": time.perf_counter() - start,
        "held_out_hand_tuned": evaluate_filter(make_filter(config), held_out),
        "held_out_learned": evaluate_filter(ekf, held_out),
        "Q_sigma": ekf.process_noise().diagonal().sqrt().tolist(),
        "R_sigma": ekf.measurement_noise.std().tolist(),
    }
    write_json(out / "eval.json", report)
    logger.finish({"objective": args.objective})
    print(
        f"wrote {params}; held-out position RMSE hand-tuned "
        f"{report['held_out_hand_tuned']['rmse_position_m']:.3f} m -> learned "
        f"{report['held_out_learned']['rmse_position_m']:.3f} m, NEES "
        f"{report['held_out_hand_tuned']['nees_mean']:.1f} -> "
        f"{report['held_out_learned']['nees_mean']:.1f} (5 is consistent)"
    )
    return 0


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


def cmd_filter_ablation(args: argparse.Namespace) -> int:
    from dockingrl.cli import command_line
    from dockingrl.io import atomic_write, write_json
    from dockingrl.scenarios import make_filter
    from dockingrl.transforms.params import save_filter_params

    if args.whiteness:
        raise UsageError("--whiteness applies to learn-filter, not to the ablation table")
    _check_fit_arguments(args)
    torch.set_num_threads(args.threads)
    out = Path(args.out)
    start = time.perf_counter()
    results = {
        "command": command_line(),
        "range_noise_from": args.range_noise_from,
        "learn_r": args.learn_r,
        "conditions": {},
    }
    lines = [
        f"Command: `{command_line()}`",
        "",
        "| condition | filter | position RMSE m | heading RMSE rad | surge RMSE m/s | "
        "yaw-rate RMSE rad/s | mean NEES (5 = consistent) | its 95 % CI over the runs | "
        "steps in 95 % NEES interval | "
        "time steps whose run-averaged NEES is in its 95 % region | "
        "mean NIS (6 = consistent), its 95 % CI over the runs | "
        "e_i^2/P_ii: x / y / heading / surge / yaw rate (1 = consistent) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for condition, scale in (("nominal", 1.0), ("mismatched", args.mismatch)):
        config = mismatched_config(scale)
        data = record_rollouts(
            args.num_envs, args.steps, config=config, behaviour=args.behaviour, seed=args.seed
        )
        held_out = record_rollouts(
            args.num_envs, args.steps, config=config, behaviour=args.behaviour, seed=HELD_OUT_SEED
        )
        filters = {"hand-tuned (Tables 1-2)": make_filter(config)}
        if args.range_noise_from == "estimate":  # the control: Table 2's R, estimated range
            filters["hand-tuned, R from the estimated range"] = make_filter(
                config, range_noise_from="estimate"
            )
        variants = [(objective, "") for objective in OBJECTIVES]
        for flag, kind in ((args.manoeuvre_noise, "manoeuvre"), (args.context_noise, "context")):
            if flag:
                variants += [(objective, kind) for objective in ("nll", "supervised")]
        constant = {}
        for objective, kind in variants:
            ekf, _ = _fit(
                args,
                objective,
                config,
                data,
                manoeuvre=kind == "manoeuvre",
                context=kind == "context",
                init=constant.get(objective) if kind == "context" else None,
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
                range_noise_from=args.range_noise_from,
                learn_r=args.learn_r,
                command=command_line(),
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
        f"Held-out rollouts: {args.num_envs} envs x {args.steps} steps, seed {HELD_OUT_SEED} "
        f"(training rollouts: seed {args.seed}), behaviour `{args.behaviour}`; the first 10 steps "
        f"of each episode are left out. 95 % bounds of the mean NEES over this many samples: "
        f"[{bounds[0]:.2f}, {bounds[1]:.2f}] (they treat the correlated steps of a run as "
        f"independent); the CI column: mean NEES +- 1.96 standard errors of the "
        f"{args.num_envs} per-env means (the envs are independent runs; a consistent filter's "
        f"CI holds 5); per-step 95 % interval of chi-square(5): "
        f"[0.83, 12.83]. Monte-Carlo column: the consistency test of Bar-Shalom, "
        f"Li and Kirubarajan (2001, Sec. 5.4): at each time index the NEES averaged over the "
        f"{args.num_envs} envs against the 95 % region of such an average (a consistent filter "
        f"scores about 0.95). NIS: the normalised innovation squared, chi-square(6) for a "
        f"consistent filter, the one test that needs no ground truth. Last column: the mean "
        f"of e_i^2 / P_ii per state component (above 1: overconfident there). "
        f"Learned filters: the range sigma of R scales with the {args.range_noise_from}'s "
        f"range; R's sigmas fitted: {args.learn_r} ({_LEARN_R_WORDS[args.learn_r]}). "
        f"Wall-clock {results['wall_clock_s']:.0f} s.",
    ]
    write_json(out / "ablation.json", results)
    text = "\n".join(lines) + "\n"
    atomic_write(out / "table.md", lambda tmp: tmp.write_text(text))
    print(text)
    return 0


def add_filter_commands(sub) -> None:
    lf = sub.add_parser(
        "learn-filter", help="fit the EKF's Q and R on rollouts (nll or supervised)"
    )
    lf.add_argument(
        "--objective",
        choices=list(OBJECTIVES),
        default="nll",
        help="nll: innovation likelihood (noisy data only); supervised: likelihood of "
        "the true state under the estimate (simulation only)",
    )
    lf.add_argument("--out", default="runs/filter", help="folder for filter_params.pt, eval.json")
    lf.add_argument(
        "--logger", choices=["wandb", "csv", "none"], default="wandb", help="wandb runs offline"
    )
    _add_fit_arguments(lf)
    lf.set_defaults(func=cmd_learn_filter)

    ab = sub.add_parser(
        "filter-ablation", help="hand-tuned vs learned filters, nominal and mismatched sensor noise"
    )
    ab.add_argument("--out", default="results/filter_ablation", help="results folder")
    ab.add_argument(
        "--mismatch",
        type=POSITIVE,
        default=2.0,
        help="scale of the env's range and bearing noise in the mismatched condition",
    )
    _add_fit_arguments(ab)
    ab.set_defaults(func=cmd_filter_ablation)

    pc = sub.add_parser(
        "ppo-filter-comparison",
        help="PPO compound agents with the hand-tuned and a learned filter, mismatched noise",
    )
    pc.add_argument("--filter-params", required=True, help="learned Q/R file (learn-filter)")
    pc.add_argument("--noise-scale", type=POSITIVE, default=2.0, help="env's range/bearing noise x")
    pc.add_argument("--total-steps", type=COUNT, default=2_000_000, help="env steps per agent")
    pc.add_argument("--out", default="results/filter_ablation", help="results folder")
    pc.add_argument("--runs", default="runs", help="folder of the training runs")
    pc.add_argument(
        "--seeds",
        type=NON_NEGATIVE_INT,
        nargs="+",
        default=[0],
        help="training seeds (one agent each)",
    )
    pc.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="FIELD=VALUE",
        help="more PPO config fields of the fast preset (e.g. num_envs=8)",
    )
    pc.set_defaults(func=cmd_ppo_filter_comparison)


def cmd_ppo_filter_comparison(args: argparse.Namespace) -> int:
    """Train two PPO ``compound`` agents (``fast`` preset) in the mismatched-noise env, one
    reading the hand-tuned filter and one the learned filter, and tabulate their final
    500-episode evaluations (``ppo_mismatch.{json,md}``)."""
    from dockingrl.agents.config import make_config, parse_overrides
    from dockingrl.cli import command_line
    from dockingrl.io import atomic_write, write_json
    from dockingrl.training import train

    if not Path(args.filter_params).is_file():
        raise FileNotFoundError(f"--filter-params {args.filter_params!r}: no such file")
    fixed = {"scenario", "total_steps", "range_noise_scale", "bearing_noise_scale"}
    fixed |= {"filter_params", "out", "run_name", "logger", "seed"}
    try:
        extra = parse_overrides("ppo", args.set)
    except ValueError as exc:
        raise UsageError(f"--set {exc}") from exc
    if fixed & set(extra):
        raise UsageError(
            f"--set cannot change {', '.join(sorted(fixed & set(extra)))}: "
            "the comparison sets it with its own options"
        )
    rows, results = [], {"command": command_line(), "seeds": list(args.seeds), "agents": {}}
    for name, params in (("hand-tuned (Tables 1-2)", ""), ("learned", args.filter_params)):
        label = f"{name}: {params}" if params else name
        runs = {}
        for seed in args.seeds:
            run_name = "ppo_mismatch_" + ("learned" if params else "handtuned") + f"_s{seed}"
            cfg = make_config(
                "ppo",
                "fast",
                scenario="compound",
                total_steps=args.total_steps,
                range_noise_scale=args.noise_scale,
                bearing_noise_scale=args.noise_scale,
                filter_params=params,
                out=args.runs,
                run_name=run_name,
                logger="csv",
                seed=seed,
                **extra,
            )
            result = train(cfg, progress=False, command=command_line())
            final, summary = result["eval"], result["summary"]
            runs[seed] = {
                "success_rate": final["success_rate"],
                "total_reward": final["total_reward"],
                "time_s": final["time_s"],
                "failures": final["failures"],
                "train_wall_clock_s": summary["train_wall_clock_s"],
                "frames": summary["frames"],
                "machine": summary["machine"],
                "run_dir": result["run_dir"],
            }
            f, r = final["failures"], final["total_reward"]
            rows.append(
                f"| {label} | {seed} | {final['success_rate']:.1f} | "
                f"{r['mean']:.1f} +- {r['std']:.1f} | "
                f"{f['timeout']} / {f['missed_funnel']} / {f['too_fast']} | "
                f"{summary['train_wall_clock_s']:.0f} |"
            )
        rates = [run["success_rate"] for run in runs.values()]
        mean = sum(rates) / len(rates)
        results["agents"][label] = {"runs": runs, "success_rate_mean": mean}
        if len(rates) > 1:
            rows.append(f"| {label} | mean of {len(rates)} | **{mean:.1f}** | | | |")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "ppo_mismatch.json", results)
    text = "\n".join(
        [
            f"# PPO compound agents under mismatched sensor noise (range and bearing x"
            f"{args.noise_scale:g})",
            "",
            f"Command: `{command_line()}`",
            "",
            f"Each agent: `--preset fast{''.join(f' --set {x}' for x in args.set)}`, "
            f"{args.total_steps} env steps, trained and evaluated (500 episodes) in the "
            f"mismatched env. Data: `ppo_mismatch.json`. Machine: {summary['machine']}.",
            "",
            "| filter in the compound observation | seed | success % | total reward | "
            "timeouts / missed funnel / too fast | training wall-clock s |",
            "|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )
    atomic_write(out / "ppo_mismatch.md", lambda tmp: tmp.write_text(text))
    print(text)
    return 0
