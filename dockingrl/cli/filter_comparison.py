"""``dockingrl ppo-filter-comparison``: PPO ``compound`` agents trained with the hand-tuned and a
learned filter under mismatched sensor noise; the command-line front of
:mod:`dockingrl.filter_comparison`."""

from __future__ import annotations

import argparse

from dockingrl.cli.arguments import (
    COUNT,
    POSITIVE,
    SEED,
    UsageError,
    existing_file,
    output_folder,
)
from dockingrl.provenance import command_line


def add_filter_comparison_command(sub) -> None:
    """Register ``ppo-filter-comparison`` on the CLI's subparsers ``sub``."""
    pc = sub.add_parser(
        "ppo-filter-comparison",
        help="PPO compound agents with the hand-tuned and a learned filter, mismatched noise",
    )
    pc.add_argument(
        "--filter-params", type=existing_file, required=True, help="learned Q/R file (learn-filter)"
    )
    pc.add_argument("--noise-scale", type=POSITIVE, default=2.0, help="env's range/bearing noise x")
    pc.add_argument("--total-steps", type=COUNT, default=2_000_000, help="env steps per agent")
    pc.add_argument(
        "--out", type=output_folder, default="results/filter_ablation", help="results folder"
    )
    pc.add_argument("--runs", default="runs", help="folder of the training runs")
    pc.add_argument(
        "--seeds",
        type=SEED,
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
    from dockingrl.agents.config import parse_overrides
    from dockingrl.filter_comparison import ppo_filter_comparison

    if len(set(args.seeds)) < len(args.seeds):
        raise UsageError(f"--seeds {' '.join(map(str, args.seeds))}: a seed is named twice")
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
    text = ppo_filter_comparison(
        args.filter_params,
        args.out,
        noise_scale=args.noise_scale,
        total_steps=args.total_steps,
        runs_dir=args.runs,
        seeds=args.seeds,
        extra=extra,
        overrides=args.set,
        command=command_line(),
    )
    print(text)
    return 0
