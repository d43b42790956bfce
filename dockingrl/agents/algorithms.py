"""SAC, TD3 and PPO built from TorchRL's own pieces: actor / critic modules, ``SACLoss``,
``TD3Loss``, ``ClipPPOLoss`` with ``GAE``, ``SoftUpdate`` target updaters, Adam optimisers,
``AdditiveGaussianModule`` exploration and replay buffers.

Each builder returns an :class:`Agent`: the exploration policy used while collecting, the
deterministic policy used in evaluation, and ``learn(...)`` which turns collected data into
gradient updates (the ``update()`` closure of TorchRL's sota-implementations)."""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import (
    AddStateIndependentNormalScale,
    NormalParamExtractor,
    TensorDictModule,
    TensorDictSequential,
)
from torch import nn
from torchrl.data import Bounded, LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import RandomSampler
from torchrl.modules import (
    MLP,
    AdditiveGaussianModule,
    ProbabilisticActor,
    TanhModule,
    ValueOperator,
)
from torchrl.objectives import ClipPPOLoss, SACLoss, SoftUpdate, TD3Loss
from torchrl.objectives.value import GAE

from dockingrl.agents.config import (
    ACTIVATIONS,
    OffPolicyConfig,
    PPOConfig,
    SACConfig,
    TD3Config,
    TrainConfig,
)
from dockingrl.agents.distributions import BoundedTanhNormal
from dockingrl.scenarios import MIRROR_PAIR, mirror_signs

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
#: what a privileged critic (``privileged_critic``) reads besides the observation: simulator
#: state, never the policy's input
PRIVILEGED_KEYS = ("true_state", "ocean_current")
PRIVILEGED_DIM = 9


def transition_keys(cfg: TrainConfig) -> tuple:
    """What the replay buffer of ``cfg`` stores of each transition: ``TRANSITION_KEYS``, and
    ``PRIVILEGED_KEYS`` of both steps for a privileged critic."""
    if not getattr(cfg, "privileged_critic", False):
        return TRANSITION_KEYS
    return TRANSITION_KEYS + PRIVILEGED_KEYS + tuple(("next", k) for k in PRIVILEGED_KEYS)


def mirror_transitions(data: TensorDictBase, observation_signs: torch.Tensor) -> TensorDictBase:
    """``data``'s transitions mirrored through the docking axis (``y -> -y``, not in the
    paper): ``observation`` and ``("next", "observation")`` times ``observation_signs``
    (:func:`dockingrl.scenarios.mirror_signs`), the turn command of ``action`` negated; reward,
    flags and step counts unchanged. A new tensordict; ``data`` is left as it is."""
    out = data.clone()
    signs = observation_signs.to(device=data.device, dtype=data["observation"].dtype)
    if signs.shape[-1] != data["observation"].shape[-1]:
        raise ValueError(
            f"{signs.shape[-1]} mirror signs for an observation of "
            f"{data['observation'].shape[-1]} numbers"
        )
    out["observation"] = data["observation"] * signs
    out["next", "observation"] = data["next", "observation"] * signs
    action_signs = torch.tensor(MIRROR_PAIR, device=data.device, dtype=data["action"].dtype)
    out["action"] = data["action"] * action_signs
    return out


class MirroredPolicy(nn.Module):
    """``actor`` mirrored through the docking axis (``y -> -y``, not in the paper): in every
    situation it commands the mirror of what ``actor`` commands in the mirrored one. The task
    being symmetric (:func:`dockingrl.scenarios.mirror_signs`), a policy that treats both
    sides of the axis alike scores the same mirrored; ``dockingrl eval --mirrored`` measures
    it (and a :class:`MirrorSymmetric` actor is its own mirror)."""

    def __init__(self, actor: nn.Module, observation_signs: torch.Tensor) -> None:
        super().__init__()
        self.actor = actor
        self.register_buffer("observation_signs", torch.as_tensor(observation_signs).float())
        self.register_buffer("action_signs", torch.tensor(MIRROR_PAIR))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation = tensordict["observation"]
        mirrored = tensordict.empty()
        mirrored["observation"] = observation * self.observation_signs.to(observation.dtype)
        action = self.actor(mirrored)["action"]
        tensordict["action"] = action * self.action_signs.to(action.dtype)
        return tensordict


