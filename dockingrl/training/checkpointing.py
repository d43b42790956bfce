"""A run's checkpoints: atomic folders under ``checkpoints/``, ``latest.json`` naming the
newest, and the restore of a resumed run."""

from __future__ import annotations

import shutil
from pathlib import Path

import torch

from dockingrl.agents.config_diff import as_saved
from dockingrl.io import sync_tree, write_json
from dockingrl.training.logger import drop_curves_after

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


class Checkpoints:
    """The checkpoints of a :class:`~dockingrl.training.Trainer`: what it has trained
    (``agent``, its replay buffer, the counters, the RNG and the kept candidates), written
    every ``checkpoint_every`` env steps and restored on resume."""

    @property
    def checkpoint_root(self) -> Path:
        return self.run_dir / "checkpoints"

    def save_checkpoint(self) -> Path:
        """Write a complete checkpoint folder (:mod:`dockingrl.checkpoint`), then point
        ``latest.json`` at it (one atomic rename), then drop older ones: a crash at any point
        leaves a usable checkpoint."""
        from dockingrl.checkpoint import write_state

        path = self.checkpoint_root / f"step_{self.frames:010d}"
        tmp = path.with_name(path.name + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        if self.agent.replay_buffer is not None and len(self.agent.replay_buffer):
            self.agent.replay_buffer.dumps(tmp / "replay")
        state = {
            "agent": self.agent.state_dict(),
            "frames": self.frames,
            "episodes": self.episodes,
            "elapsed": self.elapsed,
            "next_eval": self.next_eval,
            "next_checkpoint": self.next_checkpoint,
            "torch_rng": torch.get_rng_state(),
            "best": self.best,
            "candidates": self.candidates,
            "codes": self.codes,
        }
        write_state(tmp, state)
        sync_tree(tmp)  # on disk before latest.json names it and the older ones go
        shutil.rmtree(path, ignore_errors=True)
        tmp.rename(path)
        write_json(self.checkpoint_root / "latest.json", {"path": path.name, "frames": self.frames})
        for old in self.checkpoint_root.glob("step_*"):
            if old != path:
                shutil.rmtree(old, ignore_errors=True)
        return path

    def load_checkpoint(self) -> bool:
        """Restore the checkpoint ``latest.json`` names; ``False`` where the run has none.
        Raises :class:`~dockingrl.io.ArtifactError` for a damaged, crafted or older one, or
        one that does not fit this run's agent."""
        from dockingrl.checkpoint import latest_checkpoint, read_state
        from dockingrl.io import ArtifactError

        path = latest_checkpoint(self.checkpoint_root)
        if path is None:
            return False
        state = read_state(path)
        if state["replay"] is not None and self.agent.replay_buffer is None:
            raise ArtifactError(
                f"{path / 'state.pt'}: holds a replay buffer this run's agent lacks"
            )
        self._load_agent(path, state, replay=True)
        torch.set_rng_state(state["torch_rng"])
        self.frames, self.episodes, self.elapsed = (
            state["frames"],
            state["episodes"],
            state["elapsed"],
        )
        self.next_eval, self.next_checkpoint = state["next_eval"], state["next_checkpoint"]
        earlier = [c for c in state.get("codes", []) if c != self.code]
        self.codes = [*earlier, self.code]
        best = state.get("best")
        self.candidates = state.get("candidates", [best] if best is not None else [])
        del self.candidates[self.cfg.keep_candidates :]
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

        from dockingrl.checkpoint import latest_checkpoint, read_state
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

    def checkpoint_due(self) -> bool:
        """Whether the run has reached its next checkpoint (then the one after is set)."""
        due = self.next_checkpoint is not None and self.frames >= self.next_checkpoint
        while due and self.next_checkpoint <= self.frames:
            self.next_checkpoint += self.cfg.checkpoint_every
        return due

    def _drop_curves_after(self, frames: int) -> None:
        """:func:`~dockingrl.training.logger.drop_curves_after` of this run."""
        drop_curves_after(self.run_dir, frames, self.cfg.total_steps)
