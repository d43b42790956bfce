"""What SAC and TD3 share: the replay buffer and what it stores (mirrored and n-step
transitions included), the twin Q-networks' wiring, their optimisers and target updater, and
the loop of updates after each collection."""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass
from itertools import repeat

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictParams
from torch import nn
from torchrl.data import Bounded, LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import RandomSampler
from torchrl.objectives import LossModule, SoftUpdate

from dockingrl.agents.base import Agent, adam, scalar, schedule_lr
from dockingrl.agents.config import OffPolicyConfig, TrainConfig
from dockingrl.agents.mirror import config_mirror_signs, mirror_transitions
from dockingrl.agents.networks import PRIVILEGED_KEYS, make_critic, stochastic_actor
from dockingrl.agents.nstep import NStepWindow
from dockingrl.agents.off_policy_options import OffPolicyOptions
from dockingrl.agents.run_options import RunOptions

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


class ForeachSoftUpdate(SoftUpdate):
    """TorchRL's ``SoftUpdate`` as one ``torch._foreach_lerp_`` over lists of the target and
    source parameters gathered once, instead of gathering them through tensordicts at every
    step: the same numbers, a tenth of the time (0.05 ms instead of 0.5 ms for SAC's critics
    on a 2-core CPU)."""

    _lists: tuple[list, list] | None = None

    def step(self) -> None:
        if self._lists is None:
            keys = list(self._sources.keys(True, True))
            self._lists = (
                [self._targets.get(("target_" + k[0], *k[1:])).data for k in map(_key, keys)],
                [self._sources.get(k).data for k in keys],
            )
        targets, sources = self._lists
        torch._foreach_lerp_(targets, sources, 1 - self.eps)


def _key(key) -> tuple:
    return key if isinstance(key, tuple) else (key,)


def vmap_ensembles(cfg: RunOptions) -> bool:
    """Whether the twin critics run through ``torch.vmap`` (one batched matrix product per
    layer, TorchRL's default) rather than one after the other. With ``fast_update`` on a CPU
    they run one after the other: the batched products (``bmm``) of an update took 1.7x the
    time of the plain ones at the paper's sizes, 1 thread (other roundings, hence opt-in)."""
    return not (cfg.fast_update and torch.device(cfg.device).type == "cpu")


def _slot(module: nn.Module, path: tuple) -> tuple[dict, str]:
    """The parameter or buffer table of ``module``'s submodule at ``path[:-1]`` that holds (or
    would hold) the tensor named ``path[-1]``, and that name (an empty table where the
    submodule is missing)."""
    owner = module
    for part in path[:-1]:
        owner = getattr(owner, part, None)
    table = getattr(owner, "_parameters", {})
    return (table if path[-1] in table else getattr(owner, "_buffers", {})), path[-1]


class CriticsInTurn:
    """What TorchRL's losses call to evaluate their Q-networks on the stacked parameters of
    the twin critics, with ``deactivate_vmap``: each critic in turn, as TorchRL's own loop
    (``_pseudo_vmap``) runs them, to the same numbers, but with each critic's parameters put
    straight into the module's parameter tables instead of through tensordicts (``unbind`` of
    the parameters and ``to_module`` into the ``TensorDictModule`` for each critic, on every
    call: three calls per SAC update). Returns a tensordict holding the stacked Q-values.

    ``batched_inputs``: the inputs have the critics' dimension first (TD3's losses), else all
    critics read the same inputs (SAC's)."""

    def __init__(self, qvalue: TensorDictModule, batched_inputs: bool) -> None:
        self.module, self.in_keys = qvalue.module, qvalue.in_keys
        self.out_key = qvalue.out_keys[0]
        self.batched_inputs = batched_inputs
        self._slots: list | None = None

    def _resolve(self, params: TensorDictBase) -> list:
        """``(key in params, parameter or buffer table, name)`` of each of the critic's
        tensors (``params`` is keyed from the ``TensorDictModule``, whose ``module`` this
        is)."""
        return [(key, *_slot(self.module, key[1:])) for key in params.keys(True, True)]

    def __call__(self, tensordict: TensorDictBase, params: TensorDictBase) -> TensorDictBase:
        if self._slots is None:
            self._slots = self._resolve(params)
        slots = self._slots
        per_critic = list(zip(*(params.get(key).unbind(0) for key, _, _ in slots), strict=True))
        inputs = [tensordict.get(key) for key in self.in_keys]
        per_input = (
            zip(*(x.unbind(0) for x in inputs), strict=True)
            if self.batched_inputs
            else repeat(inputs, len(per_critic))
        )
        kept = [table[name] for _, table, name in slots]
        values = []
        try:
            for tensors, args in zip(per_critic, per_input, strict=True):
                for (_, table, name), tensor in zip(slots, tensors, strict=True):
                    table[name] = tensor
                values.append(self.module(*args))
        finally:
            for (_, table, name), tensor in zip(slots, kept, strict=True):
                table[name] = tensor
        value = torch.stack(values)
        return TensorDict({self.out_key: value}, batch_size=value.shape[:-1])