def n_step_transitions(data: TensorDictBase, n_steps: int, gamma: float) -> TensorDictBase:
    """n-step transitions (not in the paper) from time-ordered data of shape ``(envs, L)``.

    The transition of step ``t`` keeps ``observation`` and ``action`` of ``t`` and looks ahead
    ``m = min(n_steps, steps left in its episode)`` steps: its reward is
    ``sum_{k<m} gamma^k r_{t+k}``, its ``next`` entries (observation and the ``done`` /
    ``terminated`` / ``truncated`` flags) are those of step ``t + m - 1``, and
    ``steps_to_next_obs = m``, which TorchRL's TD(0) estimator turns into the bootstrap
    discount ``gamma^m``. A transition ending on a terminal step therefore never bootstraps.
    Only the first ``L - n_steps + 1`` steps have their whole window in ``data`` and are
    returned; the caller carries the last ``n_steps - 1`` steps over to the next call."""
    length = data.shape[-1]
    count = length - n_steps + 1
    if count < 1:
        raise ValueError(f"n-step transitions need at least {n_steps} steps, got {length}")
    reward = data["next", "reward"]
    done = data["next", "done"]
    index = torch.arange(count, device=reward.device).expand(*data.shape[:-1], count)
    last = index.clone()
    summed = torch.zeros_like(reward[..., :count, :])
    alive = torch.ones_like(done[..., :count, :])
    for k in range(n_steps):
        summed = summed + alive * (gamma**k) * reward[..., k : k + count, :]
        last = torch.where(alive.squeeze(-1), index + k, last)
        alive = alive & ~done[..., k : k + count, :]
    out = data[..., :count].clone()
    out["next"] = data["next"].gather(-1, last)
    out["next", "reward"] = summed
    out["steps_to_next_obs"] = (last - index + 1).unsqueeze(-1).to(reward.dtype)
    return out


