"""What SAC and TD3 share: the replay buffer and what it stores (mirrored and n-step
transitions included), the twin Q-networks' wiring, their optimisers and target updater, and
the loop of updates after each collection."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Bounded, LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import RandomSampler
from torchrl.objectives import LossModule

from dockingrl.agents.base import Agent, adam, scalar, schedule_lr
from dockingrl.agents.config import OffPolicyConfig, TrainConfig
from dockingrl.agents.mirror import config_mirror_signs, mirror_transitions
from dockingrl.agents.networks import PRIVILEGED_KEYS, make_critic, stochastic_actor
from dockingrl.agents.nstep import NStepWindow
from dockingrl.agents.off_policy_options import OffPolicyOptions
from dockingrl.agents.run_options import RunOptions
from dockingrl.agents.torchrl_adapter import ForeachSoftUpdate

#: what an off-policy replay buffer stores of each transition
TRANSITION_KEYS = (
    "observation",
    "action",
    ("next", "observation"),
    ("next", "reward"),
    ("next", "done"),
    ("next", "terminated"),
    ("next", "truncated"),
)


def transition_keys(cfg: TrainConfig) -> tuple:
    """What the replay buffer of ``cfg`` stores of each transition: ``TRANSITION_KEYS``, and
    ``PRIVILEGED_KEYS`` of both steps for a privileged critic."""
    if not getattr(cfg, "privileged_critic", False):
        return TRANSITION_KEYS
    return TRANSITION_KEYS + PRIVILEGED_KEYS + tuple(("next", k) for k in PRIVILEGED_KEYS)


def vmap_ensembles(cfg: RunOptions) -> bool:
    """Whether the twin critics run through ``torch.vmap`` (one batched matrix product per
    layer, TorchRL's default) rather than one after the other. With ``fast_update`` on a CPU
    they run one after the other: the batched products (``bmm``) of an update took 1.7x the
    time of the plain ones at the paper's sizes, 1 thread (other roundings, hence opt-in)."""
    return not (cfg.fast_update and torch.device(cfg.device).type == "cpu")


def replay_buffer(cfg: OffPolicyOptions, device) -> TensorDictReplayBuffer:
    """A uniformly sampled replay buffer of ``cfg.buffer_size`` transitions on ``device``."""
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(cfg.buffer_size, device=device),
        sampler=RandomSampler(),
        batch_size=cfg.batch_size,
    )


