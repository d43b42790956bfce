"""The files of a training checkpoint: ``checkpoints/latest.json`` naming the newest
``step_*`` folder, whose ``state.pt`` (an artefact of :mod:`dockingrl.io`) holds the trainer's
state and the sha256 of each file of its ``replay/`` folder (TorchRL's
``ReplayBuffer.dumps``), checked before the buffer loads it."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from dockingrl.io import (
    ArtifactError,
    FieldRule,
    check_folder,
    first_bad_field,
    folder_manifest,
    is_count,
    is_finite_number,
    read_artifact,
    read_to_upgrade,
    require_finite,
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
    problem = first_bad_field(_ENTRIES, state)
    if problem:
        raise ArtifactError(f"{path}: {problem}")
    require_finite(path, "agent", state["agent"])
    replay = folder / "replay"
    if state["replay"] is None:
        if replay.exists() or replay.is_symlink():
            raise ArtifactError(f"{replay}: not listed in {path}")
    else:
        check_folder(replay, state["replay"], REPLAY_SUFFIXES, path)
    return state


def _candidate(value) -> bool:
    """A kept actor as the trainer writes it: ``{"success", "frames", "actor"}``."""
    return (
        isinstance(value, dict)
        and isinstance(value.get("success"), (int, float))
        and not isinstance(value.get("success"), bool)
        and is_count(value.get("frames"))
        and isinstance(value.get("actor"), dict)
    )


#: what each entry of a checkpoint's state beside the agent's must be, and how to tell: a
#: checkpoint re-saved whole by hand would otherwise fail deep in the training loop
_ENTRIES: dict[str, FieldRule] = {
    "agent": ("a dict", lambda v: isinstance(v, dict)),
    "frames": ("an integer >= 0", is_count),
    "episodes": ("an integer >= 0", is_count),
    "elapsed": ("a finite number >= 0", lambda v: is_finite_number(v) and v >= 0),
    "next_eval": ("an integer >= 0 or None", lambda v: v is None or is_count(v)),
    "next_checkpoint": ("an integer >= 0 or None", lambda v: v is None or is_count(v)),
    "torch_rng": (
        "a uint8 tensor (torch.get_rng_state())",
        lambda v: isinstance(v, torch.Tensor) and v.dtype == torch.uint8 and v.dim() == 1,
    ),
    "codes": (
        "a list of code versions ({commit, ...})",
        lambda v: isinstance(v, list) and all(isinstance(c, dict) for c in v),
    ),
    "best": ("a kept actor or None", lambda v: v is None or _candidate(v)),
    "candidates": (
        "a list of kept actors",
        lambda v: isinstance(v, list) and all(_candidate(c) for c in v),
    ),
}


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
