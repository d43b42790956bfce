"""The networks of SAC, TD3 and PPO from TorchRL's modules: observation scaling, MLPs, the
Q-network (optionally privileged), the Tanh-Normal and the deterministic actors (each
algorithm's ``make_actor`` picks its own), the critics' sparse dropout (``critic_dropout``,
DroQ) and the actor's exponential moving average (``actor_average``); the last two are not in
the paper."""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import torch
from tensordict.nn import (
    AddStateIndependentNormalScale,
    NormalParamExtractor,
    TensorDictModule,
    TensorDictSequential,
)
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import MLP, ProbabilisticActor, TanhModule, ValueOperator

from dockingrl.agents.config import ACTIVATIONS, OffPolicyConfig, TrainConfig
from dockingrl.agents.distributions import BoundedTanhNormal
from dockingrl.agents.mirror import mirror_observation_signs, symmetric
from dockingrl.scenarios import (
    MIRROR_PAIR,
    OBSERVATION_PARTS,
    layout_options,
    observation_layout,
    observation_size,
)

#: what a privileged critic (``privileged_critic``) reads besides the observation: simulator
#: state, never the policy's input
PRIVILEGED_KEYS = ("true_state", "ocean_current")
PRIVILEGED_DIM = 9


#: standard deviations of the number of dropped entries beyond its mean that one mask draws
#: gaps for: a mask that would need more comes with probability below 1e-30
_MARGIN_SD = 12.0


