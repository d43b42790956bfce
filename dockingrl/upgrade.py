"""Converting policy, filter-parameter and checkpoint files of an older format, once, into the
current one (read weights-only, rewritten atomically; ``dockingrl upgrade``)."""

from __future__ import annotations

from pathlib import Path

from dockingrl.io import ArtifactError, read_old_artifact


def upgrade_file(path: str | Path) -> str:
    """Convert one policy, filter-parameter or checkpoint-state file of an older format (see
    :func:`~dockingrl.agents.saving.upgrade_policy`,
    :func:`~dockingrl.transforms.params.upgrade_filter_params`,
    :func:`~dockingrl.training.checkpointing.upgrade_state`); returns the line saying what was done.
    Raises :class:`~dockingrl.io.ArtifactError` for a file it cannot convert."""
    from dockingrl.agents.saving import upgrade_policy
    from dockingrl.training.checkpointing import upgrade_state
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
    try:
        return upgrade(path)
    except ArtifactError:
        raise
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        # a file of a known format whose content is not what that format holds
        detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ArtifactError(f"{path}: a damaged {kind} file, not converted ({detail})") from None


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
