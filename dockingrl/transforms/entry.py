"""A transform that computes entries of the observation from others of the same step."""

from __future__ import annotations

from tensordict import TensorDictBase
from torchrl.envs.transforms import Transform


class DerivedEntry(Transform):
    """Base of the transforms that write an entry computed from entries of the same step
    (``_call``), after each step and after each reset alike, with no state of their own."""

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict)

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        return self._call(tensordict_reset)
