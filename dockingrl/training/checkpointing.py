"""A run's checkpoints: atomic folders under ``checkpoints/``, ``latest.json`` naming the
newest ``step_*`` folder, whose ``state.pt`` (an artefact of :mod:`dockingrl.io`) holds the
trainer's state and the sha256 of each file of its ``replay/`` folder (TorchRL's
``ReplayBuffer.dumps``), checked before the buffer loads it; and the restore of a resumed
run."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import torch

from dockingrl.agents.config_diff import as_saved
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
    sync_tree,
    write_json,
)
from dockingrl.training.logger import drop_curves_after

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


#: the config fields that shape an agent's networks: a warm start needs them equal
NETWORK_FIELDS = (
    "hidden",
    "critic_layer_norm",
    "critic_dropout",
    "activation",
    "state_independent_scale",
    "observe_current",
    "observe_command",
    "observe_filter_std",
    "observe_current_error",
)


def observation_width(config) -> int | None:
    """How many numbers the policy of a run with ``config`` (a config or its config.json's
    dict) reads, or ``None`` where it names no known scenario."""
    from dockingrl.scenarios import (
        SCENARIOS,
        layout_options,
        observation_layout,
        observation_size,
    )

    get = config.get if isinstance(config, dict) else lambda k: getattr(config, k, None)
    if get("scenario") not in SCENARIOS:
        return None
    return observation_size(observation_layout(get("scenario"), **layout_options(config)))


def network_differences(source: dict, cfg) -> list[str]:
    """The :data:`NETWORK_FIELDS` in which the config.json ``source`` and the config ``cfg``
    differ, each as ``"name: <source's> there, <cfg's> here"`` (a field the config.json lacks
    read as its default), and the scenario where the two policies read observations of
    different widths."""
    differ = []
    theirs, mine = observation_width(source), observation_width(cfg)
    if None not in (theirs, mine) and theirs != mine and source["scenario"] != cfg.scenario:
        differ.append(
            f"scenario: {source['scenario']} there, {cfg.scenario} here, "
            f"observations of {theirs} and {mine} numbers"
        )
    # a field the config.json lacks (added to dockingrl since, off by default) counts as the
    # config class's default, as a grid's saved configs do (agents.config_diff.config_mismatch)
    defaults = type(cfg)().to_dict()
    for name in NETWORK_FIELDS:
        if name not in defaults:
            continue
        theirs = as_saved(source.get(name, defaults[name]))
        mine = as_saved(getattr(cfg, name))
        if theirs != mine:
            differ.append(f"{name}: {theirs} there, {mine} here")
    return differ


def first_stage_hint(recipe: str | None) -> str:
    """``", or a run of recipe R"`` where the recipe ``recipe`` fine-tunes runs of recipe R
    (its ``first_stage``), else ``""``."""
    from dockingrl.recipes import load_recipe

    if not recipe:
        return ""
    try:
        first_stage = load_recipe(recipe).first_stage
    except ValueError:  # a recipe file moved or changed since: no hint
        return ""
    return f", or a run of recipe {first_stage}" if first_stage else ""


@dataclass
class RunProgress:
    """What a run has done, the counters its checkpoints keep: env steps (``frames``), ended
    episodes, seconds of training, the env steps of the next periodic evaluation and the next
    checkpoint (None: none), and the code of each process that trained it."""

    frames: int = 0
    episodes: int = 0
    elapsed: float = 0.0
    next_eval: int = 0
    next_checkpoint: int | None = None
    codes: list = field(default_factory=list)


class Checkpoints:
    """The checkpoints of one run in ``run_dir``: what it has trained (``agent``, its replay
    buffer, the ``progress`` counters, the RNG and ``selection``'s kept candidates), written
    every ``checkpoint_every`` env steps and restored on resume; ``code`` the source this
    process trains with."""

    def __init__(self, run_dir: Path, cfg, agent, progress: RunProgress, selection, code):
        self.run_dir, self.cfg, self.agent = run_dir, cfg, agent
        self.progress, self.selection, self.code = progress, selection, code

    @property
    def root(self) -> Path:
        return self.run_dir / "checkpoints"

    def save(self) -> Path:
        """Write a complete checkpoint folder (the format above), then point
        ``latest.json`` at it (one atomic rename), then drop older ones: a crash at any point
        leaves a usable checkpoint."""

        progress = self.progress
        path = self.root / f"step_{progress.frames:010d}"
        tmp = path.with_name(path.name + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        if self.agent.replay_buffer is not None and len(self.agent.replay_buffer):
            self.agent.replay_buffer.dumps(tmp / "replay")
        state = {
            "agent": self.agent.state_dict(),
            "frames": progress.frames,
            "episodes": progress.episodes,
            "elapsed": progress.elapsed,
            "next_eval": progress.next_eval,
            "next_checkpoint": progress.next_checkpoint,
            "torch_rng": torch.get_rng_state(),
            "best": self.selection.best,
            "candidates": self.selection.candidates,
            "codes": progress.codes,
        }
        write_state(tmp, state)
        sync_tree(tmp)  # on disk before latest.json names it and the older ones go
        shutil.rmtree(path, ignore_errors=True)
        tmp.rename(path)
        write_json(self.root / "latest.json", {"path": path.name, "frames": progress.frames})
        for old in self.root.glob("step_*"):
            if old != path:
                shutil.rmtree(old, ignore_errors=True)
        return path

    def load(self) -> bool:
        """Restore the checkpoint ``latest.json`` names; ``False`` where the run has none.
        Raises :class:`~dockingrl.io.ArtifactError` for a damaged, crafted or older one, or
        one that does not fit this run's agent."""
        from dockingrl.io import ArtifactError

        path = latest_checkpoint(self.root)
        if path is None:
            return False
        state = read_state(path)
        if state["replay"] is not None and self.agent.replay_buffer is None:
            raise ArtifactError(
                f"{path / 'state.pt'}: holds a replay buffer this run's agent lacks"
            )
        self._load_agent(path, state, replay=True)
        torch.set_rng_state(state["torch_rng"])
        progress = self.progress
        progress.frames, progress.episodes = state["frames"], state["episodes"]
        progress.elapsed = state["elapsed"]
        progress.next_eval, progress.next_checkpoint = state["next_eval"], state["next_checkpoint"]
        earlier = [c for c in state.get("codes", []) if c != self.code]
        progress.codes = [*earlier, self.code]
        best = state.get("best")
        candidates = state.get("candidates", [best] if best is not None else [])
        self.selection.candidates = candidates[: self.cfg.keep_candidates]
        return True

    def _load_agent(self, path: Path, state: dict, replay: bool, warm: bool = False) -> None:
        """Put the agent of the checkpoint ``path`` (its ``state``, read) into this run's, with
        its replay buffer where ``replay`` and it has one; ``warm``: a warm start, whose agent
        may start its average and keeps its own settings (``fresh_average`` and
        ``own_settings`` of :meth:`~dockingrl.agents.Agent.load_state_dict`). ArtifactError
        where it does not fit."""
        from dockingrl.io import ArtifactError, first_line

        try:
            self.agent.load_state_dict(state["agent"], fresh_average=warm, own_settings=warm)
            if replay and state["replay"] is not None:
                self.agent.replay_buffer.loads(path / "replay")
        except (KeyError, IndexError, RuntimeError, TypeError, ValueError) as exc:
            raise ArtifactError(
                f"{path / 'state.pt'}: does not fit this run ({first_line(exc)})"
            ) from None

    def warm_start(self) -> dict:
        """Start a new run from the agent of ``init_from``'s latest checkpoint (a finished
        run's, so that a grid never starts from a run still training): its networks,
        optimiser states (and with ``init_replay`` its replay buffer); this run's counters,
        RNG and kept actors stay new. Returns what it started from (``{"run", "frames"}``)."""
        import json

        from dockingrl.io import ArtifactError

        cfg = self.cfg
        source = Path(cfg.init_from)
        try:
            config = json.loads((source / "config.json").read_text())
            algo = config["algo"]
        except (OSError, ValueError, KeyError, TypeError):
            raise ArtifactError(
                f"init_from {source}: no run folder (no readable config.json)"
            ) from None
        if algo != cfg.algo:
            raise ValueError(f"init_from {source}: a {algo} run, not {cfg.algo}")
        differ = network_differences(config, cfg)
        if differ:
            raise ValueError(
                f"init_from {source}: its networks are not this run's ({'; '.join(differ)}); "
                f"give this run the same network options{first_stage_hint(cfg.recipe)}"
            )
        if not (source / "summary.json").exists():
            raise ValueError(
                f"init_from {source}: the run has not finished (no summary.json); finish it "
                f"first (dockingrl train --resume {source})"
            )
        path = latest_checkpoint(source / "checkpoints")
        if path is None:
            raise ArtifactError(f"init_from {source}: the run holds no checkpoint")
        state = read_state(path)
        if cfg.init_replay and (self.agent.replay_buffer is None or state["replay"] is None):
            raise ValueError(f"init_replay: {path} holds no replay buffer to start from")
        if cfg.init_replay and config.get("buffer_size", cfg.buffer_size) != cfg.buffer_size:
            raise ValueError(
                f"init_replay keeps {source}'s replay buffer of {config['buffer_size']} "
                f"transitions: give this run the same buffer_size (got {cfg.buffer_size})"
            )
        # where this run averages its actor and the source run did not, the average starts at
        # the loaded actor; the learning rate, discount and other settings stay this run's
        self._load_agent(path, state, replay=cfg.init_replay, warm=True)
        self.agent.updates = 0
        return {"run": str(source), "frames": state["frames"]}

    def due(self) -> bool:
        """Whether the run has reached its next checkpoint (then the one after is set)."""
        progress = self.progress
        due = progress.next_checkpoint is not None and progress.frames >= progress.next_checkpoint
        while due and progress.next_checkpoint <= progress.frames:
            progress.next_checkpoint += self.cfg.checkpoint_every
        return due

    def drop_curves_after(self, frames: int) -> None:
        """:func:`~dockingrl.training.logger.drop_curves_after` of this run."""
        drop_curves_after(self.run_dir, frames, self.cfg.total_steps)
