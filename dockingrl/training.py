"""Training loop shared by SAC, TD3 and PPO: collection with TorchRL's ``Collector``, periodic
and final evaluation, logging (wandb offline by default), atomic checkpoints and resume."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import sys
import threading
import time
from dataclasses import fields
from pathlib import Path

import torch
from torchrl.collectors import Collector
from torchrl.envs import RewardSum
from torchrl.envs.utils import ExplorationType

from dockingrl.agents import Agent, make_agent
from dockingrl.agents.config import CONFIGS, TrainConfig
from dockingrl.agents.reward_shaping import RewardShaping
from dockingrl.agents.saving import pipeline_options, save_policy
from dockingrl.env import DockingConfig
from dockingrl.env.levels import level_config
from dockingrl.evaluation import base_env, describe_machine, evaluate
from dockingrl.io import atomic_write, write_json
from dockingrl.scenarios import check_mirror_symmetric, make_env
from dockingrl.transforms import (
    ContactSpeedPenalty,
    MissPenaltyFloor,
    PassedStationEnd,
    SuccessBonus,
)
from dockingrl.transforms.params import read_filter_params

#: seed of the validation episodes that pick among ``keep_candidates`` actors (plus the run's
#: seed); periodic evaluations use ``1_000_000 + frames``, the final one ``seed + 10_000``
SELECT_SEED = 1 << 40
#: TrainConfig fields that bias the training env's resets (``DockingConfig`` fields of the same
#: name); evaluation keeps Sec. 4.1's draws
TRAINING_DRAWS = ("following_current_fraction", "lateral_current_fraction", "near_start_fraction")


class TrainingInterrupted(Exception):
    """A run stopped by SIGTERM or SIGINT after checkpointing its last whole batch: nothing
    trained is lost, and ``--resume`` continues it."""

    def __init__(self, signum: int, frames: int, run_dir: Path) -> None:
        self.signum, self.frames, self.run_dir = signum, frames, run_dir
        super().__init__(
            f"stopped by {signal.Signals(signum).name} at {frames} env steps, checkpoint "
            f"written; continue with: dockingrl train --resume {run_dir}"
        )


class _StopRequests:
    """While training (main thread only), SIGTERM and SIGINT ask the loop to stop after the
    current batch and checkpoint; a second signal interrupts at once (``KeyboardInterrupt``)."""

    SIGNALS = (signal.SIGTERM, signal.SIGINT)

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict = {}

    def _handler(self, signum, frame) -> None:
        if self.signum is not None:
            raise KeyboardInterrupt(f"second {signal.Signals(signum).name}: stopping now")
        self.signum = signum
        print(
            f"\n{signal.Signals(signum).name}: stopping after this batch and its checkpoint "
            "(again to stop at once)",
            file=sys.stderr,
            flush=True,
        )

    def install(self) -> None:
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handler)

    def restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()


class RunLogger:
    """Namespaced scalars (``train/``, ``eval/``, ``losses/``, ``time/``) to a local
    ``curves.csv``, appended as they come, and to wandb (offline by default) or TorchRL's CSV
    logger.

    ``curves.csv`` is the record: a resumed run cuts it back to its checkpoint
    (:meth:`Trainer._drop_curves_after`). The backend receives the rows of ``curves.csv`` once
    each, in order: with ``buffered`` (a run that checkpoints), only when :meth:`flush` is
    called after a checkpoint and at the end, so that it never holds a step that a resumed run
    trains again; otherwise after every :meth:`log`. ``logged.json`` counts the rows the backend
    has; :meth:`sync` (on resume) rewrites the CSV backend's files from ``curves.csv`` and sends
    the rows it lacks."""

    def __init__(
        self,
        config: dict,
        kind: str,
        run_dir: Path,
        run_id: str,
        online: bool = False,
        *,
        buffered: bool = False,
    ) -> None:
        self.run_dir = run_dir
        self.curves = run_dir / "curves.csv"
        self.marker = run_dir / "logged.json"
        self.kind, self.buffered = kind, buffered
        self._pending: list[tuple[int, str, float]] = []
        self._sent = 0
        self.backend = None
        if kind == "wandb":
            from torchrl.record.loggers import WandbLogger

            self.backend = WandbLogger(
                exp_name=run_dir.name,
                offline=not online,
                save_dir=str(run_dir),
                id=run_id,
                project="dockingrl",
                config=config,
                resume="allow",
                log_env_packages=False,
            )
        elif kind == "csv":
            from torchrl.record.loggers import CSVLogger

            self.backend = CSVLogger(exp_name=run_dir.name, log_dir=str(run_dir / "csv"))
            self.backend.log_hparams(config)
        elif kind != "none":
            raise ValueError(f"unknown logger {kind!r}; valid: wandb, csv, none")

    def log(self, metrics: dict[str, float], step: int) -> None:
        rows = [(step, key, float(value)) for key, value in metrics.items()]
        new = not self.curves.exists()
        with self.curves.open("a", newline="") as f:
            writer = csv.writer(f)
            if new:
                writer.writerow(["step", "key", "value"])
            writer.writerows(rows)
        if self.backend is not None:
            self._pending.extend(rows)
            if not self.buffered:
                self.flush()

    def flush(self) -> None:
        """Send the backend the rows logged since the last flush, step by step; with
        ``buffered``, ``logged.json`` counts the rows sent after each step."""
        rows, self._pending = self._pending, []
        start = 0
        while start < len(rows):
            end = start
            while end < len(rows) and rows[end][0] == rows[start][0]:
                end += 1
            for step, key, value in rows[start:end]:
                self.backend.log_scalar(key, value, step=int(step))
            self._sent += end - start
            if self.buffered:
                write_json(self.marker, {"rows": self._sent})
            start = end

    def sync(self) -> None:
        """Make the backend hold the rows of ``curves.csv`` (cut back to the checkpoint on
        resume) once each: the CSV backend's files are written anew from it; another backend
        (wandb) is sent the rows that ``logged.json`` says it lacks."""
        if self.backend is None:
            return
        rows: list = []
        if self.curves.exists():
            with self.curves.open(newline="") as f:
                rows = [(int(s), k, float(v)) for s, k, v in list(csv.reader(f))[1:]]
        if self.kind == "csv":
            experiment = self.backend.experiment
            for handle in experiment.files.values():
                handle.close()
            experiment.files.clear()
            scalars = Path(experiment.log_dir) / "scalars"
            by_key: dict[str, str] = {}
            for step, key, value in rows:
                by_key[key] = by_key.get(key, "") + f"{step},{value}\n"
            for path in scalars.rglob("*.csv"):
                if path.relative_to(scalars).with_suffix("").as_posix() not in by_key:
                    path.unlink()
            for key, text in by_key.items():
                atomic_write(scalars / f"{key}.csv", lambda tmp, text=text: tmp.write_text(text))
            self._sent = len(rows)
            write_json(self.marker, {"rows": self._sent})
        else:
            try:
                self._sent = min(int(json.loads(self.marker.read_text())["rows"]), len(rows))
            except (OSError, ValueError, KeyError, TypeError):
                self._sent = 0
        self._pending = rows[self._sent :]
        self.flush()

    def finish(self, summary: dict) -> None:
        self.flush()
        if self.backend is not None and hasattr(self.backend, "experiment"):
            experiment = self.backend.experiment
            if hasattr(experiment, "summary"):
                experiment.summary.update(
                    {k: v for k, v in summary.items() if isinstance(v, (int, float, str))}
                )
            if hasattr(experiment, "finish"):
                experiment.finish()


def read_curves(run_dir: str | Path) -> dict[str, list[tuple[int, float]]]:
    """``curves.csv`` as ``{key: [(step, value), ...]}``."""
    curves: dict[str, list[tuple[int, float]]] = {}
    path = Path(run_dir) / "curves.csv"
    if path.exists():
        with path.open() as f:
            for row in csv.DictReader(f):
                curves.setdefault(row["key"], []).append((int(row["step"]), float(row["value"])))
    return curves


def env_kwargs(cfg: TrainConfig) -> dict:
    """The :func:`~dockingrl.make_env` options a training config implies (sensor-noise
    scaling, the realism options of its ``train_level``, learned filter parameters, and
    :func:`pipeline_options`)."""
    config = DockingConfig().scale_usbl_noise(cfg.range_noise_scale, cfg.bearing_noise_scale)
    kwargs: dict = {"config": level_config(cfg.train_level, config)}
    if cfg.filter_params:
        kwargs["filter_params"] = read_filter_params(cfg.filter_params)
    kwargs.update(pipeline_options(cfg.to_dict()))
    return kwargs


def training_draws(cfg: TrainConfig, config: DockingConfig) -> DockingConfig:
    """The training env's config: ``config`` with the run's curricula (``TRAINING_DRAWS``)
    that are on. Evaluations keep ``config``, Sec. 4.1's draws."""
    curricula = {name: getattr(cfg, name) for name in TRAINING_DRAWS if getattr(cfg, name) > 0}
    return config.replace(**curricula) if curricula else config


