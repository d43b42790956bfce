"""``dockingrl upgrade``: convert policy, filter-parameter and checkpoint files of an older
format, once, into the current one (read weights-only, rewritten atomically)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dockingrl.io import ArtifactError, read_old_artifact


def upgrade_file(path: str | Path) -> str:
    """Convert one policy, filter-parameter or checkpoint-state file of an older format (see
    :func:`~dockingrl.agents.saving.upgrade_policy`,
    :func:`~dockingrl.transforms.params.upgrade_filter_params`,
    :func:`~dockingrl.checkpoint.upgrade_state`); returns the line saying what was done.
    Raises :class:`~dockingrl.io.ArtifactError` for a file it cannot convert."""
    from dockingrl.agents.saving import upgrade_policy
    from dockingrl.checkpoint import upgrade_state
    from dockingrl.transforms.params import upgrade_filter_params

    found = read_old_artifact(path, "dockingrl file").get("format")
    kind = found.split("/")[0] if isinstance(found, str) else None
    upgrade = {
        "dockingrl.policy": upgrade_policy,
        "dockingrl.filter_params": upgrade_filter_params,
        "dockingrl.checkpoint": upgrade_state,
    }.get(kind)
    if upgrade is None:
        raise ArtifactError(f"{path}: not a dockingrl file (format {found!r})")
    return upgrade(path)


def upgrade_targets(path: str | Path) -> list[Path]:
    """The files ``dockingrl upgrade PATH`` converts: ``path`` itself, or for a folder (a run
    folder, or one of learned filters) its ``*.pt`` files and the state of each of its
    checkpoints."""
    path = Path(path)
    if not path.is_dir():
        return [path]
    files = sorted(path.glob("*.pt")) + sorted(
        p / "state.pt"
        for p in (path / "checkpoints").glob("step_*")
        if not p.name.endswith(".tmp") and (p / "state.pt").is_file()
    )
    if not files:
        raise ArtifactError(f"{path}: holds no .pt file and no checkpoint to convert")
    return files


def cmd_upgrade(args: argparse.Namespace) -> int:
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
