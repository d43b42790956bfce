"""The run's fields of the training config: how long and how wide it trains, its evaluations,
which actor it ends with, its checkpoints, logs, threads and device."""

from __future__ import annotations

from dataclasses import dataclass

from dockingrl.agents.option_fields import check_ranges, documented, refuse
from dockingrl.env.bounds import MAX_BATCH, MAX_SEED

LOGGERS = ("wandb", "csv", "none")


@dataclass
class RunOptions:
    """How a training run runs; what it learns is in the other groups."""

    total_steps: int = documented(
        "env steps (frames) to train for, all envs counted", default=500_000
    )
    num_envs: int = documented("envs stepped in parallel while collecting", default=1)
    seed: int = documented("seed of networks, exploration and envs", default=0)
    eval_every: int = documented("env steps between periodic evaluations", default=10_000)
    eval_episodes: int = documented("episodes of each periodic evaluation (paper: 10)", default=10)
    final_eval_episodes: int = documented(
        "episodes of the final evaluation (paper: 500)", default=500
    )
    checkpoint_every: int = documented("env steps between checkpoints (0: never)", default=50_000)
    logger: str = documented("wandb (offline unless --wandb-online), csv or none", default="wandb")
    wandb_online: bool = documented("let wandb sync to its servers", default=False)
    out: str = documented("folder that holds the run folders", default="runs")
    run_name: str = documented(
        "run folder name (default: dockingrl__algo__scenario__seed__time)", default=""
    )
    threads: int = documented("torch CPU threads", default=2)
    device: str = documented("torch device", default="cpu")
    compile: bool = documented("torch.compile the env and filter steps", default=False)
    compile_update: bool = documented(
        "torch.compile the gradient step (~20 s to compile)", default=False
    )
    time_budget_s: float = documented(
        "stop once training (periodic evaluations included) has run this many seconds, "
        "before total_steps if need be (0: no limit)",
        default=0.0,
    )
    keep_best: bool = documented(
        "end with the actor of the best periodic evaluation (its episodes never overlap the "
        "final evaluation's) instead of the last one (not in the paper)",
        default=False,
    )
    keep_candidates: int = documented(
        "with keep_best: keep the actors of this many best periodic evaluations; with more "
        "than one, each is evaluated again at the end on select_episodes validation episodes "
        "(one set for all of them, never overlapping the periodic or final evaluations' "
        "episodes) and the run ends with the best of them (not in the paper)",
        default=1,
    )
    select_episodes: int = documented(
        "episodes of the validation that picks among keep_candidates actors", default=500
    )
    actor_average: float = documented(
        "decay of an exponential moving average of the actor's weights, moved after every "
        "actor step; periodic evaluations, keep_best and the saved policy use the averaged "
        "actor, training explores with the live one (0: off; not in the paper)",
        default=0.0,
    )
    init_from: str = documented(
        "a run folder whose latest checkpoint's networks and optimiser moments start this run "
        "(its settings, learning rate, discount, a fixed temperature..., are this run's): "
        "fine-tuning a trained agent on another task, e.g. a stress-ladder level; the env "
        "steps, updates, periodic evaluations and kept actors start anew (not in the paper)",
        default="",
    )
    init_replay: bool = documented(
        "with init_from: start with that run's replay buffer too, so that the agent goes on "
        "learning from the old task's transitions beside the new ones (SAC, TD3)",
        default=False,
    )
    fast_update: bool = documented(
        "faster gradient updates that round differently from the default (same arithmetic, "
        "other kernels and order): fused Adam steps; on a CPU SAC's and TD3's twin critics "
        "in turn, two matrix products each instead of vmap's batched one; PPO's loss without "
        "parameter swaps and its GAE in chunks (not in the paper)",
        default=False,
    )

    def _check_run(self) -> None:
        """Refuse a run field out of its range, naming it."""
        if self.logger not in LOGGERS:
            refuse(self, "logger", f"valid: {', '.join(LOGGERS)}")
        check_ranges(
            self,
            counts=(
                "total_steps",
                "num_envs",
                "eval_episodes",
                "final_eval_episodes",
                "threads",
                "eval_every",
                "keep_candidates",
                "select_episodes",
            ),
            non_negative=("seed", "checkpoint_every", "time_budget_s"),
            flags=("fast_update",),
        )
        if self.seed > MAX_SEED:
            refuse(self, "seed", f"must be <= {MAX_SEED}")
        for name in ("num_envs", "eval_episodes", "final_eval_episodes", "select_episodes"):
            if getattr(self, name) > MAX_BATCH:
                refuse(self, name, f"must be <= {MAX_BATCH}: the envs of one batch")
        if (
            not isinstance(self.run_name, str)
            or any(c in self.run_name for c in "/\\")
            or (self.run_name in (".", ".."))
        ):
            refuse(self, "run_name", "must be a folder name, without / or \\")
        try:
            from dockingrl.env.checks import available_device

            available_device(self.device, here=False)
        except ValueError:
            refuse(self, "device", "expected cpu, cuda[:N] or mps")
        if self.keep_candidates > 1 and not self.keep_best:
            refuse(
                self, "keep_candidates", "chooses among the actors keep_best keeps: set keep_best"
            )
        if not 0.0 <= self.actor_average < 1.0:
            refuse(self, "actor_average", "must lie in [0, 1)")
