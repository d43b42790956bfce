"""The training loop shared by SAC, TD3 and PPO: collect a batch, update on it, evaluate,
log and checkpoint, until the run's ``total_steps`` or time budget."""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
from pathlib import Path

import torch

from dockingrl.agents import Agent, make_agent
from dockingrl.agents.config import TrainConfig
from dockingrl.agents.saving import save_policy
from dockingrl.evaluation.machine import describe_machine, note_shared_cores
from dockingrl.evaluation.protocol import FINAL_EVAL_OFFSET
from dockingrl.io import write_json
from dockingrl.training.checkpointing import Checkpoints, RunProgress
from dockingrl.training.collection import (
    env_shapes,
    episode_metrics,
    make_collector,
    training_env,
)
from dockingrl.training.logger import RunLogger, plot_run
from dockingrl.training.options import env_kwargs, stage_at
from dockingrl.training.run_folder import code_version
from dockingrl.training.selection import Selection


class TrainingInterrupted(Exception):
    """A run stopped by SIGTERM or SIGINT after checkpointing its last whole batch: nothing
    trained is lost, and ``--resume`` continues it."""

    def __init__(self, signum: int, frames: int, run_dir: Path) -> None:
        self.signum, self.frames, self.run_dir = signum, frames, run_dir
        super().__init__(
            f"stopped by {signal.Signals(signum).name} at {frames} env steps, checkpoint "
            f"written; continue with: dockingrl train --resume {run_dir}"
        )


class StopRequests:
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