def training_transforms(cfg: RewardShaping) -> list:
    """What the training env adds to the scenario: ``RewardSum`` (logged episode rewards are
    the paper's eq. 12), then the optional terms the agent learns from: the floor on a miss's
    contact reward, the contact-speed penalty, the success bonus, and the end of an episode
    that passes the station."""
    base = DockingConfig()
    contact_weight = base.contact_weight
    transforms = [RewardSum()]
    if cfg.miss_penalty_floor > 0:
        transforms.append(MissPenaltyFloor(cfg.miss_penalty_floor, contact_weight))
    if cfg.contact_speed_penalty > 0:
        cap = contact_weight if cfg.contact_speed_penalty_cap else None
        transforms.append(
            ContactSpeedPenalty(cfg.contact_speed_penalty, cfg.contact_speed_target, cap)
        )
    if cfg.success_bonus > 0:
        transforms.append(SuccessBonus(cfg.success_bonus))
    if cfg.passed_station_penalty > 0:
        transforms.append(PassedStationEnd(cfg.passed_station_penalty, base.dock_x[1]))
    return transforms


def default_run_name(cfg: TrainConfig) -> str:
    return f"dockingrl__{cfg.algo}__{cfg.scenario}__{cfg.seed}__{int(time.time())}"


class Trainer:
    """Trains one agent on one scenario; see :func:`train`."""

    def __init__(
        self, cfg: TrainConfig, run_dir: Path, *, progress: bool = True, command: str = ""
    ) -> None:
        self.cfg, self.run_dir, self.progress, self.command = cfg, run_dir, progress, command
        torch.set_num_threads(cfg.threads)
        self.frames = 0
        self.episodes = 0
        self.elapsed = 0.0
        self.next_eval = cfg.eval_every
        self.next_checkpoint = cfg.checkpoint_every or None
        self.last_success = float("nan")
        # keep_best: the keep_candidates best periodic evaluations so far (best first, the
        # earlier of equal scores first), each with the actor's weights then
        self.candidates: list[dict] = []
        self.run_id = run_dir.name.replace("__", "-")[-60:]
        self.env_kwargs = env_kwargs(cfg)
        probe = make_env(cfg.scenario, 1, seed=0, **self.env_kwargs)
        if getattr(cfg, "mirror_augment", False):
            check_mirror_symmetric(probe)
        sim = base_env(probe)
        self.obs_dim = probe.observation_spec["observation"].shape[-1]
        self.action_spec = probe.action_spec[0].clone()
        self.max_dist = sim.config.max_dist
        torch.manual_seed(cfg.seed)
        self.agent: Agent = make_agent(
            cfg, self.obs_dim, self.action_spec, self.max_dist, cfg.device
        )

    @property
    def out_of_time(self) -> bool:
        """Whether ``time_budget_s`` (if any) is spent."""
        return 0 < self.cfg.time_budget_s <= self.elapsed

    # -- checkpoints -----------------------------------------------------------------------
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
        }
        write_state(tmp, state)
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
        from dockingrl.io import ArtifactError, first_line

        path = latest_checkpoint(self.checkpoint_root)
        if path is None:
            return False
        state = read_state(path)
        if state["replay"] is not None and self.agent.replay_buffer is None:
            raise ArtifactError(
                f"{path / 'state.pt'}: holds a replay buffer this run's agent lacks"
            )
        try:
            self.agent.load_state_dict(state["agent"])
            if state["replay"] is not None:
                self.agent.replay_buffer.loads(path / "replay")
            torch.set_rng_state(state["torch_rng"])
        except (KeyError, IndexError, RuntimeError, TypeError, ValueError) as exc:
            raise ArtifactError(
                f"{path / 'state.pt'}: does not fit this run ({first_line(exc)})"
            ) from None
        self.frames, self.episodes, self.elapsed = (
            state["frames"],
            state["episodes"],
            state["elapsed"],
        )
        self.next_eval, self.next_checkpoint = state["next_eval"], state["next_checkpoint"]
        best = state.get("best")
        self.candidates = state.get("candidates", [best] if best is not None else [])
        del self.candidates[self.cfg.keep_candidates :]
        return True

    def _drop_curves_after(self, frames: int) -> None:
        """Forget what was logged after the checkpoint: those steps are trained again. A run
        resumed at its total only to end again (a new end-of-run choice) also forgets its
        final evaluation, which it logs again."""
        again = frames >= self.cfg.total_steps
        path = self.run_dir / "curves.csv"
        if not path.exists():
            return
        with path.open() as f:
            rows = list(csv.reader(f))
        kept = [rows[0]] + [
            row
            for row in rows[1:]
            if int(row[0]) < frames
            or (int(row[0]) == frames and not (again and row[1].startswith("eval/final_")))
        ]

        def write(tmp: Path) -> None:
            with tmp.open("w", newline="") as f:
                csv.writer(f).writerows(kept)

        atomic_write(path, write)

    # -- evaluation ------------------------------------------------------------------------
    def _evaluate(self, episodes: int, seed: int, **kwargs) -> dict:
        """:func:`~dockingrl.evaluation.evaluate` of the policy the agent evaluates and saves,
        in the run's scenario and world."""
        return evaluate(
            self.agent.policy,
            self.cfg.scenario,
            episodes,
            seed=seed,
            device=self.cfg.device,
            **kwargs,
            **self.env_kwargs,
        )

    def periodic_eval(self) -> dict[str, float]:
        m = self._evaluate(self.cfg.eval_episodes, 1_000_000 + self.frames)
        self.last_success = m["success_rate"]
        if self.cfg.keep_best:
            self._keep_candidate(m["success_rate"])
        return {
            "eval/success_rate": m["success_rate"],
            "eval/total_reward": m["total_reward"]["mean"],
            "eval/episode_time_s": m["time_all_s"]["mean"],
        }

    @property
    def best(self) -> dict | None:
        """The best periodic evaluation kept so far (``keep_best``), or None."""
        return self.candidates[0] if self.candidates else None

    def _keep_candidate(self, success: float) -> None:
        if len(self.candidates) >= self.cfg.keep_candidates and not (
            success > self.candidates[-1]["success"]
        ):
            return
        actor = {k: v.detach().cpu().clone() for k, v in self.agent.policy.state_dict().items()}
        self.candidates.append({"success": success, "frames": self.frames, "actor": actor})
        self.candidates.sort(key=lambda c: -c["success"])  # stable: earlier first on ties
        del self.candidates[self.cfg.keep_candidates :]

    def _select_candidate(self) -> dict:
        """Load the kept actor to end with into ``agent.policy``; returns what the summary and
        the policy file record of the choice. With several candidates, each is scored on the
        same ``select_episodes`` validation episodes (seed :data:`SELECT_SEED` + the run's
        seed) and the best success rate wins (the higher mean reward on a tie, then the
        better periodic evaluation)."""
        cfg, chosen = self.cfg, self.candidates[0]
        record = {}
        if len(self.candidates) > 1:
            start, scores = time.perf_counter(), []
            for candidate in self.candidates:
                self.agent.policy.load_state_dict(candidate["actor"])
                m = self._evaluate(cfg.select_episodes, SELECT_SEED + cfg.seed)
                scores.append((m["success_rate"], m["total_reward"]["mean"]))
            top = max(range(len(scores)), key=lambda i: (*scores[i], -i))
            chosen = self.candidates[top]
            record = {
                "policy_validation_success_rate": scores[top][0],
                "selection_wall_clock_s": time.perf_counter() - start,
                "selection": [
                    {
                        "frames": c["frames"],
                        "periodic_success_rate": c["success"],
                        "validation_success_rate": score[0],
                        "validation_total_reward": score[1],
                    }
                    for c, score in zip(self.candidates, scores, strict=True)
                ],
            }
        self.agent.policy.load_state_dict(chosen["actor"])
        return {
            "policy_from_frames": chosen["frames"],
            "policy_periodic_success_rate": chosen["success"],
            **record,
        }

    # -- the loop --------------------------------------------------------------------------
    def _collector(self, env) -> Collector:
        # the collector counts transitions: one per action_repeat env steps
        cfg, repeat = self.cfg, self.cfg.action_repeat
        if cfg.algo == "ppo":
            frames_per_batch = cfg.num_envs * cfg.steps_per_env
            random_frames = 0
        else:
            frames_per_batch = max(
                cfg.num_envs, cfg.frames_per_batch // repeat // cfg.num_envs * cfg.num_envs
            )
            random_frames = -(-max(0, cfg.start_steps - self.frames) // repeat)
            random_frames = -(-random_frames // frames_per_batch) * frames_per_batch
        remaining = -(-(cfg.total_steps - self.frames) // repeat)
        return Collector(
            env,
            self.agent.exploration_policy,
            frames_per_batch=frames_per_batch,
            total_frames=-(-remaining // frames_per_batch) * frames_per_batch,
            init_random_frames=random_frames,
            exploration_type=ExplorationType.RANDOM,
            device=cfg.device,
            auto_register_policy_transforms=False,
        )

    def run(self, logger: RunLogger) -> None:
        cfg = self.cfg
        kwargs = dict(self.env_kwargs)
        kwargs["config"] = training_draws(cfg, kwargs["config"])
        env = make_env(
            cfg.scenario,
            cfg.num_envs,
            seed=cfg.seed * 1_000_003 + self.frames,
            device=cfg.device,
            compile=cfg.compile,
            transforms=training_transforms(cfg),
            **kwargs,
        )
        collector = self._collector(env)
        bar = None
        if self.progress:
            from tqdm.auto import tqdm

            bar = tqdm(
                total=cfg.total_steps,
                initial=self.frames,
                unit="step",
                desc=cfg.algo,
                dynamic_ncols=True,
            )
        started = time.perf_counter() - self.elapsed
        stops = _StopRequests()
        try:
            stops.install()
            for data in collector:
                if self.frames >= cfg.total_steps:
                    break
                # env steps: action_repeat per transition (fewer where an episode ended
                # during the repeat; counted in full, as the batch stepped them)
                batch_frames = data.numel() * cfg.action_repeat
                self.frames += batch_frames
                metrics = self._train_on(data, batch_frames)
                done = data["next", "done"].squeeze(-1)
                if bool(done.any()):
                    self.episodes += int(done.sum())
                    metrics["train/episode_reward"] = float(
                        data["next", "episode_reward"][done].mean()
                    )
                    metrics["train/success_rate"] = 100.0 * float(
                        data["next", "success"][done].float().mean()
                    )
                self.elapsed = time.perf_counter() - started
                metrics.update(
                    {
                        "train/episodes": self.episodes,
                        "time/elapsed_s": self.elapsed,
                        "time/steps_per_s": self.frames / max(self.elapsed, 1e-9),
                        "time/updates": self.agent.updates,
                    }
                )
                if self.frames >= self.next_eval:
                    metrics.update(self.periodic_eval())
                    while self.next_eval <= self.frames:
                        self.next_eval += cfg.eval_every
                logger.log(metrics, self.frames)
                if bar is not None:
                    bar.update(batch_frames)
                    bar.set_postfix(
                        sps=f"{metrics['time/steps_per_s']:.0f}",
                        success=f"{self.last_success:.0f}%",
                    )
                due = self.next_checkpoint is not None and self.frames >= self.next_checkpoint
                while due and self.next_checkpoint <= self.frames:
                    self.next_checkpoint += cfg.checkpoint_every
                stopping = stops.signum is not None and self.frames < cfg.total_steps
                if due or stopping:
                    self.save_checkpoint()
                    logger.flush()
                if stopping:
                    raise TrainingInterrupted(stops.signum, self.frames, self.run_dir)
                if self.out_of_time:
                    break
        finally:
            stops.restore()
            collector.shutdown()
            if bar is not None:
                bar.close()

    def _train_on(self, data, batch_frames: int) -> dict[str, float]:
        """Update on a collected batch of ``batch_frames`` env steps (already counted)."""
        cfg = self.cfg
        if cfg.algo == "ppo":
            progress = (self.frames - batch_frames) / cfg.total_steps
            losses = self.agent.learn(data, progress=progress)
        else:
            learning_frames = self.frames - cfg.start_steps
            target = int(cfg.updates_per_step * learning_frames) if learning_frames > 0 else 0
            losses = self.agent.learn(data, num_updates=max(0, target - self.agent.updates))
        return {f"losses/{k}": v for k, v in losses.items()}

    def finish(self, logger: RunLogger) -> dict:
        cfg = self.cfg
        chosen = {}
        if cfg.keep_best and self.candidates:
            chosen = self._select_candidate()
        save_policy(
            self.run_dir / "policy.pt",
            self.agent.policy,
            cfg,
            self.obs_dim,
            self.action_spec,
            self.max_dist,
            filter_params=self.env_kwargs.get("filter_params"),
            frames=self.frames,
            **chosen,
        )
        start = time.perf_counter()
        final = self._evaluate(cfg.final_eval_episodes, cfg.seed + 10_000, progress=self.progress)
        final.update(algo=cfg.algo, policy=str(self.run_dir / "policy.pt"), command=self.command)
        write_json(self.run_dir / "eval.json", final)
        summary = {
            "algo": cfg.algo,
            "scenario": cfg.scenario,
            "frames": self.frames,
            "num_envs": cfg.num_envs,
            "updates": self.agent.updates,
            "train_wall_clock_s": self.elapsed,
            "stopped_by_time_budget": self.frames < cfg.total_steps and self.out_of_time,
            "final_eval_wall_clock_s": time.perf_counter() - start,
            "success_rate": final["success_rate"],
            **chosen,
            "machine": describe_machine(cfg.device),
            "command": self.command,
            "code": code_version(),
        }
        write_json(self.run_dir / "summary.json", summary)
        logger.log(
            {
                "eval/final_success_rate": final["success_rate"],
                "eval/final_total_reward": final["total_reward"]["mean"],
            },
            self.frames,
        )
        plot_run(self.run_dir)
        logger.finish(summary)
        return {"summary": summary, "eval": final}


def plot_run(run_dir: str | Path) -> Path | None:
    """Learning curve of a run (Figures 6-8 style) from its ``curves.csv``."""
    from dockingrl.plots import plot_learning_curve

    run_dir = Path(run_dir)
    curves = read_curves(run_dir)
    if "eval/total_reward" not in curves:
        return None
    steps = [s for s, _ in curves["eval/total_reward"]]
    summary_path = run_dir / "summary.json"
    footer = ""
    if summary_path.exists():
        s = json.loads(summary_path.read_text())
        footer = (
            f"{s['command']}  |  {s['machine']}  |  train {s['train_wall_clock_s']:.0f} s, "
            f"final success {s['success_rate']:.1f} %"
        )
    return plot_learning_curve(
        steps,
        [v for _, v in curves["eval/total_reward"]],
        [v for _, v in curves["eval/episode_time_s"]],
        run_dir / "learning_curve.png",
        success=[v for _, v in curves["eval/success_rate"]],
        title=run_dir.name,
        footer=footer,
    )


#: what a resumed run may change: where and how fast it runs, not what it learns, how long it
#: goes on (``total_steps``: a finished run can be continued to a larger total), and how it
#: chooses the actor it ends with (``keep_candidates``, ``select_episodes``)
RESUME_OVERRIDES = ("threads", "device", "total_steps", "keep_candidates", "select_episodes")
#: the overrides that config.json records (the others change how, not what, the run computes)
_RECORDED_OVERRIDES = ("total_steps", "keep_candidates", "select_episodes")


def train(
    cfg: TrainConfig | None,
    *,
    resume: str | Path | None = None,
    progress: bool = True,
    command: str = "",
    overrides: dict | None = None,
) -> dict:
    """Train ``cfg.algo`` on ``cfg.scenario``; returns ``{"summary", "eval", "run_dir"}``.

    The run folder (``cfg.out / run_name``) receives ``config.json``, ``curves.csv``, the logger's
    files, ``checkpoints/`` (every ``checkpoint_every`` steps, atomic), and at the end
    ``policy.pt`` (for ``dockingrl eval --policy``), ``eval.json`` (the final evaluation),
    ``summary.json`` and ``learning_curve.png``.

    Args:
        resume: a run folder whose latest checkpoint to continue from, to the same
            ``total_steps`` (its ``config.json`` is used; ``cfg`` is ignored).
        overrides: with ``resume``, new values of :data:`RESUME_OVERRIDES` (threads, device,
            total_steps, keep_candidates, select_episodes). A new ``total_steps`` continues the
            run, finished or not, to that total (not below its checkpoint). With ``keep_best``
            the final policy is chosen among the best periodic actors of the whole run; a new
            ``keep_candidates`` keeps that many from the checkpoint's on (a checkpoint holds
            only those it was asked to keep). ``config.json`` records these three. PPO's
            linear learning-rate schedule is tied to the total, so that run's total cannot
            change.
    """
    if resume is not None:
        run_dir = Path(resume)
        if not (run_dir / "config.json").exists():
            raise FileNotFoundError(f"{run_dir} holds no run (no config.json) to resume")
        saved = json.loads((run_dir / "config.json").read_text())
        cls = CONFIGS[saved["algo"]]
        names = {f.name for f in fields(cls)}
        saved = {k: (tuple(v) if k == "hidden" else v) for k, v in saved.items() if k in names}
        overrides = dict(overrides or {})
        if overrides.get("algo") == saved["algo"]:
            del overrides["algo"]
        changed = sorted(set(overrides) - set(RESUME_OVERRIDES))
        if changed:
            raise ValueError(
                f"a resumed run keeps its config; only {', '.join(RESUME_OVERRIDES)} may change, "
                f"not {', '.join(changed)}"
            )
        for name in _RECORDED_OVERRIDES:
            if name in overrides and overrides[name] == saved.get(name):
                del overrides[name]
        if "total_steps" in overrides and saved.get("lr_schedule", "constant") != "constant":
            raise ValueError(
                f"the run's lr_schedule {saved['lr_schedule']!r} anneals to its total_steps "
                f"({saved['total_steps']}), which therefore cannot change"
            )
        cfg = cls(**{**saved, **overrides})
        cfg.validate()
    elif overrides:
        raise ValueError("overrides apply to a resumed run only; set them in cfg")
    else:
        cfg.validate()
        run_dir = Path(cfg.out) / (cfg.run_name or default_run_name(cfg))
        run_dir.mkdir(parents=True, exist_ok=True)
    with RunLock(run_dir):
        if resume is None:
            if (run_dir / "config.json").exists():
                raise FileExistsError(f"{run_dir} already holds a run: pass --resume {run_dir}")
            write_json(run_dir / "config.json", cfg.to_dict())
        return _train_locked(cfg, run_dir, resume, progress, command, overrides or {})


class RunInUse(RuntimeError):
    """Another process is training in the run folder."""


class RunLock:
    """An exclusive lock on a run folder (``run.lock``, ``flock``) for as long as a process
    trains in it; the operating system releases it when the process dies, however it dies."""

    def __init__(self, run_dir: Path) -> None:
        self.path = Path(run_dir) / "run.lock"
        self._file = None

    def __enter__(self) -> RunLock:
        import fcntl

        self._file = self.path.open("a")
        try:
            fcntl.flock(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._file.close()
            raise RunInUse(f"{self.path.parent} is in use by another training process") from None
        self._file.truncate(0)
        self._file.write(f"{os.getpid()}\n")
        self._file.flush()
        return self

    def __exit__(self, *exc) -> None:
        self._file.close()


def code_version() -> dict:
    """The git commit of the dockingrl source that runs, and whether the package's tracked
    files differ from it (``dirty``; results and docs do not count); ``commit`` is None outside
    a git checkout."""
    import subprocess

    root = Path(__file__).resolve().parent.parent
    try:

        def git(*args: str) -> str:
            return subprocess.run(
                ["git", "-C", str(root), *args], capture_output=True, text=True, check=True
            ).stdout.strip()

        return {
            "commit": git("rev-parse", "HEAD"),
            "dirty": bool(git("status", "--porcelain", "-uno", "--", "dockingrl")),
        }
    except (OSError, subprocess.CalledProcessError):
        return {"commit": None, "dirty": None}


def _train_locked(cfg, run_dir, resume, progress, command, overrides) -> dict:
    trainer = Trainer(cfg, run_dir, progress=progress, command=command)
    if resume is not None:
        # a run that stopped before its first checkpoint starts again from its config
        if trainer.load_checkpoint() and "total_steps" in overrides:
            # the last batch may overshoot the total: only a new total below it is refused
            if cfg.total_steps < trainer.frames:
                raise ValueError(
                    f"total_steps {cfg.total_steps} is below the checkpoint's {trainer.frames} "
                    "env steps"
                )
        if set(overrides) & set(_RECORDED_OVERRIDES):
            write_json(run_dir / "config.json", cfg.to_dict())
        trainer._drop_curves_after(trainer.frames)
    logger = RunLogger(
        cfg.to_dict(),
        cfg.logger,
        run_dir,
        trainer.run_id,
        cfg.wandb_online,
        buffered=cfg.checkpoint_every > 0,
    )
    logger.sync()
    if trainer.frames < cfg.total_steps and not trainer.out_of_time:
        try:
            trainer.run(logger)
        except TrainingInterrupted:
            logger.finish({"interrupted_at_frames": trainer.frames})
            raise
    result = trainer.finish(logger)
    result["run_dir"] = str(run_dir)
    return result


__all__ = [
    "RESUME_OVERRIDES",
    "RunInUse",
    "RunLock",
    "RunLogger",
    "Trainer",
    "TrainingInterrupted",
    "plot_run",
    "read_curves",
    "train",
]