class ModuleOwnParams(TensorDictParams):
    """A loss's ``TensorDictParams`` of a network whose module holds the same tensors: TorchRL
    takes the actor's parameters from the actor itself (the same ``Parameter`` objects; each
    buffer another tensor over the same memory). ``to_module`` onto that module is no swap
    while both sides hold what they held when these were made (this object's ``nn.Module``
    tables, which ``TensorDictParams`` keeps in step with its tensordict, and the module's),
    each buffer pair still over one memory, and TorchRL's swap otherwise: a tensor replaced in
    either, a buffer moved on one side (``loss.to(...)``, ``loss.double()``), another module.
    TorchRL's SAC and TD3 losses swap the actor's parameters in and out of the actor at each of
    its evaluations; skipping that is the same arithmetic, about 4 % of an eager SAC update at
    the paper's sizes on a 2-core CPU (``results/bench/update_speed.md``). A deep copy is a
    plain ``TensorDictParams`` of copied tensors, which swaps."""

    def __init__(self, params: TensorDictParams, module: nn.Module) -> None:
        super().__init__(params)
        held = []
        for key, tensor in self.items(True, True):
            key = _key(key)
            table, name = _slot(module, key)
            if not _same_memory(table.get(name), tensor):
                held = None  # not the module's own: every to_module swaps
                break
            flat = ".".join(key)
            ours = self._parameters if flat in self._parameters else self._buffers
            held.append((ours, flat, tensor, table, name, table[name]))
        # kept out of nn.Module's attribute tables: the module is not a submodule of these
        self.__dict__["_own"] = (module, held)

    def to_module(self, module: nn.Module, **kwargs):
        owner, held = self.__dict__["_own"]
        if (
            module is owner
            and held is not None
            and all(
                ours.get(flat) is tensor and table.get(name) is mine and _same_memory(mine, tensor)
                for ours, flat, tensor, table, name, mine in held
            )
        ):
            return nullcontext()
        return super().to_module(module, **kwargs)


def _same_memory(a: torch.Tensor | None, b: torch.Tensor) -> bool:
    """``a`` is ``b``, or a view of the same memory with the same layout."""
    return a is b or (
        isinstance(a, torch.Tensor)
        and a.data_ptr() == b.data_ptr()
        and a.dtype == b.dtype
        and a.shape == b.shape
        and a.stride() == b.stride()
        and a.requires_grad == b.requires_grad
    )


def own_actor_params(loss: LossModule) -> None:
    """Gives ``loss`` its actor's parameters as :class:`ModuleOwnParams` (the same tensors)."""
    loss.actor_network_params = ModuleOwnParams(loss.actor_network_params, loss.actor_network)


class FastUpdatePaths:
    """What ``deactivate_vmap`` (``fast_update`` on a CPU) changes in a TorchRL loss over an
    actor and twin critics (mixed in before the loss's class): the critics run through
    :class:`CriticsInTurn`, set as the loss's attribute ``critics_attr`` (reading inputs with
    the critics' dimension first with ``batched_inputs``), and the actor's parameters are
    :class:`ModuleOwnParams`. The same numbers as TorchRL's paths."""

    critics_attr: str
    batched_inputs: bool

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        if self.deactivate_vmap:
            own_actor_params(self)

    def _make_vmap(self) -> None:
        super()._make_vmap()
        if self.deactivate_vmap:
            critics = CriticsInTurn(self.qvalue_network, batched_inputs=self.batched_inputs)
            setattr(self, self.critics_attr, critics)


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
