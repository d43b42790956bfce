"""The :class:`Agent` every algorithm builds: its modules, its update rule and its checkpoint
state."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import Bounded, TensorDictReplayBuffer
from torchrl.objectives import SoftUpdate
from torchrl.objectives.value import GAE

from dockingrl.agents.config import TrainConfig
from dockingrl.agents.networks import ActorAverage
from dockingrl.env.checks import compiled as compiled_step
from dockingrl.io import is_count


@dataclass
class Agent:
    """An algorithm's modules and its update rule: the exploration policy used while
    collecting, the deterministic ``actor`` used in evaluation, and :meth:`learn`, which turns
    collected data into gradient updates (the ``update()`` closure of TorchRL's
    sota-implementations). Each algorithm is a subclass with its own :meth:`build`."""

    config: TrainConfig
    actor: nn.Module  # deterministic under ExplorationType.DETERMINISTIC
    exploration_policy: nn.Module
    loss: nn.Module
    optimizers: dict[str, torch.optim.Optimizer]
    target_updater: SoftUpdate | None = None
    replay_buffer: TensorDictReplayBuffer | None = None
    advantage: GAE | None = None
    updates: int = 0
    extra: dict[str, Any] = field(default_factory=dict)
    #: the exponential moving average of ``actor``'s weights (``actor_average > 0``)
    average: ActorAverage | None = None

    @classmethod
    def build(
        cls,
        cfg: TrainConfig,
        actor: nn.Module,
        action_spec: Bounded,
        obs_dim: int,
        scale: torch.Tensor,
        max_dist: float,
        device: torch.device | str,
    ) -> Agent:
        """The agent of ``cfg`` around ``actor`` (:func:`~dockingrl.agents.networks.build_actor`)
        for observations of ``obs_dim`` numbers scaled by ``scale``."""
        raise NotImplementedError(f"{cls.__name__} has no build")

    @property
    def averaged(self) -> nn.Module | None:
        """The averaged actor (``actor_average > 0``), else ``None``."""
        return None if self.average is None else self.average.module

    @property
    def policy(self) -> nn.Module:
        """The actor to evaluate and save: the averaged one if there is one."""
        return self.actor if self.average is None else self.average.module

    def _average_actor(self) -> None:
        """One step of the averaged actor after an actor step (nothing without one)."""
        if self.average is not None:
            self.average.step()

    def learn(
        self, data: TensorDictBase, num_updates: int = 0, progress: float = 0.0
    ) -> dict[str, float]:
        """Turn ``data`` (``(num_envs, T)``) into updates; returns mean losses (``losses/...``)."""
        raise NotImplementedError(f"{type(self).__name__} has no learn")

    @classmethod
    def make_actor(
        cls, cfg: TrainConfig, obs_dim: int, action_spec: Bounded, scale, mirror
    ) -> nn.Module:
        """The policy network of ``cfg`` (what a saved policy holds) for observations of
        ``obs_dim`` numbers scaled by ``scale``, mirror-symmetric with ``mirror`` signs."""
        raise NotImplementedError(f"{cls.__name__} has no actor")

    def learn_batch(self, data: TensorDictBase, frames: int, batch_frames: int) -> dict:
        """The updates that a collected batch of ``batch_frames`` env steps buys, ``frames``
        counted so far (the batch included), at the learning-rate schedule's share of the run
        done before it. Returns the mean losses."""
        raise NotImplementedError(f"{type(self).__name__} has no learn_batch")

    def random_steps(self, frames: int) -> int:
        """Env steps still to collect with uniformly random actions after ``frames``."""
        return 0

    def restart_episodes(self) -> None:
        """The training env was built anew, its episodes start over: forget what waits for
        their continuation (nothing, unless a subclass carries steps between collections)."""

    def _gradients(self, name: str, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """Forward and backward of one loss (``name``: the ``_grad_<name>`` method); returns
        the detached logged values. With ``compile_update`` each of these runs through
        ``torch.compile`` (built on first use)."""
        compiled = self.extra.setdefault("compiled", {})
        if name not in compiled:
            fn = getattr(self, f"_grad_{name}")
            if self.config.compile_update:
                fn = compiled_step(fn, self.config.device)
            compiled[name] = fn
        return compiled[name](batch)

    # -- checkpoints -----------------------------------------------------------------------
    def state_dict(self) -> dict:
        state = {
            "loss": self.loss.state_dict(),
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "updates": self.updates,
        }
        if "generator" in self.extra:
            state["generator"] = self.extra["generator"].get_state()
        if self.average is not None:
            state["averaged"] = self.average.module.state_dict()
        return state

    def load_state_dict(
        self, state: dict, *, fresh_average: bool = False, own_settings: bool = False
    ) -> None:
        """Load :meth:`state_dict`'s ``state``. ``fresh_average``: where the agent averages its
        actor and ``state`` holds no averaged actor (a run started from one that did not
        average), the average starts at the loaded actor instead of being refused.
        ``own_settings``: this agent keeps its settings and takes only what was learned from
        ``state``, as a run started from another one with other settings needs: the loss
        takes the networks, their targets and the learned parameters (a learned temperature)
        and keeps its own fixed values (a fixed temperature, the target entropy, the
        discount, PPO's coefficients); the optimisers take their moments and keep their
        learning rate, betas, fused... (``load_state_dict`` of a torch module or optimiser
        takes the saved values of all of them). Raises ``ValueError`` (one line naming the
        entry) for a state not of this agent's shapes."""
        self._check_state(state)
        loss = state["loss"]
        if own_settings:
            mine = self.loss.state_dict()
            learned = {name for name, _ in self.loss.named_parameters()}
            loss = {
                k: v if "network_params" in k or k in learned or k not in mine else mine[k]
                for k, v in loss.items()
            }
        self.loss.load_state_dict(loss)
        for k, o in self.optimizers.items():
            own = None
            if own_settings:
                own = [{n: v for n, v in g.items() if n != "params"} for g in o.param_groups]
            o.load_state_dict(state["optimizers"][k])
            if own is not None:
                for group, settings in zip(o.param_groups, own, strict=True):
                    group.update(settings)
        self.updates = state["updates"]
        if "generator" in state:
            self.extra["generator"].set_state(state["generator"])
        if self.average is not None:
            if "averaged" in state:
                self.average.module.load_state_dict(state["averaged"])
            elif fresh_average:
                self.average.module.load_state_dict(self.actor.state_dict())
            else:
                raise ValueError("the agent averages its actor; the state holds no averaged actor")

    def _check_state(self, state) -> None:
        """Refuse a ``state`` whose entries are not those of :meth:`state_dict`'s kinds and
        shapes: torch would broadcast a number into a weight tensor, or skip a ``None``."""
        mine = self.state_dict()
        if not isinstance(state, dict) or not isinstance(state.get("optimizers"), dict):
            raise ValueError("the agent's state must be a dict with a dict of optimizers")
        updates = state.get("updates")
        if not is_count(updates):
            raise ValueError(f"updates must be an integer >= 0 (got {updates!r:.40})")
        for name in self.optimizers:
            if not isinstance(state["optimizers"].get(name), dict):
                raise ValueError(f"optimizers.{name} must be an optimiser's state dict")
        for part in ("loss", "averaged"):
            if part not in mine or part not in state:
                continue
            if not isinstance(state[part], dict):
                raise ValueError(f"{part} must be a dict of tensors")
            for key, own in mine[part].items():
                given = state[part].get(key, own)
                if isinstance(own, torch.Tensor) and not (
                    isinstance(given, torch.Tensor) and given.shape == own.shape
                ):
                    shape = tuple(given.shape) if isinstance(given, torch.Tensor) else given
                    raise ValueError(
                        f"{part}.{key} must be a tensor of shape {tuple(own.shape)} "
                        f"(got {shape!r:.40})"
                    )


def scalar(value: torch.Tensor) -> float:
    """``value`` as a Python float, detached."""
    return float(value.detach())


def schedule_lr(optimizers, cfg: TrainConfig, progress: float) -> float:
    """Set every optimiser of ``optimizers`` to ``cfg.lr`` under ``cfg.lr_schedule`` at
    ``progress`` (the fraction of ``total_steps`` done): the rate itself (``constant``),
    ``cfg.lr * (1 - progress)`` (``linear``, 0 at ``total_steps``) or the rate itself up to
    half of ``total_steps``, then ``cfg.lr * 2 (1 - progress)`` (``late-linear``, 0 at
    ``total_steps``). Returns the rate."""
    lr, done = cfg.lr, min(max(progress, 0.0), 1.0)
    if cfg.lr_schedule == "linear":
        lr = cfg.lr * (1.0 - done)
    elif cfg.lr_schedule == "late-linear":
        lr = cfg.lr * min(1.0, 2.0 * (1.0 - done))
    for optim in optimizers:
        for group in optim.param_groups:
            group["lr"] = lr
    return lr


def adam(params, cfg: TrainConfig) -> torch.optim.Adam:
    """An Adam optimiser over ``params`` at ``cfg.lr``: fused with ``cfg.fast_update`` (about a
    third of the time per step on a CPU; other roundings than the default's per-tensor step)."""
    return torch.optim.Adam(list(params), lr=cfg.lr, fused=True if cfg.fast_update else None)
