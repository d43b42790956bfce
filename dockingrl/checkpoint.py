"""The files of a training checkpoint: ``checkpoints/latest.json`` naming the newest
``step_*`` folder, whose ``state.pt`` (an artefact of :mod:`dockingrl.io`) holds the trainer's
state and the sha256 of each file of its ``replay/`` folder (TorchRL's
``ReplayBuffer.dumps``), checked before the buffer loads it."""

from __future__ import annotations

import json
from pathlib import Path

from dockingrl.io import (
    ArtifactError,
    check_folder,
    folder_manifest,
    read_artifact,
    read_to_upgrade,
    require_keys,
    save_artifact,
)

FORMAT = "dockingrl.checkpoint/2"
#: version 1 had no content hash and no manifest of ``replay/``
OLD_FORMATS = ("dockingrl.checkpoint/1",)
WHAT = "dockingrl checkpoint"
#: the keys every checkpoint's state holds
KEYS = ("agent", "frames", "episodes", "elapsed", "next_eval", "next_checkpoint", "torch_rng")
#: the only files a checkpoint's ``replay/`` may hold: no pickle TorchRL would load
REPLAY_SUFFIXES = (".json", ".memmap")


def write_state(folder: str | Path, state: dict) -> Path:
    """Write ``folder/state.pt`` holding ``state`` (tensors, numbers, strings, lists, dicts)
    and the manifest of ``folder/replay/``, if the replay buffer was dumped there first. The
    prefetch queue TorchRL pickles beside the buffer is dropped: dockingrl's buffers do not
    prefetch."""
    folder = Path(folder)
    replay = folder / "replay"
    payload = {"format": FORMAT, **state, "replay": None}
    if replay.is_dir():
        (replay / "prefetch.pkl").unlink(missing_ok=True)
        payload["replay"] = folder_manifest(replay)
    return save_artifact(folder / "state.pt", payload)


def latest_checkpoint(root: str | Path) -> Path | None:
    """The checkpoint folder ``root/latest.json`` names, or ``None`` without that file.
    The folder must be a folder directly in ``root`` (no path out of it, no link out of it).
    Raises :class:`~dockingrl.io.ArtifactError`."""
    root = Path(root)
    latest = root / "latest.json"
    if not latest.exists() and not latest.is_symlink():
        return None
    if latest.is_dir():
        raise ArtifactError(f"{latest}: is a directory, not a checkpoint pointer")
    try:
        pointer = json.loads(latest.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise ArtifactError(f"{latest}: cannot be read as text ({exc})") from None
    except json.JSONDecodeError as exc:
        raise ArtifactError(f"{latest}: not JSON ({exc.msg} at line {exc.lineno})") from None
    name = pointer.get("path") if isinstance(pointer, dict) else None
    if not isinstance(name, str) or not name:
        raise ArtifactError(f'{latest}: holds no "path" naming a checkpoint folder')
    inside = root.resolve()
    path = (root / name).resolve()
    if path.parent != inside:
        raise ArtifactError(
            f"{latest}: path {name!r} leads out of {root}; a checkpoint is a folder in it"
        )
    if not path.is_dir():
        raise ArtifactError(f"{latest}: path {name!r} is not a checkpoint folder in {root}")
    return path


def read_state(folder: str | Path) -> dict:
    """The state in ``folder/state.pt``, checked (format, hash, keys), with its ``replay/``
    folder checked against the manifest. Raises :class:`~dockingrl.io.ArtifactError`."""
    folder = Path(folder)
    path = folder / "state.pt"
    if path.is_symlink():
        raise ArtifactError(f"{path}: a link; a checkpoint's state is a plain file")
    state = read_artifact(path, WHAT, FORMAT, OLD_FORMATS)
    require_keys(path, state, WHAT, KEYS + ("replay",))
    replay = folder / "replay"
    if state["replay"] is None:
        if replay.exists() or replay.is_symlink():
            raise ArtifactError(f"{replay}: not listed in {path}")
    else:
        check_folder(replay, state["replay"], REPLAY_SUFFIXES, path)
    return state


def upgrade_state(path: str | Path) -> str:
    """Rewrite the checkpoint state ``path`` (``step_*/state.pt``) of an older format in the
    current one, trusting its ``replay/`` folder as it is; returns what was done."""
    path = Path(path)
    state = read_to_upgrade(path, WHAT, FORMAT, OLD_FORMATS)
    if state is None:
        return f"{path}: already {FORMAT}"
    found = state["format"]
    require_keys(path, state, WHAT, KEYS)
    del state["format"]
    state.pop("replay", None)
    write_state(path.parent, state)
    return f"{path}: {found} -> {FORMAT}"
