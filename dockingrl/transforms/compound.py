"""The paper's compound observation (Sec. 3.5, Figure 3): raw and filtered readings side by
side, as one TorchRL transform."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded

from dockingrl.transforms.entry import DerivedEntry


class CompoundObservation(DerivedEntry):
    """Concatenates observation entries in the given, fixed order (no sorting) into one key.

    The paper's compound observation (Sec. 3.5, Figure 3) is
    ``CompoundObservation(["observation", "filtered_observation"])``: raw first, then
    filtered, 12 numbers, written to ``observation`` (which the policy reads). With a single
    key it renames, as in the ``filtered`` scenario.

    Args:
        in_keys: entries to concatenate along the last dimension, in this order.
        out_key: where to write the result (default ``"observation"``, overwritten).
    """

    def __init__(self, in_keys: Sequence[str], out_key: str = "observation") -> None:
        if isinstance(in_keys, str) or len(in_keys) == 0:
            raise ValueError("in_keys must be a non-empty sequence of keys")
        super().__init__(in_keys=list(in_keys), out_keys=[out_key])

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        values = [next_tensordict.get(key) for key in self.in_keys]
        next_tensordict.set(self.out_keys[0], torch.cat(values, dim=-1))
        return next_tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        specs = [observation_spec[key] for key in self.in_keys]
        size = sum(spec.shape[-1] for spec in specs)
        first = specs[0]
        observation_spec[self.out_keys[0]] = Unbounded(
            shape=(*first.shape[:-1], size), device=first.device, dtype=first.dtype
        )
        return observation_spec
