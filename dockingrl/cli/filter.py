"""``dockingrl learn-filter``, ``filter-ablation`` and ``filter-figure``: fit the EKF's ``Q`` and
``R``, compare learned filters with the hand-tuned one (Tables 1-2) and draw Figure 5; the
command-line front of :mod:`dockingrl.filter_learning` and :mod:`dockingrl.filter_experiments`."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING

from dockingrl.cli.arguments import (
    COUNT,
    FINITE,
    NON_NEGATIVE,
    POSITIVE,
    SEED,
    UsageError,
    integer,
    output_folder,
    results_folder,
)
from dockingrl.env.levels import LEVELS
from dockingrl.provenance import command_line, footer_text

if TYPE_CHECKING:
    from dockingrl.filter_learning import FilterFit

#: the ranges that may scale a learned filter's range sigma (the values of
#: ``dockingrl.transforms.noise.RANGE_NOISE_FROM``, a test checks: named here without torch)
RANGE_NOISE_FROM = ("measurement", "estimate")


def _add_fit_arguments(parser: argparse.ArgumentParser) -> None:
    from dockingrl.filter_learning.options import LEARN_R, FilterFit

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
    parser.add_argument("--seed", type=SEED, default=d.seed, help="seed of the training rollouts")
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
        "--lags",
        type=COUNT,
        default=None,
        help=f"lags of the whiteness penalty (1..window-1; default {d.lags})",
    )
    parser.add_argument(
        "--range-noise-from",
        choices=RANGE_NOISE_FROM,
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


def _check_fit_arguments(args: argparse.Namespace) -> None:
    """Refuse, before any rollout, a window the recorded steps cannot fill, whiteness lags
    the window cannot hold and training rollouts that would be the held-out ones."""
    if args.steps <= args.window:
        raise UsageError(f"--steps ({args.steps}) must exceed --window ({args.window})")
    if args.lags is not None and not args.whiteness:
        raise UsageError("--lags applies to a --whiteness penalty only")
    lags = _fit_options(args, "nll").lags
    if args.whiteness > 0 and lags >= args.window:
        raise UsageError(f"--lags ({lags}) must be below --window ({args.window})")
    from dockingrl.filter_experiments import HELD_OUT_SEED

    if args.seed == HELD_OUT_SEED:
        raise UsageError(f"--seed {HELD_OUT_SEED} draws the held-out rollouts; train on another")


def _fit_options(args: argparse.Namespace, objective: str) -> FilterFit:
    """The fit options of the command line, for ``objective``."""
    from dockingrl.filter_learning import FilterFit

    return FilterFit(
        objective=objective,
        num_envs=args.num_envs,
        steps=args.steps,
        window=args.window,
        epochs=args.epochs,
        lr=args.lr,
        behaviour=args.behaviour,
        seed=args.seed,
        whiteness=args.whiteness if objective == "nll" else 0.0,
        lags=FilterFit().lags if args.lags is None else args.lags,
        learn_r=args.learn_r,
    )


def _noise_models(args: argparse.Namespace) -> dict:
    """The noise models of the learned filters the command line asks for: ``manoeuvre_noise``,
    ``context_noise`` and ``range_noise_from``."""
    return {
        "manoeuvre_noise": args.manoeuvre_noise,
        "context_noise": args.context_noise,
        "range_noise_from": args.range_noise_from,
    }


def cmd_learn_filter(args: argparse.Namespace) -> int:
    """``dockingrl learn-filter``: one filter fitted and scored on held-out rollouts."""
    from dockingrl.filter_experiments import learn_filter
    from dockingrl.training import RunLogger

    if args.whiteness and args.objective != "nll":
        raise UsageError(
            f"--whiteness penalises the innovations of the nll objective, not {args.objective!r}"
        )
    _check_fit_arguments(args)
    import torch

    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    options = {k: v for k, v in vars(args).items() if k != "func"}
    logger = RunLogger(options, args.logger, out, f"filter-{args.objective}-{int(time.time())}")
    report = learn_filter(
        _fit_options(args, args.objective),
        out,
        noise_scale=args.noise_scale,
        level=args.level,
        compensate_latency=args.compensate_latency,
        log=logger.log,
        **_noise_models(args),
        command=command_line(),
    )
    logger.finish({"objective": args.objective})
    print(
        f"wrote {out / 'filter_params.pt'}; held-out position RMSE hand-tuned "
        f"{report['held_out_hand_tuned']['rmse_position_m']:.3f} m -> learned "
        f"{report['held_out_learned']['rmse_position_m']:.3f} m, NEES "
        f"{report['held_out_hand_tuned']['nees_mean']:.1f} -> "
        f"{report['held_out_learned']['nees_mean']:.1f} (5 is consistent)"
    )
    return 0


def cmd_filter_ablation(args: argparse.Namespace) -> int:
    """``dockingrl filter-ablation``: hand-tuned against learned filters, nominal and
    mismatched sensor noise."""
    from dockingrl.filter_experiments import filter_ablation

    if args.whiteness:
        raise UsageError("--whiteness applies to learn-filter, not to the ablation table")
    if args.context_epochs is not None and not args.context_noise:
        raise UsageError("--context-epochs applies to the --context-noise rows only")
    _check_fit_arguments(args)
    import torch

    torch.set_num_threads(args.threads)
    text = filter_ablation(
        _fit_options(args, "nll"),
        args.out,
        mismatch=args.mismatch,
        context_epochs=args.context_epochs,
        command=command_line(),
        **_noise_models(args),
    )
    print(text)
    return 0


def _check_figure_start(start: list[float], current: list[float]) -> None:
    """Refuse a start the AUV cannot reach the DS from in one episode (farther than its top
    speed covers before truncation) and a current it cannot make headway against (a
    component above its top speed)."""
    from dockingrl.env import DockingConfig

    c = DockingConfig()
    reach = c.max_velocity * c.dt * c.max_steps
    x, y, _ = start
    if math.hypot(x, y) > reach:
        raise UsageError(
            f"--start ({x:g}, {y:g}) lies more than {reach:g} m from the DS, farther than "
            "the AUV travels in one episode"
        )
    if max(abs(v) for v in current) > c.max_velocity:
        raise UsageError(
            f"--current components must be within +-{c.max_velocity:g} m/s (the AUV's top "
            f"speed), got {current[0]:g} {current[1]:g}"
        )


def cmd_filter_figure(args: argparse.Namespace) -> int:
    """One episode of the managed surge controller (on the EKF estimate) in the compound
    scenario: raw, filtered and true rho, psi, alpha (Figure 5)."""
    from dockingrl.filter_experiments import filter_episode
    from dockingrl.io import write_json
    from dockingrl.plots import plot_filter_episode

    _check_figure_start(args.start, args.current)
    episode = filter_episode(args.start, args.current, seed=args.seed)
    seconds = episode["seconds"]
    out = Path(args.out)
    plot_filter_episode(
        seconds,
        episode["raw"],
        episode["filtered"],
        episode["true"],
        out / "filter_episode.png",
        footer=footer_text(),
    )
    write_json(
        out / "filter_episode.json",
        {
            "command": command_line(),
            "start": args.start,
            "ocean_current": args.current,
            "steps": len(seconds),
            "rmse_raw": episode["rmse_raw"],
            "rmse_filtered": episode["rmse_filtered"],
        },
    )
    print(f"wrote {out}/filter_episode.png ({len(seconds)} steps)")
    return 0


def add_filter_commands(sub) -> None:
    """Register the filter subcommands on the CLI's subparsers ``sub``."""
    from dockingrl.filter_learning.options import OBJECTIVES

    ff = sub.add_parser("filter-figure", help="raw vs filtered vs true observation (Figure 5)")
    ff.add_argument("--out", type=output_folder, default="results/filter", help="results folder")
    ff.add_argument("--seed", type=SEED, default=0)
    ff.add_argument(
        "--start", type=FINITE, nargs=3, default=[-28.0, 5.0, 0.3], metavar=("X", "Y", "ALPHA")
    )
    ff.add_argument(
        "--current", type=FINITE, nargs=2, default=[0.1, -0.1], metavar=("OC_X", "OC_Y")
    )
    ff.set_defaults(func=cmd_filter_figure)

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
    lf.add_argument(
        "--out",
        type=results_folder,
        default="runs/filter",
        help="folder for filter_params.pt, eval.json",
    )
    lf.add_argument(
        "--level",
        choices=list(LEVELS),
        default="L0",
        help="stress level whose world the rollouts come from (L1, L4, L5: slow, late, lost "
        "and outlying fixes; docs/realism.md)",
    )
    lf.add_argument(
        "--compensate-latency",
        action="store_true",
        help="the filter compensates the level's USBL latency (L1, L4, L5: 0.6 s)",
    )
    lf.add_argument(
        "--logger", choices=["wandb", "csv", "none"], default="wandb", help="wandb runs offline"
    )
    _add_fit_arguments(lf)
    lf.set_defaults(func=cmd_learn_filter)

    ab = sub.add_parser(
        "filter-ablation", help="hand-tuned vs learned filters, nominal and mismatched sensor noise"
    )
    ab.add_argument(
        "--out", type=output_folder, default="results/filter_ablation", help="results folder"
    )
    ab.add_argument(
        "--mismatch",
        type=POSITIVE,
        default=2.0,
        help="scale of the env's range and bearing noise in the mismatched condition",
    )
    _add_fit_arguments(ab)
    ab.add_argument(
        "--context-epochs",
        type=COUNT,
        default=None,
        help="passes of the context fits, after the constant fit they start from "
        "(default: --epochs)",
    )
    ab.set_defaults(func=cmd_filter_ablation)