@dataclass
class OffPolicyAgent(Agent):
    """An agent that stores what it collects in a replay buffer and samples its updates from
    it. A subclass gives its loss (:meth:`make_loss`), its exploration policy and
    :meth:`_update`, one gradient step on a sampled batch."""

    #: the n-step window over successive collections (``n_steps``)
    window: NStepWindow | None = None

    def __post_init__(self) -> None:
        if self.window is None:
            self.window = NStepWindow(self.config.n_steps, self.config.gamma)
        if self.config.reset_every:
            built = self.loss.state_dict()
            self.extra["built"] = {k: v.detach().clone() for k, v in built.items()}

    def reset_networks(self) -> None:
        """Put the actor, the critics, their targets (the loss's learned temperature too) back
        to the weights this agent was built with, in place, and clear the optimisers'
        moments; the replay buffer and the update count stay (``reset_every``, Nikishin et
        al., ICML 2022). A resumed run builds the same weights from its seed."""
        if "built" not in self.extra:
            raise ValueError("reset_networks needs an agent built with reset_every > 0")
        self.loss.load_state_dict(self.extra["built"])
        for optimizer in self.optimizers.values():
            optimizer.state.clear()

    @classmethod
    def build(cls, cfg, actor, action_spec, obs_dim, scale, max_dist, device) -> Agent:
        act_dim = action_spec.shape[-1]
        qvalue = make_critic(cfg, obs_dim, act_dim, scale, max_dist).to(device)
        exploration = cls.make_exploration(cfg, actor, action_spec, device)
        loss = cls.make_loss(cfg, actor, qvalue, action_spec)
        loss.make_value_estimator(gamma=cfg.gamma)
        optimizers = {
            "actor": adam(loss.actor_network_params.flatten_keys().values(), cfg),
            "critic": adam(loss.qvalue_network_params.flatten_keys().values(), cfg),
            **cls.more_optimizers(cfg, loss),
        }
        return cls(
            cfg,
            actor,
            exploration,
            loss,
            optimizers,
            ForeachSoftUpdate(loss, tau=cfg.tau),
            replay_buffer(cfg, device),
        )

    @classmethod
    def make_actor(cls, cfg: OffPolicyConfig, obs_dim, action_spec, scale, mirror):
        """A Tanh-Normal policy (SAC's; TD3 overrides it)."""
        return stochastic_actor(obs_dim, action_spec, cfg.hidden, scale, mirror=mirror)

    def learn_batch(self, data: TensorDictBase, frames: int, batch_frames: int) -> dict:
        """Up to ``updates_per_step`` updates per env step after ``start_steps``, the networks
        reset first where a multiple of ``reset_every`` falls within the batch."""
        cfg = self.config
        if resets_before(cfg, frames, batch_frames):
            self.reset_networks()
        learning_frames = frames - cfg.start_steps
        target = int(cfg.updates_per_step * learning_frames) if learning_frames > 0 else 0
        progress = (frames - batch_frames) / cfg.total_steps
        return self.learn(data, num_updates=max(0, target - self.updates), progress=progress)

    def random_steps(self, frames: int) -> int:
        return max(0, self.config.start_steps - frames)

    @classmethod
    def make_exploration(
        cls, cfg: OffPolicyConfig, actor: nn.Module, action_spec: Bounded, device
    ) -> nn.Module:
        """The policy that collects: the actor itself unless a subclass adds noise."""
        return actor

    @classmethod
    def make_loss(
        cls,
        cfg: OffPolicyConfig,
        actor: nn.Module,
        qvalue: TensorDictModule,
        action_spec: Bounded,
    ) -> LossModule:
        """The TorchRL loss over ``actor`` and two copies of ``qvalue``."""
        raise NotImplementedError(f"{cls.__name__} has no loss")

    @classmethod
    def more_optimizers(cls, cfg: OffPolicyConfig, loss: LossModule) -> dict:
        """Optimisers besides the actor's and the critics' (none unless a subclass adds)."""
        return {}

    def learn(
        self, data: TensorDictBase, num_updates: int = 0, progress: float = 0.0
    ) -> dict[str, float]:
        """Store ``data`` (``(num_envs, T)``; mirrored too with ``mirror_augment``) and run
        ``num_updates`` updates at the rate of ``lr_schedule`` at ``progress`` (the fraction of
        ``total_steps`` done before ``data``). Returns mean losses (``losses/...``)."""
        schedule_lr(self.optimizers.values(), self.config, progress)
        transitions = self.window(data.select(*transition_keys(self.config))).reshape(-1)
        self.replay_buffer.extend(transitions)
        if self.config.mirror_augment:
            signs = config_mirror_signs(self.config)
            self.replay_buffer.extend(mirror_transitions(transitions, signs))
        logs: dict[str, list[float]] = {}
        for _ in range(num_updates):
            for key, value in self._off_policy_update().items():
                logs.setdefault(key, []).append(value)
        return {k: sum(v) / len(v) for k, v in logs.items()}

    def restart_episodes(self) -> None:
        """Drop the steps the n-step window holds: the new env's episodes do not continue
        them."""
        self.window.tail = None

    def _off_policy_update(self) -> dict[str, float]:
        """One update on a batch sampled from the replay buffer."""
        # the size asked each time: a loaded buffer (a resumed or warm-started run's) takes
        # back the batch size it was saved with, which a warm start may have changed
        batch = self.replay_buffer.sample(self.config.batch_size)
        self.updates += 1
        return {k: scalar(v) for k, v in self._update(batch).items()}

    def _update(self, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """The gradient steps of one update on ``batch``; returns the logged values."""
        raise NotImplementedError(f"{type(self).__name__} has no update")


def resets_before(cfg: OffPolicyConfig, frames: int, batch_frames: int) -> bool:
    """Whether the off-policy agent resets its networks before learning on the batch that
    brings the run to ``frames`` env steps: a multiple of ``reset_every`` falls within the
    batch, and the batch is not the run's last."""
    every = cfg.reset_every
    if not every or frames >= cfg.total_steps:
        return False
    return frames // every > (frames - batch_frames) // every
