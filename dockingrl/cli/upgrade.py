"""``dockingrl upgrade``: the command-line front of :mod:`dockingrl.upgrade`."""

from __future__ import annotations

import argparse
import sys


def cmd_upgrade(args: argparse.Namespace) -> int:
    from dockingrl.io import ArtifactError
    from dockingrl.upgrade import upgrade_file, upgrade_targets

    failed = 0
    for path in args.paths:
        try:
            files = upgrade_targets(path)
        except ArtifactError as exc:
            print(f"dockingrl: error: {exc}", file=sys.stderr)
            failed += 1
            continue
        for file in files:
            try:
                print(upgrade_file(file))
            except ArtifactError as exc:
                print(f"dockingrl: error: {exc}", file=sys.stderr)
                failed += 1
    return 1 if failed else 0


def add_upgrade_command(sub) -> None:
    """Register ``dockingrl upgrade`` on the subcommands ``sub`` of the CLI's parser."""
    up = sub.add_parser(
        "upgrade",
        help="convert policy, filter-parameter and checkpoint files of an older format",
        description="Rewrite each file (or each run folder's policy.pt, *.pt files and "
        "checkpoints) of an older dockingrl format in the current one, with its content hash "
        "and, for a policy, its observation layout. Files are read weights-only (no code runs) "
        "and replaced atomically; current files are left as they are. Exit status 1 if a file "
        "could not be converted.",
    )
    up.add_argument("paths", nargs="+", metavar="PATH", help="a file or a run folder")
    up.set_defaults(func=cmd_upgrade)