class SparseDropout(nn.Dropout):
    """``nn.Dropout`` (each entry zeroed with probability ``p`` independently, the others
    scaled by ``1 / (1 - p)``) whose mask costs random numbers for the dropped entries only.

    The positions of the dropped entries of a Bernoulli(``p``) sequence are the partial sums of
    independent geometric gaps, ``G = floor(log U / log(1 - p)) + 1`` with ``U`` uniform: one
    mask of ``n`` entries draws ``n p + 12 sd + 12`` of them instead of ``n`` uniforms. At
    DroQ's ``p = 0.01`` and the critics' 256 x 256 activations that is about 900 numbers
    instead of 65,536: a SAC update with it runs at 57.0 a second eager against 49.7 with
    ``nn.Dropout`` (``bench/dropout_speed.py``). The mask is the same in law as
    ``nn.Dropout``'s, not in its draws; it works under ``torch.vmap`` (randomness
    ``"different"``) and ``torch.compile`` (its shapes depend on ``n`` and ``p`` alone)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training or self.p == 0.0:
            return x
        n, p = x.numel(), float(self.p)
        mean = n * p
        draws = math.ceil(mean + _MARGIN_SD * math.sqrt(mean * (1.0 - p)) + _MARGIN_SD)
        u = torch.rand(draws, dtype=torch.float64, device=x.device)
        gaps = torch.floor(torch.log(u) / math.log1p(-p)) + 1.0
        # positions past the end (and log(0)'s infinity) land on a spare slot, cut off below
        where = (torch.cumsum(gaps, 0) - 1.0).clamp(max=float(n)).long()
        no = torch.zeros(n + 1, dtype=torch.bool, device=x.device)
        dropped = no.scatter(0, where, True)[:n].reshape(x.shape)
        return (x * (1.0 / (1.0 - p))).masked_fill(dropped, 0.0)


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


def observation_scale(
    obs_dim: int, max_dist: float, normalize: bool, layout: Sequence[str] = ()
) -> torch.Tensor:
    """``1 / max_dist`` on every range entry, 1 elsewhere (the current, the previous command
    and the filter's standard deviations included). The range entries are the first of each
    reading (``observation``, ``filtered_observation``) of ``layout``
    (:func:`~dockingrl.scenarios.observation_layout`) where it describes these ``obs_dim``
    numbers; otherwise index 0 of each full 6-block, the same for every layout without
    ``filter_std``."""
    scale = torch.ones(obs_dim)
    if not normalize:
        return scale
    if observation_size(layout) != obs_dim:
        scale[0 : 6 * (obs_dim // 6) : 6] = 1.0 / max_dist
        return scale
    start = 0
    for key in layout:
        if key in ("observation", "filtered_observation"):
            scale[start] = 1.0 / max_dist
        start += len(OBSERVATION_PARTS[key])
    return scale


def config_observation_scale(cfg: TrainConfig, obs_dim: int, max_dist: float) -> torch.Tensor:
    """:func:`observation_scale` of the observation ``cfg``'s policy reads."""
    layout = observation_layout(cfg.scenario, **layout_options(cfg))
    return observation_scale(obs_dim, max_dist, cfg.normalize_observation, layout)


def mlp(
    in_features: int,
    out_features: int,
    hidden: tuple[int, ...],
    scale: torch.Tensor,
    *,
    activation: str = "relu",
    orthogonal_gain: float | None = None,
    layer_norm: bool = False,
    dropout: float = 0.0,
) -> nn.Module:
    """Observation scaling then an MLP. ``orthogonal_gain`` (``None``: PyTorch's default
    init) gives orthogonal weights of gain sqrt(2) in the hidden layers and ``orthogonal_gain``
    on the output layer, with zero biases (stable-baselines3's init). ``layer_norm`` puts a
    ``LayerNorm`` after each hidden linear layer, before its activation; ``dropout`` (> 0) a
    :class:`SparseDropout` right after each hidden linear layer (before the ``LayerNorm``, as
    DroQ)."""
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
        **({"dropout": dropout} if dropout > 0 else {}),
        **norm,
    )
    for i, module in enumerate(net):
        if isinstance(module, nn.Dropout):
            net[i] = SparseDropout(dropout)
    if orthogonal_gain is not None:
        linears = [m for m in net.modules() if isinstance(m, nn.Linear)]
        for i, layer in enumerate(linears):
            gain = orthogonal_gain if i == len(linears) - 1 else 2**0.5
            nn.init.orthogonal_(layer.weight, gain=gain)
            nn.init.zeros_(layer.bias)
    return nn.Sequential(ObservationScale(scale), net)


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
    :class:`MirrorSymmetric`. ``dropout``: see :func:`mlp`."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden,
        scale,
        layer_norm=False,
        privileged_max_dist: float | None = None,
        mirror: torch.Tensor | None = None,
        dropout: float = 0.0,
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
            dropout=dropout,
        )
        if mirror is not None and extra:
            raise ValueError("a privileged critic cannot be mirror-symmetric")
        in_signs = None if mirror is None else torch.cat((mirror, torch.tensor(MIRROR_PAIR)))
        self.net = symmetric(net, in_signs, (1.0,))

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
            dropout=cfg.critic_dropout,
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
    net = nn.Sequential(symmetric(body, mirror, out_signs), head)
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
    net = symmetric(mlp(obs_dim, action_spec.shape[-1], hidden, scale), mirror, MIRROR_PAIR)
    return TensorDictSequential(
        TensorModule(net, in_keys=["observation"], out_keys=["param"]),
        TanhModule(in_keys=["param"], out_keys=["action"], spec=action_spec),
    )


class ActorAverage:
    """An exponential moving average of ``actor``'s weights: ``module`` starts as a frozen copy
    of ``actor`` and :meth:`step` moves it ``avg <- decay avg + (1 - decay) live`` (its buffers,
    if any, are copied). Polyak averaging of the iterates: it smooths the update-to-update
    wander of the policy."""

    def __init__(self, actor: nn.Module, decay: float) -> None:
        self.actor = actor
        self.module = copy.deepcopy(actor).requires_grad_(False)
        self.decay = decay
        self._pairs: tuple[list, list, list] | None = None

    def step(self) -> None:
        """Move the averaged weights towards the live actor's by ``1 - decay``."""
        if self._pairs is None:
            live = dict(self.actor.named_parameters())
            avg = dict(self.module.named_parameters())
            self._pairs = (
                [avg[k] for k in live],
                [live[k] for k in live],
                list(zip(self.module.buffers(), self.actor.buffers(), strict=True)),
            )
        averaged, live, buffers = self._pairs
        weight = 1.0 - self.decay
        with torch.no_grad():
            for mine, theirs in zip(averaged, live, strict=True):
                mine.lerp_(theirs, weight)
            for mine, theirs in buffers:
                mine.copy_(theirs)