class Trainer:
    """Trains one agent on one scenario; see :func:`~dockingrl.training.train`. What it has
    done is its ``progress`` (:class:`RunProgress`), its evaluations and kept actors its
    ``selection`` (:class:`Selection`), its checkpoints its ``checkpoints``
    (:class:`Checkpoints`), all three over the same agent and counters."""

    def __init__(
        self, cfg: TrainConfig, run_dir: Path, *, progress: bool = True, command: str = ""
    ) -> None:
        self.cfg, self.run_dir, self.show_progress, self.command = cfg, run_dir, progress, command
        note_shared_cores(cfg.threads)
        torch.set_num_threads(cfg.threads)
        self.run_id = run_dir.name.replace("__", "-")[-60:]
        #: the source this process trains with (read now: the checkout may move on during a
        #: long run) and, from a resumed checkpoint, what the run's earlier processes ran
        self.code = code_version()
        self.progress = RunProgress(
            next_eval=cfg.eval_every,
            next_checkpoint=cfg.checkpoint_every or None,
            codes=[self.code],
        )
        self.env_kwargs = env_kwargs(cfg)
        #: the env of the stage at ``frames`` 0, built once: the agent is sized from it and a
        #: new run trains in it (a resumed run builds the env of the step it resumes at)
        self._first_env = training_env(cfg, self._stage_kwargs(stage_at(cfg, 0)[0]), 0)
        self.obs_dim, self.action_spec, self.max_dist = env_shapes(self._first_env)
        torch.manual_seed(cfg.seed)
        self.agent: Agent = make_agent(
            cfg, self.obs_dim, self.action_spec, self.max_dist, cfg.device
        )
        self.selection = Selection(self.agent, cfg, self.env_kwargs)
        self.checkpoints = Checkpoints(
            run_dir, cfg, self.agent, self.progress, self.selection, self.code
        )

    @property
    def frames(self) -> int:
        """The env steps trained so far."""
        return self.progress.frames

    @property
    def candidates(self) -> list[dict]:
        """The actors kept for ``keep_best`` (:attr:`Selection.candidates`)."""
        return self.selection.candidates

    def load_checkpoint(self) -> bool:
        """Restore the run's latest checkpoint (:meth:`Checkpoints.load`)."""
        return self.checkpoints.load()

    def warm_start(self) -> dict:
        """Start from ``init_from``'s agent (:meth:`Checkpoints.warm_start`)."""
        return self.checkpoints.warm_start()

    @property
    def out_of_time(self) -> bool:
        """Whether ``time_budget_s`` (if any) is spent."""
        return 0 < self.cfg.time_budget_s <= self.progress.elapsed

    def run(self, logger: RunLogger) -> None:
        """Train from ``frames`` to ``total_steps`` (or the time budget), logging each batch,
        one stage of ``train_curriculum`` after another; a stop request ends it after a
        checkpoint with :class:`TrainingInterrupted`."""
        cfg = self.cfg
        bar = None
        if self.show_progress:
            from tqdm.auto import tqdm

            bar = tqdm(
                total=cfg.total_steps,
                initial=self.progress.frames,
                unit="step",
                desc=cfg.algo,
                dynamic_ncols=True,
            )
        #: the clock's zero: ``elapsed`` counts training, not the set-up of the envs
        self.started = time.perf_counter() - self.progress.elapsed
        stops = StopRequests()
        try:
            stops.install()
            while self.progress.frames < cfg.total_steps and not self.out_of_time:
                level, until = stage_at(cfg, self.progress.frames)
                self._run_stage(logger, level, until, stops, bar)
        finally:
            stops.restore()
            if bar is not None:
                bar.close()

    def _stage_kwargs(self, level: str) -> dict:
        """The env options of the world at ``level``: the curriculum's world for its stage,
        the run's own at ``train_level``."""
        return self.env_kwargs if level == self.cfg.train_level else env_kwargs(self.cfg, level)

    def _run_stage(self, logger, level, until, stops, bar) -> None:
        """Collect and learn in the world of ``level`` from ``frames`` to ``until`` env steps
        (the batch that reaches it included), or to the time budget or a stop request."""
        cfg = self.cfg
        set_up = time.perf_counter()
        env, self._first_env = self._first_env, None
        if env is None or self.progress.frames > 0:
            env = training_env(cfg, self._stage_kwargs(level), self.progress.frames)
        collector = make_collector(
            cfg,
            env,
            self.agent.exploration_policy,
            self.progress.frames,
            until,
            random_steps=self.agent.random_steps(self.progress.frames),
        )
        self.agent.restart_episodes()
        self.started += time.perf_counter() - set_up
        try:
            for data in collector:
                # env steps: action_repeat per transition (fewer where an episode ended
                # during the repeat; counted in full, as the batch stepped them)
                batch_frames = data.numel() * cfg.action_repeat
                self.progress.frames += batch_frames
                losses = self.agent.learn_batch(data, self.progress.frames, batch_frames)
                metrics = {f"losses/{k}": v for k, v in losses.items()}
                ended, ended_metrics = episode_metrics(data)
                self.progress.episodes += ended
                metrics.update(ended_metrics)
                self.progress.elapsed = time.perf_counter() - self.started
                metrics.update(
                    {
                        "train/episodes": self.progress.episodes,
                        "time/elapsed_s": self.progress.elapsed,
                        "time/steps_per_s": self.progress.frames / max(self.progress.elapsed, 1e-9),
                        "time/updates": self.agent.updates,
                    }
                )
                if self.progress.frames >= self.progress.next_eval:
                    metrics.update(self.selection.periodic_eval(self.progress.frames))
                    while self.progress.next_eval <= self.progress.frames:
                        self.progress.next_eval += cfg.eval_every
                logger.log(metrics, self.progress.frames)
                if bar is not None:
                    bar.update(batch_frames)
                    bar.set_postfix(progress_fields(metrics, self.selection.last_success))
                due = self.checkpoints.due()
                stopping = stops.signum is not None and self.progress.frames < cfg.total_steps
                if due or stopping:
                    self.checkpoints.save()
                    logger.flush()
                if stopping:
                    raise TrainingInterrupted(stops.signum, self.progress.frames, self.run_dir)
                if self.out_of_time or self.progress.frames >= until:
                    break
        finally:
            collector.shutdown()

    def finish(self, logger: RunLogger) -> dict:
        """End the run: the kept actor chosen (``keep_best``), ``policy.pt``, the final
        evaluation (``eval.json``), ``summary.json`` and the learning curve; returns
        ``{"summary", "eval"}``."""
        cfg = self.cfg
        chosen = {}
        if cfg.keep_best and self.selection.candidates:
            chosen = self.selection.select_candidate()
        save_policy(
            self.run_dir / "policy.pt",
            self.agent.policy,
            cfg,
            self.obs_dim,
            self.action_spec,
            self.max_dist,
            filter_params=self.env_kwargs.get("filter_params"),
            frames=self.progress.frames,
            **chosen,
        )
        start = time.perf_counter()
        seed = cfg.seed + FINAL_EVAL_OFFSET
        final = self.selection.evaluate(cfg.final_eval_episodes, seed, progress=self.show_progress)
        final.update(
            algo=cfg.algo,
            level=cfg.train_level,  # the world of the final evaluation: the run's own
            policy=str(self.run_dir / "policy.pt"),
            command=self.command,
        )
        write_json(self.run_dir / "eval.json", final)
        summary = {
            "algo": cfg.algo,
            "scenario": cfg.scenario,
            "frames": self.progress.frames,
            "num_envs": cfg.num_envs,
            "updates": self.agent.updates,
            "train_wall_clock_s": self.progress.elapsed,
            "stopped_by_time_budget": self.progress.frames < cfg.total_steps and self.out_of_time,
            "final_eval_wall_clock_s": time.perf_counter() - start,
            "success_rate": final["success_rate"],
            **chosen,
            "machine": describe_machine(cfg.device),
            "command": self.command,
            "code": self.code,
            **({"code_history": self.progress.codes} if len(self.progress.codes) > 1 else {}),
        }
        write_json(self.run_dir / "summary.json", summary)
        logger.log(
            {
                "eval/final_success_rate": final["success_rate"],
                "eval/final_total_reward": final["total_reward"]["mean"],
            },
            self.progress.frames,
        )
        plot_run(self.run_dir)
        logger.finish(summary)
        return {"summary": summary, "eval": final}


def progress_fields(metrics: dict, last_success: float) -> dict:
    """The progress bar's fields: env steps per second, and the last periodic evaluation's
    success once one has run."""
    fields = {"sps": f"{metrics['time/steps_per_s']:.0f}"}
    if not math.isnan(last_success):
        fields["success"] = f"{last_success:.0f}%"
    return fields
