"""Training shared by SAC, TD3 and PPO: :func:`train` runs or resumes one, a :class:`Trainer`
collects with TorchRL's ``Collector`` (:mod:`.collection`), has the agent learn on each batch,
evaluates and keeps the best actors (:mod:`.selection`), checkpoints (:mod:`.checkpointing`)
and logs (:mod:`.logger`, wandb offline by default); :mod:`.options` holds what a training
config adds to the env."""

from dockingrl.training.logger import RunLogger, plot_run, read_curves
from dockingrl.training.options import (
    TRAINING_DRAWS,
    env_kwargs,
    training_draws,
    training_transforms,
)
from dockingrl.training.run_folder import RunInUse, RunLock, code_version
from dockingrl.training.runs import RESUME_OVERRIDES, train
from dockingrl.training.trainer import Trainer, TrainingInterrupted

__all__ = [
    "RESUME_OVERRIDES",
    "TRAINING_DRAWS",
    "RunInUse",
    "RunLock",
    "RunLogger",
    "Trainer",
    "TrainingInterrupted",
    "code_version",
    "env_kwargs",
    "plot_run",
    "read_curves",
    "train",
    "training_draws",
    "training_transforms",
]
