"""The one place dockingrl reaches into TorchRL's (and tensordict's) private names: the speed
paths of ``fast_update`` for the off-policy losses. Each class here gives the same numbers as
TorchRL's own path (``tests/test_update_paths.py``); ``tests/test_torchrl_adapter.py`` fails
when a TorchRL release moves one of the names below, and no other module uses them
(``tests/test_architecture.py``).

- :class:`ForeachSoftUpdate`: ``SoftUpdate``'s ``_sources`` and ``_targets``;
- :class:`FastUpdatePaths`: the losses' ``_make_vmap`` and the vmapped critics they set
  (``_vmap_qnetworkN0`` of ``SACLoss``, ``_vmap_qvalue_network00`` of ``TD3Loss``), evaluated
  in turn by :class:`CriticsInTurn` (as ``_pseudo_vmap`` does), with the actor's parameters as
  :class:`ModuleOwnParams` (``TensorDictParams``'s ``_parameters`` and ``_buffers``);
- :class:`TwinCriticTD3Loss`: ``TD3Loss.actor_loss``'s helpers
  (``_maybe_get_priority_weight``, ``_cached_detach_qvalue_network_params``, ``_reduce_loss``,
  ``_clear_weakrefs``).
"""

from __future__ import annotations

from contextlib import nullcontext
from itertools import repeat

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictParams
from torch import nn
from torchrl.objectives import LossModule, SACLoss, SoftUpdate, TD3Loss

#: the TorchRL and tensordict private names this module uses, and no other
PRIVATE_NAMES = (
    "_sources",
    "_targets",
    "_make_vmap",
    "_vmap_qnetworkN0",
    "_vmap_qvalue_network00",
    "_maybe_get_priority_weight",
    "_cached_detach_qvalue_network_params",
    "_reduce_loss",
    "_clear_weakrefs",
)


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


class TwinCriticSACLoss(FastUpdatePaths, SACLoss):
    """TorchRL's ``SACLoss``, with :class:`FastUpdatePaths` under ``deactivate_vmap``."""

    critics_attr, batched_inputs = "_vmap_qnetworkN0", False


class TwinCriticTD3Loss(FastUpdatePaths, TD3Loss):
    """TorchRL's ``TD3Loss``, with :class:`FastUpdatePaths` under ``deactivate_vmap``, where
    the actor's loss also evaluates the first critic only, the one it reads (TorchRL's
    evaluates both and discards the second's values; same loss, same gradients, one critic
    pass fewer)."""

    critics_attr, batched_inputs = "_vmap_qvalue_network00", True

    def actor_loss(self, tensordict):
        if not self.deactivate_vmap:
            return super().actor_loss(tensordict)
        weights = self._maybe_get_priority_weight(tensordict)
        actor_in = tensordict.select(*self.actor_network.in_keys, strict=False)
        with self.actor_network_params.to_module(self.actor_network, preserve_module_state=False):
            actor_out = self.actor_network(actor_in)
        critic_in = actor_out.select(*self.qvalue_network.in_keys, strict=False).unsqueeze(0)
        first_critic = self._cached_detach_qvalue_network_params[:1]
        value = self._vmap_qvalue_network00(critic_in, first_critic)
        value = value.get(self.tensor_keys.state_action_value).squeeze(-1)
        loss = self._reduce_loss(-value[0], tensordict=tensordict, weights=weights)
        self._clear_weakrefs(
            tensordict,
            "actor_network_params",
            "qvalue_network_params",
            "target_actor_network_params",
            "target_qvalue_network_params",
        )
        return loss, {"state_action_value_actor": value.detach()}
