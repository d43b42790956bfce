"""The entry point of a run: :func:`train` starts one or resumes one from its checkpoint,
with the few settings a resumed run may change."""

from __future__ import annotations

import json
import shutil
from dataclasses import fields
from pathlib import Path

from dockingrl.agents.config import CONFIGS, TrainConfig, saved_fields
from dockingrl.env.checks import available_device
from dockingrl.io import ArtifactError, file_in_the_way, write_json
from dockingrl.training.logger import RunLogger
from dockingrl.training.run_folder import RunLock, default_run_name
from dockingrl.training.trainer import Trainer, TrainingInterrupted

#: what a resumed run may change: where and how fast it runs, not what it learns, how long it
#: goes on (``total_steps``: a finished run can be continued to a larger total), and how it
#: chooses the actor it ends with (``keep_candidates``, ``select_episodes``)
RESUME_OVERRIDES = ("threads", "device", "total_steps", "keep_candidates", "select_episodes")
#: what every run's config.json holds beside its algo (an eval.json or a summary.json lacks some)
RUN_CONFIG_KEYS = ("scenario", "seed", "total_steps")
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
            only those it was asked to keep). ``config.json`` records these three. A linear
            learning-rate schedule and a ``train_curriculum`` are tied to the total, so such a
            run's total cannot change.
    """
    if resume is not None:
        run_dir = Path(resume)
        if not (run_dir / "config.json").exists():
            raise FileNotFoundError(f"{run_dir} holds no run (no config.json) to resume")
        saved = _saved_config(run_dir / "config.json")
        cls = CONFIGS[saved["algo"]]
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
        if "total_steps" in overrides and saved.get("train_curriculum"):
            raise ValueError(
                f"the run's train_curriculum {saved['train_curriculum']!r} shares out its "
                f"total_steps ({saved['total_steps']}), which therefore cannot change"
            )
        cfg = cls(**{**saved, **overrides})
        try:
            cfg.validate()
        except ValueError as exc:
            raise ValueError(f"{run_dir / 'config.json'}: {exc}") from None
        available_device(cfg.device)
    elif not isinstance(cfg, TrainConfig):
        raise TypeError(
            f"train takes a TrainConfig (load_recipe(NAME).make_config() or make_config(ALGO)), "
            f"not {type(cfg).__name__}"
        )
    elif overrides:
        raise ValueError("overrides apply to a resumed run only; set them in cfg")
    else:
        cfg.validate()
        if cfg.init_replay and not cfg.init_from:
            raise ValueError(
                "init_replay takes the replay buffer of the run that init_from names: "
                "give --init-from RUN_DIR"
            )
        available_device(cfg.device)
        run_dir = Path(cfg.out) / (cfg.run_name or default_run_name(cfg))
        blocker = file_in_the_way(run_dir)
        if blocker == run_dir:
            raise NotADirectoryError(f"{run_dir}: a file, not a run folder")
        if blocker is not None:
            raise NotADirectoryError(f"out {cfg.out}: not a folder ({blocker} is a file)")
        new_folder = not run_dir.exists()
        run_dir.mkdir(parents=True, exist_ok=True)
    with RunLock(run_dir):
        if resume is None:
            if (run_dir / "config.json").exists():
                if (run_dir / "summary.json").exists():
                    more = (
                        f", or continue it with --resume {run_dir} --total-steps N"
                        if _resumable_checkpoint(run_dir)
                        else ""
                    )
                    raise FileExistsError(
                        f"{run_dir} already holds a finished run: train into another --out or "
                        f"--run-name{more}"
                    )
                raise FileExistsError(f"{run_dir} already holds a run: pass --resume {run_dir}")
            write_json(run_dir / "config.json", cfg.to_dict())
            try:
                started = _start(cfg, run_dir, resume, progress, command)
            except BaseException:
                # a run that could not start leaves nothing that a second try would trip on
                if new_folder:
                    shutil.rmtree(run_dir, ignore_errors=True)
                else:
                    (run_dir / "config.json").unlink(missing_ok=True)
                raise
        else:
            started = _start(cfg, run_dir, resume, progress, command)
        return _train_locked(*started, cfg, run_dir, resume, overrides or {})


def _saved_config(path: Path) -> dict:
    """The config fields that a run folder's ``config.json`` saved, checked: a one-line
    ``ValueError`` naming the file when it is not a run's config."""
    try:
        saved = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable run config ({exc})") from None
    if not isinstance(saved, dict) or saved.get("algo") not in CONFIGS:
        raise ValueError(f"{path}: not a run config (no algo of {', '.join(CONFIGS)})")
    lacking = [name for name in RUN_CONFIG_KEYS if name not in saved]
    if lacking:
        raise ValueError(f"{path}: not a run config (no {', '.join(lacking)})")
    names = {f.name for f in fields(CONFIGS[saved["algo"]])}
    saved = {k: v for k, v in saved.items() if k in names}
    try:
        return saved_fields(saved["algo"], saved)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def _start(cfg, run_dir, resume, progress, command) -> tuple[Trainer, bool]:
    """The run's trainer and whether it was restored from a checkpoint (when resumed), else
    warm-started where ``init_from`` asks."""
    if resume is not None:
        _check_resumable(run_dir)
    trainer = Trainer(cfg, run_dir, progress=progress, command=command)
    # a run that stopped before its first checkpoint starts again from its config
    restored = resume is not None and trainer.load_checkpoint()
    if not restored and cfg.init_from:
        trainer.warm_start()
    return trainer, restored


def _resumable_checkpoint(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a checkpoint that ``--resume`` would go on from."""
    from dockingrl.training.checkpointing import latest_checkpoint

    try:
        return latest_checkpoint(run_dir / "checkpoints") is not None
    except ArtifactError:
        return False


def _check_resumable(run_dir: Path) -> None:
    """Refuse to resume a run folder that holds no checkpoint to go on from but whose work a
    start from scratch would overwrite: a finished run (``summary.json``) or checkpoint
    folders without the ``latest.json`` that names the complete one. A run that stopped
    before its first checkpoint (neither) starts again from its config."""
    from dockingrl.training.checkpointing import latest_checkpoint

    root = run_dir / "checkpoints"
    if root.exists() and not root.is_dir():
        raise NotADirectoryError(f"{root}: a file, not the run's checkpoint folder")
    if latest_checkpoint(root) is not None:
        return
    if any(root.glob("step_*")):
        raise ArtifactError(
            f"{root}: holds checkpoint folders but no latest.json naming a complete one; "
            "nothing resumed"
        )
    if (run_dir / "summary.json").exists():
        raise FileExistsError(
            f"{run_dir}: a finished run (summary.json) with no checkpoint to resume from; "
            "train anew into another folder"
        )


def _train_locked(trainer, restored, cfg, run_dir, resume, overrides) -> dict:
    if resume is not None:
        if restored and "total_steps" in overrides:
            # the last batch may overshoot the total: only a new total below it is refused
            if cfg.total_steps < trainer.frames:
                raise ValueError(
                    f"total_steps {cfg.total_steps} is below the checkpoint's {trainer.frames} "
                    "env steps"
                )
        if set(overrides) & set(_RECORDED_OVERRIDES):
            write_json(run_dir / "config.json", cfg.to_dict())
        trainer.checkpoints.drop_curves_after(trainer.frames)
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
