"""``dockingrl grid`` and ``dockingrl table``: the command-line front of :mod:`dockingrl.grid`
and :mod:`dockingrl.table`."""

from __future__ import annotations

import argparse

from dockingrl.cli.arguments import (
    COUNT,
    NON_NEGATIVE,
    NON_NEGATIVE_INT,
    POSITIVE,
    UsageError,
    output_folder,
)
from dockingrl.provenance import command_line


def cmd_grid(args: argparse.Namespace) -> int:
    from dockingrl.grid import load_grid, run_grid, select_trials

    whole = load_grid(args.grid, out=args.out, collect=args.collect)
    grid = select_trials(whole, args.only, args.threads)
    check_table_options(args, [t.seed for t in whole.trials])
    if args.list:
        from dockingrl.grid import finished_trial
        from dockingrl.grid.folders import success_rate_text

        for trial in grid.trials:
            s, refusal = finished_trial(grid, trial)
            if refusal:
                state = f"finished with another config: {refusal}"
            elif s:
                state = f"finished, {success_rate_text(s)}"
            else:
                state = "not finished"
            print(f"{trial.name:<34} {state}")
        return 0
    states = run_grid(
        grid,
        address=args.address,
        max_concurrent=args.max_concurrent,
        hours=args.hours,
        view_every=args.view_every,
        stop_after=args.stop_after,
    )
    left = sorted(n for n, s in states.items() if s != "finished")
    if left:
        print(f"{len(left)} of {len(states)} trials not finished; run the same command to resume")
        return 1 if any(states[n] == "failed" for n in left) else 3
    if args.table:
        from dockingrl.grid import finished_summary
        from dockingrl.table import write_table

        # the table is the whole grid's, also when --only ran a part of it
        unfinished = [t for t in whole.trials if finished_summary(whole, t) is None]
        if unfinished:
            print(f"table not written: {len(unfinished)} trials of the grid are not finished")
            return 0
        dirs = [whole.collect / t.name if whole.collect else whole.run_dir(t) for t in whole.trials]
        write_table(
            dirs,
            args.table,
            prune_policies=args.prune_policies,
            command=command_line(),
            baseline=args.baseline,
            held_out=args.held_out,
        )
        print(f"table written to {args.table}")
    return 0


def check_table_options(args: argparse.Namespace, seeds: list[int]) -> None:
    """Refuse, before any trial runs, table options that the grid's table would refuse at the
    end: ``--baseline``, ``--held-out`` or ``--prune-policies`` without ``--table``, a baseline
    that is not an evaluation, and ``--held-out`` with a grid on seeds below 100."""
    if args.table is None:
        given = [
            flag
            for flag, value in (
                ("--baseline", args.baseline),
                ("--held-out", args.held_out),
                ("--prune-policies", args.prune_policies),
            )
            if value
        ]
        if given:
            raise UsageError(f"{', '.join(given)} apply to the table: give --table DIR")
        return
    if args.baseline is not None:
        from pathlib import Path

        from dockingrl.table.claims import read_baseline

        read_baseline(Path(args.baseline))
    if args.held_out:
        from dockingrl.evaluation.protocol import require_held_out

        require_held_out(seeds, "dockingrl grid --held-out")


def cmd_table(args: argparse.Namespace) -> int:
    from dockingrl.table import write_table

    table = write_table(
        args.runs,
        args.out,
        prune_policies=args.prune_policies,
        command=command_line(),
        baseline=args.baseline,
        held_out=args.held_out,
    )
    print(f"{len(table['cells'])} cells written to {args.out} (table.md, table.json, figures)")
    return 0


def add_grid_commands(sub) -> None:
    """Register ``dockingrl grid`` and ``dockingrl table`` on the CLI's subparsers ``sub``."""
    gr = sub.add_parser(
        "grid",
        help="train a grid of recipes x scenarios x seeds on Ray (resumable)",
        description="Run the trials of a grid file on Ray, as many at once as the CPUs allow "
        "for the threads each takes. Interrupted (Ctrl-C, SIGTERM, a killed driver or machine), "
        "the same command resumes it: finished trials are kept, unfinished ones continue from "
        "their last checkpoint. Exit status: 0 all finished, 1 a trial failed, 3 trials left.",
    )
    gr.add_argument("grid", help="a shipped grid name (table6, robust) or a grid YAML file")
    gr.add_argument("--address", help="an existing Ray cluster to run on (default: local Ray)")
    gr.add_argument(
        "--out", type=output_folder, help="folder of the run folders (default: the grid file's)"
    )
    gr.add_argument(
        "--collect",
        type=output_folder,
        help="folder for finished trials' small files (default: file's)",
    )
    gr.add_argument(
        "--only",
        nargs="+",
        metavar="PATTERN",
        help="run (or list) only the trials whose names match a pattern, e.g. 'td3__*' "
        "'*__compound__s1' (names: RECIPE__SCENARIO__sSEED); the rest are left as they are",
    )
    gr.add_argument(
        "--threads",
        type=COUNT,
        default=None,
        help="torch threads (and Ray CPUs) per trial (default: the grid file's); a trial may "
        "resume with another count",
    )
    gr.add_argument(
        "--max-concurrent",
        type=COUNT,
        default=None,
        help="trials at once (default: CPUs // threads); more share the cores, each slower, "
        "ending together: more trials finished on a machine lent for a few hours (docs/grid.md)",
    )
    gr.add_argument(
        "--hours",
        type=NON_NEGATIVE,
        default=0.0,
        help="start only trials expected to end within this many hours (0: no limit)",
    )
    gr.add_argument(
        "--stop-after",
        type=NON_NEGATIVE_INT,
        default=0,
        help="start no more trials once this many ended",
    )
    gr.add_argument("--view-every", type=POSITIVE, default=60.0, help="seconds between views")
    gr.add_argument("--list", action="store_true", help="list the trials and their state, run none")
    gr.add_argument(
        "--table",
        type=output_folder,
        default=None,
        metavar="DIR",
        help="when every trial is finished, write the table and figures there (dockingrl table)",
    )
    _table_options(gr)
    gr.set_defaults(func=cmd_grid)

    tb = sub.add_parser(
        "table",
        help="Table 6 and Figures 6-8 from finished runs (cells: recipe x scenario, over seeds)",
    )
    tb.add_argument("runs", nargs="+", help="run folders (unfinished ones are left out)")
    tb.add_argument(
        "--out",
        type=output_folder,
        default="results/table6",
        help="folder for table.md/json, figures",
    )
    _table_options(tb)
    tb.set_defaults(func=cmd_table)


def _table_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--prune-policies",
        action="store_true",
        help="delete policy.pt from every run folder but the best seed's of each cell (off by "
        "default: other results may load the other seeds' policies)",
    )
    parser.add_argument(
        "--baseline",
        metavar="EVAL_JSON",
        help="the managed surge controller's eval.json: test the claim that learned policies "
        "dock faster (e.g. results/managed_surge/eval.json)",
    )
    parser.add_argument(
        "--held-out",
        action="store_true",
        help="refuse runs on a training seed below 100: a reported table is on held-out seeds "
        "(docs/reproduction.md, 'The held-out protocol')",
    )
