"""The mirror through the docking axis (``y -> -y``, not in the paper): mirrored transitions for
the replay buffer, mirror-symmetric networks and the mirrored policy of ``dockingrl eval
--mirrored``."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import nn

from dockingrl.agents.config import TrainConfig
from dockingrl.agents.world_options import WorldOptions
from dockingrl.scenarios import MIRROR_PAIR, layout_options, mirror_signs


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


def symmetric(net: nn.Module, in_signs: torch.Tensor | None, out_signs) -> nn.Module:
    """``net`` as a :class:`MirrorSymmetric` network for the input signs ``in_signs``, or
    ``net`` itself where they are ``None``."""
    if in_signs is None:
        return net
    return MirrorSymmetric(net, in_signs, torch.as_tensor(out_signs, dtype=torch.float32))


def config_mirror_signs(cfg: WorldOptions) -> torch.Tensor:
    """:func:`~dockingrl.scenarios.mirror_signs` of the observation ``cfg``'s policy reads."""
    return mirror_signs(cfg.scenario, **layout_options(cfg))


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
