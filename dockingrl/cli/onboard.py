"""``dockingrl record-log`` and ``dockingrl replay``: a sensor log from a simulated approach, and
the onboard loop run over a log (:mod:`dockingrl.onboard.sensor_log`, docs/onboard.md)."""

from __future__ import annotations

import argparse

from dockingrl.cli.arguments import SEED, UsageError, csv_file, distinct_output


def _policy_and_config(args: argparse.Namespace):
    from dockingrl.env.levels import LEVELS, level_config
    from dockingrl.onboard import OnboardPolicy

    if args.level not in LEVELS:
        raise UsageError(f"--level {args.level!r}: unknown; valid: {', '.join(LEVELS)}")
    if args.policy == "managed_surge":
        raise UsageError("--policy managed_surge: give a trained policy.pt")
    config = level_config(args.level)
    return OnboardPolicy.from_file(args.policy, config=config), config


def cmd_record_log(args: argparse.Namespace) -> int:
    """``dockingrl record-log``: fly one approach and log what the vehicle received."""
    from dockingrl.env import DockingEnv
    from dockingrl.onboard.sensor_log import record_episode, write_log

    distinct_output(args.out, policy=args.policy)
    policy, config = _policy_and_config(args)
    env = DockingEnv(1, config=config, seed=args.seed)
    log, commands = record_episode(policy, env)
    path = write_log(log, args.out)
    rows = sum(len(v) for v in log.times.values())
    print(f"wrote {path}: {rows} messages over {len(commands)} control steps, level {args.level}")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    """``dockingrl replay``: the commands the onboard loop sends over a log."""
    from dockingrl.onboard.sensor_log import read_log, replay, write_replay

    distinct_output(args.out, log=args.log, policy=args.policy)
    log = read_log(args.log)  # a bad log is refused before the policy is loaded
    policy, config = _policy_and_config(args)
    result = replay(policy, log, config.dt)
    path = write_replay(result, args.out)
    line = f"wrote {path}: {len(result.times)} commands"
    if result.logged_commands is not None:
        sent = result.logged_commands.isfinite().all(-1)
        diff = (result.commands[sent] - result.logged_commands[sent]).abs()
        worst = float(diff.max()) if diff.numel() else 0.0
        line += f"; against the log's {int(sent.sum())} commands: largest difference {worst:.3g}"
    print(line)
    return 0


def add_onboard_commands(sub) -> None:
    """Register ``dockingrl record-log`` and ``dockingrl replay`` on the CLI's subparsers."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--policy", required=True, help="policy.pt written by training")
    common.add_argument(
        "--level",
        default="L0",
        help="the stress level whose sensors (rates, USBL latency) and vehicle the loop assumes "
        "(docs/realism.md; default L0, the paper's task)",
    )
    rec = sub.add_parser(
        "record-log",
        parents=[common],
        help="fly one simulated approach and write the sensor log the vehicle received",
    )
    rec.add_argument("--seed", type=SEED, default=0, help="the approach's seed")
    rec.add_argument("--out", type=csv_file, required=True, help="the log's file (.csv)")
    rec.set_defaults(func=cmd_record_log)
    rep = sub.add_parser(
        "replay",
        parents=[common],
        help="run the onboard loop over a sensor log: the commands, the filter's estimate and "
        "its uncertainty",
    )
    rep.add_argument("--log", required=True, help="a sensor log (docs/onboard.md)")
    rep.add_argument("--out", type=csv_file, required=True, help="the commands' file (.csv)")
    rep.set_defaults(func=cmd_replay)
