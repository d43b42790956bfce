"""``dockingrl stress``: the command-line front of :mod:`dockingrl.stress`."""

from __future__ import annotations

import argparse
import time

from dockingrl.cli.arguments import (
    COUNT,
    EPISODES,
    POSITIVE,
    SEED,
    UsageError,
    output_folder,
    policy_from_args,
    torch_device,
)
from dockingrl.env.config import DockingConfig
from dockingrl.env.levels import LEVELS
from dockingrl.env.realism_options import VEHICLES
from dockingrl.provenance import command_line


def cmd_stress(args: argparse.Namespace) -> int:
    """``dockingrl stress``: a policy on the stress ladder's levels."""
    from dockingrl.evaluation import describe_machine
    from dockingrl.policies import trained_filter_options
    from dockingrl.stress import stress_ladder, stress_table, write_stress

    policy, name, scenario, options, trained = policy_from_args(args)
    if trained:
        options = trained_filter_options(trained, scenario, options)
    levels = tuple(args.levels.split(",")) if args.levels is not None else tuple(LEVELS)
    unknown = [level for level in levels if level not in LEVELS]
    if unknown:
        raise UsageError(
            f"--levels {args.levels}: unknown level {unknown[0]!r}; valid: {', '.join(LEVELS)}"
        )
    if len(set(levels)) < len(levels):
        raise UsageError(f"--levels {args.levels}: a level is named twice")
    start = time.perf_counter()
    result = stress_ladder(
        policy,
        scenario,
        episodes=args.episodes,
        levels=levels,
        seed=args.seed,
        gate=args.gate,
        compensate_latency=args.compensate_latency,
        estimate_current=args.estimate_current,
        device=args.device,
        base=DockingConfig(vehicle=args.vehicle),
        **options,
    )
    wall = time.perf_counter() - start
    result.update(
        policy=args.policy,
        command=command_line(),
        machine=describe_machine(args.device),
        wall_clock_s=wall,
    )
    print(stress_table(result, name), end="")
    if args.out:
        write_stress(result, args.out, name)
    print(f"wall-clock {wall:.1f} s" + (f"; results in {args.out}/" if args.out else ""))
    return 0


def add_stress_command(sub) -> None:
    """Register ``dockingrl stress`` on the CLI's subparsers ``sub``."""
    st = sub.add_parser(
        "stress",
        help="evaluate a policy on the stress ladder L0 (the paper's task) to L5 (docs/realism.md)",
        description="Evaluate a policy at each level of the stress ladder: L0 the paper's task, "
        "L1 slow, late and faulty sensors, L2 a varying, imperfectly known current, L3 a "
        "mismatched vehicle, L4 sensors and current, L5 all of them. Writes stress.json, "
        "stress.md and stress.png with --out.",
    )
    st.add_argument("--policy", default="managed_surge", help="'managed_surge' or a policy.pt")
    st.add_argument("--scenario", help="scenario (default: the policy's, or noise)")
    st.add_argument("--episodes", type=EPISODES, default=1000, help="episodes a level")
    st.add_argument("--levels", help=f"comma-separated levels (default: {','.join(LEVELS)})")
    st.add_argument("--seed", type=SEED, default=0)
    st.add_argument(
        "--vehicle",
        choices=list(VEHICLES),
        default="paper",
        help="the vehicle of the L levels (F0 and F5 fly the Fossen vehicle, the M levels either)",
    )
    st.add_argument("--gate", type=POSITIVE, default=None, help="EKF chi-square gate (13.8)")
    st.add_argument(
        "--compensate-latency",
        action="store_true",
        help="the EKF compensates each level's USBL latency (filtered scenarios)",
    )
    st.add_argument(
        "--estimate-current",
        action="store_true",
        help="the EKF estimates the current's error (filtered scenarios; not in the paper)",
    )
    st.add_argument("--use-filter", action="store_true", help="managed surge reads the EKF")
    st.add_argument(
        "--out", type=output_folder, help="folder for stress.json, stress.md and stress.png"
    )
    st.add_argument("--device", type=torch_device, default="cpu")
    st.add_argument("--threads", type=COUNT, default=1)
    st.set_defaults(func=cmd_stress)