class ObservationScale(nn.Module):
    """Multiplies the observation by fixed per-entry factors (part of the saved network)."""

    def __init__(self, scale: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("scale", scale.clone().float())

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        observation, *rest = inputs
        return (
            torch.cat((observation * self.scale, *rest), dim=-1)
            if rest
            else observation * self.scale
        )


def observation_scale(obs_dim: int, max_dist: float, normalize: bool) -> torch.Tensor:
    """``1 / max_dist`` on every range entry (index 0 of each full 6-block: the raw and the
    filtered observation), 1 elsewhere (the optional ocean current after them included)."""
    scale = torch.ones(obs_dim)
    if normalize:
        scale[0 : 6 * (obs_dim // 6) : 6] = 1.0 / max_dist
    return scale


def mlp(
    in_features: int,
    out_features: int,
    hidden: tuple[int, ...],
    scale: torch.Tensor,
    *,
    activation: str = "relu",
    orthogonal_gain: float | None = None,
    layer_norm: bool = False,
) -> nn.Module:
    """Observation scaling then an MLP. ``orthogonal_gain`` (``None``: PyTorch's default
    init) gives orthogonal weights of gain sqrt(2) in the hidden layers and ``orthogonal_gain``
    on the output layer, with zero biases (stable-baselines3's init). ``layer_norm`` puts a
    ``LayerNorm`` after each hidden linear layer, before its activation."""
    norm = (
        {"norm_class": nn.LayerNorm, "norm_kwargs": [{"normalized_shape": h} for h in hidden]}
        if layer_norm
        else {}
    )
    net = MLP(
        in_features=in_features,
        out_features=out_features,
        num_cells=list(hidden),
        activation_class=getattr(nn, ACTIVATIONS[activation]),
        **norm,
    )
    if orthogonal_gain is not None:
        linears = [m for m in net.modules() if isinstance(m, nn.Linear)]
        for i, layer in enumerate(linears):
            gain = orthogonal_gain if i == len(linears) - 1 else 2**0.5
            nn.init.orthogonal_(layer.weight, gain=gain)
            nn.init.zeros_(layer.bias)
    return nn.Sequential(ObservationScale(scale), net)


class MirrorSymmetric(nn.Module):
    """``f_sym(x) = (f(x) + s_out * f(s_in * x)) / 2``: ``net`` made exactly equivariant
    under the mirror ``y -> -y`` (not in the paper).

    ``s_in`` mirrors the input (:func:`dockingrl.scenarios.mirror_signs`, with the action's
    ``MIRROR_PAIR`` after it for a critic) and ``s_out`` the output: the turn command's
    pre-squash location changes sign and the rest (surge, the scales, a value) stays, so the
    actor commands the mirrored command in the mirrored situation and a critic values a
    transition and its mirror alike, whatever the weights. Averaging over the two-element
    group is the simplest equivariant network; the task being symmetric
    (:func:`~dockingrl.scenarios.mirror_signs`), its optimal policy is such a one, and a
    policy that has learned one side of the docking axis cannot fail the other."""

    def __init__(self, net: nn.Module, in_signs: torch.Tensor, out_signs: torch.Tensor) -> None:
        super().__init__()
        self.net = net
        self.register_buffer("in_signs", torch.as_tensor(in_signs, dtype=torch.float32))
        self.register_buffer("out_signs", torch.as_tensor(out_signs, dtype=torch.float32))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        both = self.net(torch.stack((x, x * self.in_signs.to(x.dtype))))
        return 0.5 * (both[0] + both[1] * self.out_signs.to(both.dtype))


def config_mirror_signs(cfg: TrainConfig) -> torch.Tensor:
    """:func:`~dockingrl.scenarios.mirror_signs` of the observation ``cfg``'s policy reads."""
    return mirror_signs(
        cfg.scenario, observe_current=cfg.observe_current, observe_command=cfg.observe_command
    )


def mirror_observation_signs(
    cfg: TrainConfig, obs_dim: int, network: str = "actor"
) -> torch.Tensor | None:
    """The observation's mirror signs where ``cfg.mirror_symmetric`` makes ``network``
    (``actor`` or ``critic``) mirror-symmetric, else ``None``."""
    if cfg.mirror_symmetric == "none" or (network == "critic" and cfg.mirror_symmetric != "all"):
        return None
    signs = config_mirror_signs(cfg)
    if signs.numel() != obs_dim:
        raise ValueError(
            f"mirror_symmetric: the observation of {cfg.scenario!r} has {signs.numel()} "
            f"entries with these options, the networks read {obs_dim}"
        )
    return signs


def _symmetric(net: nn.Module, in_signs: torch.Tensor | None, out_signs) -> nn.Module:
    if in_signs is None:
        return net
    return MirrorSymmetric(net, in_signs, torch.as_tensor(out_signs, dtype=torch.float32))


def privileged_features(
    true_state: torch.Tensor, ocean_current: torch.Tensor, max_dist: float
) -> torch.Tensor:
    """What a privileged critic reads besides the observation (``PRIVILEGED_DIM`` numbers):
    the true ``x, y`` over ``max_dist``, the cosine and sine of the true heading, the true
    ``u, v, r`` and the ocean current ``(oc_x, oc_y)`` (DS frame)."""
    x, y, alpha, u, v, r = true_state.unbind(-1)
    pose = torch.stack((x / max_dist, y / max_dist, alpha.cos(), alpha.sin(), u, v, r), dim=-1)
    return torch.cat((pose, ocean_current), dim=-1)


class _Critic(nn.Module):
    """Q(o, a): the scaled observation and the action through one MLP. With
    ``privileged_max_dist`` (asymmetric actor-critic) it is Q(o, s, a): the
    :func:`privileged_features` of the simulator's true state and current ``s`` sit between
    observation and action. With ``mirror`` (the observation's mirror signs) it is
    :class:`MirrorSymmetric`."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden,
        scale,
        layer_norm=False,
        privileged_max_dist: float | None = None,
        mirror: torch.Tensor | None = None,
    ) -> None:
        super().__init__()
        self.privileged_max_dist = privileged_max_dist
        extra = 0 if privileged_max_dist is None else PRIVILEGED_DIM
        net = mlp(
            obs_dim + extra + act_dim,
            1,
            hidden,
            torch.cat((scale, torch.ones(extra + act_dim))),
            layer_norm=layer_norm,
        )
        if mirror is not None and extra:
            raise ValueError("a privileged critic cannot be mirror-symmetric")
        in_signs = None if mirror is None else torch.cat((mirror, torch.tensor(MIRROR_PAIR)))
        self.net = _symmetric(net, in_signs, (1.0,))

    def forward(self, observation: torch.Tensor, *rest: torch.Tensor) -> torch.Tensor:
        *privileged, action = rest
        if self.privileged_max_dist is not None:
            privileged = [privileged_features(*privileged, self.privileged_max_dist)]
        return self.net(torch.cat((observation, *privileged, action), dim=-1))


class _WritesTensors:
    """Writes a module's tensor outputs straight into its input tensordict.

    ``TensorDictModule`` passes every output through ``TensorDict.from_any``, which, for a plain
    tensor and with pandas not imported, calls ``importlib.util.find_spec("pandas")`` (a scan
    of ``sys.path``) before returning the tensor unchanged: seven times per SAC update.
    Setting them directly made the eager SAC update 2.5-6.5 % faster in paired runs on a 2-core
    CPU (``results/bench/update_speed.md``). Outputs that are all tensors, written in place
    (the default), are set directly; anything else takes ``TensorDictModule``'s own path."""

    def _write_to_tensordict(self, tensordict, tensors, tensordict_out=None, out_keys=None):
        keys = self.out_keys_source if out_keys is None else out_keys
        if (
            tensordict_out is None
            and self.inplace is True
            and len(keys) == len(tensors)
            and all(isinstance(t, torch.Tensor) for t in tensors)
        ):
            for key, tensor in zip(keys, tensors, strict=True):
                if key != "_":
                    tensordict.set(key, tensor)
            return tensordict
        return super()._write_to_tensordict(tensordict, tensors, tensordict_out, out_keys)


class TensorModule(_WritesTensors, TensorDictModule):
    """``TensorDictModule`` for networks whose outputs are tensors (see ``_WritesTensors``)."""


class QValueModule(_WritesTensors, ValueOperator):
    """``ValueOperator`` for value and Q-networks (see ``_WritesTensors``)."""


def make_critic(cfg: OffPolicyConfig, obs_dim: int, act_dim: int, scale, max_dist: float):
    """The Q-network of SAC / TD3 as a ``ValueOperator`` (``state_action_value``): reads
    ``observation`` and ``action``, plus ``PRIVILEGED_KEYS`` with SAC's
    ``privileged_critic``."""
    privileged = getattr(cfg, "privileged_critic", False)
    return QValueModule(
        _Critic(
            obs_dim,
            act_dim,
            cfg.hidden,
            scale,
            cfg.critic_layer_norm,
            privileged_max_dist=max_dist if privileged else None,
            mirror=mirror_observation_signs(cfg, obs_dim, "critic"),
        ),
        in_keys=["observation", *(PRIVILEGED_KEYS if privileged else ()), "action"],
    )


def stochastic_actor(
    obs_dim: int,
    action_spec: Bounded,
    hidden,
    scale,
    *,
    log_prob=False,
    activation: str = "relu",
    state_independent_scale: bool = False,
    orthogonal_init: bool = False,
    mirror: torch.Tensor | None = None,
):
    """Tanh-Normal actor (SAC, PPO): an MLP gives the loc and, unless
    ``state_independent_scale`` (one learned scale per action, initially 1), the scale too;
    the sample is squashed into the bounds (:class:`BoundedTanhNormal`, TorchRL's
    ``TanhNormal`` computed without its transform chain). ``mirror``: the observation's mirror
    signs, for a :class:`MirrorSymmetric` MLP (the turn bounds being symmetric, the squashed
    turn command changes sign with its loc)."""
    act_dim = action_spec.shape[-1]
    outputs, head = (
        (act_dim, AddStateIndependentNormalScale(act_dim, scale_lb=1e-4))
        if state_independent_scale
        else (2 * act_dim, NormalParamExtractor())
    )
    gain = 0.01 if orthogonal_init else None
    body = mlp(obs_dim, outputs, hidden, scale, activation=activation, orthogonal_gain=gain)
    # the loc's turn entry changes sign under the mirror, the scales do not
    out_signs = torch.ones(outputs)
    out_signs[:act_dim] = torch.tensor(MIRROR_PAIR)
    net = nn.Sequential(_symmetric(body, mirror, out_signs), head)
    return ProbabilisticActor(
        TensorModule(net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        out_keys=["action"],
        spec=action_spec,
        distribution_class=BoundedTanhNormal,
        distribution_kwargs={"low": action_spec.space.low, "high": action_spec.space.high},
        return_log_prob=log_prob,
    )


def deterministic_actor(obs_dim: int, action_spec: Bounded, hidden, scale, mirror=None):
    """TD3's actor: an MLP (:class:`MirrorSymmetric` with ``mirror``, the observation's mirror
    signs) squashed by tanh into the action bounds."""
    net = _symmetric(mlp(obs_dim, action_spec.shape[-1], hidden, scale), mirror, MIRROR_PAIR)
    return TensorDictSequential(
        TensorModule(net, in_keys=["observation"], out_keys=["param"]),
        TanhModule(in_keys=["param"], out_keys=["action"], spec=action_spec),
    )


def build_actor(cfg: TrainConfig, obs_dim: int, action_spec: Bounded, max_dist: float):
    """The policy network of ``cfg.algo`` (what a saved policy holds)."""
    scale = observation_scale(obs_dim, max_dist, cfg.normalize_observation)
    mirror = mirror_observation_signs(cfg, obs_dim)
    if cfg.algo == "td3":
        return deterministic_actor(obs_dim, action_spec, cfg.hidden, scale, mirror)
    ppo_options = (
        {
            "log_prob": True,
            "activation": cfg.activation,
            "state_independent_scale": cfg.state_independent_scale,
            "orthogonal_init": cfg.orthogonal_init,
        }
        if cfg.algo == "ppo"
        else {}
    )
    return stochastic_actor(obs_dim, action_spec, cfg.hidden, scale, mirror=mirror, **ppo_options)


@dataclass
class Agent:
    """An algorithm's modules and its update rule."""

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
    averaged: nn.Module | None = None

    @property
    def policy(self) -> nn.Module:
        """The actor to evaluate and save: the averaged one if there is one."""
        return self.actor if self.averaged is None else self.averaged

    def _average_actor(self) -> None:
        """Move the averaged actor's weights towards the live actor's by
        ``1 - actor_average`` (its buffers, if any, are copied)."""
        if self.averaged is None:
            return
        pairs = self.extra.get("average_pairs")
        if pairs is None:
            live, avg = dict(self.actor.named_parameters()), dict(self.averaged.named_parameters())
            pairs = self.extra["average_pairs"] = (
                [avg[k] for k in live],
                [live[k] for k in live],
                list(zip(self.averaged.buffers(), self.actor.buffers(), strict=True)),
            )
        averaged, live, buffers = pairs
        weight = 1.0 - self.config.actor_average
        with torch.no_grad():
            for mine, theirs in zip(averaged, live, strict=True):
                mine.lerp_(theirs, weight)
            for mine, theirs in buffers:
                mine.copy_(theirs)

    # -- learning ------------------------------------------------------------------------
    def learn(
        self, data: TensorDictBase, num_updates: int = 0, progress: float = 0.0
    ) -> dict[str, float]:
        """Off-policy: store ``data`` (``(num_envs, T)``) and run ``num_updates`` updates.
        On-policy: PPO's epochs over ``data``; ``progress`` (the fraction of ``total_steps``
        done before ``data``) sets the learning rate of ``lr_schedule="linear"``. Returns mean
        losses (``losses/...``)."""
        if self.config.algo == "ppo":
            return self._learn_ppo(data, progress)
        keys = transition_keys(self.config)
        transitions = self._transitions(data.select(*keys)).reshape(-1)
        self.replay_buffer.extend(transitions)
        if self.config.mirror_augment:
            signs = config_mirror_signs(self.config)
            self.replay_buffer.extend(mirror_transitions(transitions, signs))
        logs: dict[str, list[float]] = {}
        for _ in range(num_updates):
            for key, value in self._off_policy_update().items():
                logs.setdefault(key, []).append(value)
        return {k: sum(v) / len(v) for k, v in logs.items()}

    def _transitions(self, data: TensorDictBase) -> TensorDictBase:
        """What the replay buffer stores of ``data``: one-step transitions, or with
        ``n_steps > 1`` the n-step ones of :func:`n_step_transitions`, the last
        ``n_steps - 1`` steps waiting for the next collection to complete their window. A
        checkpoint does not keep those steps: a resumed run restarts its envs' episodes, so
        they have no continuation."""
        n = self.config.n_steps
        if n == 1:
            return data
        tail = self.extra.get("n_step_tail")
        if tail is not None:
            data = torch.cat((tail, data), dim=-1)
        self.extra["n_step_tail"] = data[..., data.shape[-1] - (n - 1) :].clone()
        return n_step_transitions(data, n, self.config.gamma)

    def _gradients(self, name: str, batch: TensorDictBase) -> dict[str, torch.Tensor]:
        """Forward and backward of one loss (``name``: ``sac``, ``critic``, ``actor`` or
        ``ppo``); returns the detached logged values. With ``compile_update`` each of these
        runs through ``torch.compile`` (built on first use)."""
        compiled = self.extra.setdefault("compiled", {})
        if name not in compiled:
            fn = getattr(self, f"_grad_{name}")
            compiled[name] = torch.compile(fn) if self.config.compile_update else fn
        return compiled[name](batch)

    def _grad_sac(self, batch):
        out = self.loss(batch)
        total = out["loss_actor"] + out["loss_qvalue"]
        if self.config.learn_alpha:
            total = total + out["loss_alpha"]
        total.backward()
        return {k: out[k].detach() for k in ("loss_actor", "loss_qvalue", "alpha", "entropy")}

    def _grad_critic(self, batch):
        loss, _ = self.loss.value_loss(batch)
        loss.backward()
        return {"loss_qvalue": loss.detach()}

    def _grad_actor(self, batch):
        loss, _ = self.loss.actor_loss(batch)
        loss.backward()
        return {"loss_actor": loss.detach()}

    def _grad_ppo(self, batch):
        out = self.loss(batch)
        total = out["loss_objective"] + out["loss_critic"]
        if "loss_entropy" in out.keys():
            total = total + out["loss_entropy"]
        total.backward()
        keys = ("loss_objective", "loss_critic", "clip_fraction", "kl_approx")
        return {k: out[k].detach() for k in keys if k in out.keys()}

    def _off_policy_update(self) -> dict[str, float]:
        batch = self.replay_buffer.sample()
        cfg, opt = self.config, self.optimizers
        self.updates += 1
        if cfg.algo == "sac":
            for o in opt.values():
                o.zero_grad(set_to_none=True)
            logs = self._gradients("sac", batch)
            for o in opt.values():
                o.step()
            self.target_updater.step()
            self._average_actor()
            return {k: _scalar(v) for k, v in logs.items()}
        # TD3: the critics every update, the actor and the targets every policy_delay updates
        opt["critic"].zero_grad(set_to_none=True)
        logs = self._gradients("critic", batch)
        opt["critic"].step()
        if self.updates % cfg.policy_delay == 0:
            opt["actor"].zero_grad(set_to_none=True)
            logs.update(self._gradients("actor", batch))
            opt["actor"].step()
            self.target_updater.step()
            self._average_actor()
        return {k: _scalar(v) for k, v in logs.items()}

    def _learn_ppo(self, data: TensorDictBase, progress: float) -> dict[str, float]:
        cfg, optim = self.config, self.optimizers["all"]
        lr = cfg.lr
        if cfg.lr_schedule == "linear":
            lr = cfg.lr * (1.0 - min(max(progress, 0.0), 1.0))
        for group in optim.param_groups:
            group["lr"] = lr
        params = list(self.loss.parameters())
        frames = data.numel()
        if cfg.reward_scale != 1.0:
            data = data.clone(recurse=False)
            data["next"] = data["next"].clone(recurse=False)
            data["next", "reward"] = data["next", "reward"] * cfg.reward_scale
        logs: dict[str, list[float]] = {}
        for _ in range(cfg.epochs):
            with torch.no_grad():
                self.advantage(data)
            flat = data.reshape(-1)
            order = torch.randperm(frames, generator=self.extra["generator"])
            for start in range(0, frames, cfg.minibatch_size):
                batch = flat[order[start : start + cfg.minibatch_size]]
                optim.zero_grad(set_to_none=True)
                out = self._gradients("ppo", batch)
                torch.nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
                optim.step()
                self._average_actor()
                self.updates += 1
                for key, value in out.items():
                    logs.setdefault(key, []).append(_scalar(value))
        logs["lr"] = [lr]
        return {k: sum(v) / len(v) for k, v in logs.items()}

    # -- checkpoints -----------------------------------------------------------------------
    def state_dict(self) -> dict:
        state = {
            "loss": self.loss.state_dict(),
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "updates": self.updates,
        }
        if "generator" in self.extra:
            state["generator"] = self.extra["generator"].get_state()
        if self.averaged is not None:
            state["averaged"] = self.averaged.state_dict()
        return state

    def load_state_dict(self, state: dict) -> None:
        self.loss.load_state_dict(state["loss"])
        for k, o in self.optimizers.items():
            o.load_state_dict(state["optimizers"][k])
        self.updates = state["updates"]
        if "generator" in state:
            self.extra["generator"].set_state(state["generator"])
        if self.averaged is not None:
            if "averaged" not in state:
                raise ValueError("the agent averages its actor; the state holds no averaged actor")
            self.averaged.load_state_dict(state["averaged"])


def _scalar(value: torch.Tensor) -> float:
    return float(value.detach())


def _adam(params, lr: float) -> torch.optim.Adam:
    return torch.optim.Adam(list(params), lr=lr)


def make_agent(
    cfg: TrainConfig,
    obs_dim: int,
    action_spec: Bounded,
    max_dist: float,
    device: torch.device | str = "cpu",
) -> Agent:
    """Build the agent of ``cfg.algo`` for observations of ``obs_dim`` numbers."""
    action_spec = action_spec.to(device)
    scale = observation_scale(obs_dim, max_dist, cfg.normalize_observation)
    act_dim = action_spec.shape[-1]
    actor = build_actor(cfg, obs_dim, action_spec, max_dist).to(device)
    averaged = None
    if cfg.actor_average > 0:
        averaged = copy.deepcopy(actor).requires_grad_(False)
    if isinstance(cfg, SACConfig):
        agent = _make_sac(cfg, actor, obs_dim, act_dim, scale, max_dist, device)
    elif isinstance(cfg, TD3Config):
        agent = _make_td3(cfg, actor, action_spec, obs_dim, act_dim, scale, max_dist, device)
    elif isinstance(cfg, PPOConfig):
        agent = _make_ppo(cfg, actor, obs_dim, scale, device)
    else:
        raise TypeError(f"no agent for {type(cfg).__name__}")
    agent.averaged = averaged
    return agent


def _replay_buffer(cfg, device) -> TensorDictReplayBuffer:
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(cfg.buffer_size, device=device),
        sampler=RandomSampler(),
        batch_size=cfg.batch_size,
    )


def _make_sac(cfg: SACConfig, actor, obs_dim, act_dim, scale, max_dist, device) -> Agent:
    qvalue = make_critic(cfg, obs_dim, act_dim, scale, max_dist).to(device)
    loss = SACLoss(
        actor_network=actor,
        qvalue_network=qvalue,
        num_qvalue_nets=2,
        loss_function="l2",
        alpha_init=cfg.alpha,
        fixed_alpha=not cfg.learn_alpha,
        target_entropy=cfg.target_entropy,
    )
    loss.make_value_estimator(gamma=cfg.gamma)
    optimizers = {
        "actor": _adam(loss.actor_network_params.flatten_keys().values(), cfg.lr),
        "critic": _adam(loss.qvalue_network_params.flatten_keys().values(), cfg.lr),
    }
    if cfg.learn_alpha:
        optimizers["alpha"] = _adam([loss.log_alpha], cfg.lr)
    return Agent(
        cfg,
        actor,
        actor,
        loss,
        optimizers,
        SoftUpdate(loss, tau=cfg.tau),
        _replay_buffer(cfg, device),
    )


def _make_td3(
    cfg: TD3Config, actor, action_spec, obs_dim, act_dim, scale, max_dist, device
) -> Agent:
    qvalue = make_critic(cfg, obs_dim, act_dim, scale, max_dist).to(device)
    exploration = TensorDictSequential(
        actor,
        AdditiveGaussianModule(
            spec=action_spec,
            sigma_init=float(cfg.exploration_sigma),
            sigma_end=float(cfg.exploration_sigma),
            device=device,
        ),
    )
    loss = TD3Loss(
        actor_network=actor,
        qvalue_network=qvalue,
        action_spec=action_spec,
        num_qvalue_nets=2,
        policy_noise=cfg.target_policy_noise,
        noise_clip=cfg.target_noise_clip,
        loss_function="l2",
    )
    loss.make_value_estimator(gamma=cfg.gamma)
    optimizers = {
        "actor": _adam(loss.actor_network_params.flatten_keys().values(), cfg.lr),
        "critic": _adam(loss.qvalue_network_params.flatten_keys().values(), cfg.lr),
    }
    return Agent(
        cfg,
        actor,
        exploration,
        loss,
        optimizers,
        SoftUpdate(loss, tau=cfg.tau),
        _replay_buffer(cfg, device),
    )


def _make_ppo(cfg: PPOConfig, actor, obs_dim, scale, device) -> Agent:
    value_net = mlp(
        obs_dim,
        1,
        cfg.hidden,
        scale,
        activation=cfg.activation,
        orthogonal_gain=1.0 if cfg.orthogonal_init else None,
    )
    value_net = _symmetric(value_net, mirror_observation_signs(cfg, obs_dim, "critic"), (1.0,))
    critic = QValueModule(value_net, in_keys=["observation"]).to(device)
    advantage = GAE(gamma=cfg.gamma, lmbda=cfg.gae_lambda, value_network=critic, average_gae=False)
    loss = ClipPPOLoss(
        actor_network=actor,
        critic_network=critic,
        clip_epsilon=cfg.clip,
        entropy_bonus=cfg.entropy_coef > 0,
        entropy_coeff=cfg.entropy_coef if cfg.entropy_coef > 0 else None,
        critic_coeff=cfg.value_coef,
        loss_critic_type="l2",
        normalize_advantage=cfg.normalize_advantage,
    )
    generator = torch.Generator().manual_seed(cfg.seed)
    return Agent(
        cfg,
        actor,
        actor,
        loss,
        {"all": _adam(loss.parameters(), cfg.lr)},
        advantage=advantage,
        extra={"generator": generator},
    )
