"""The filter's position uncertainty as an observation (not in the paper).

The paper's policies read the EKF's estimate (Sec. 3.5) without its covariance: a position
fixed a moment ago and one predicted through a second of lost or refused USBL fixes look the
same to them. With the USBL at its own slow rate, late, with dropouts and gated outliers
(docs/realism.md), how far the estimate may be off changes within an episode; the filter's
covariance says by how much, and onboard the same covariance is at hand
(:class:`dockingrl.OnboardPolicy`).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded

from dockingrl.transforms.entry import DerivedEntry


def position_std(cov: torch.Tensor) -> torch.Tensor:
    """The standard deviations (m) of the estimate's ``x`` and ``y`` (the first two entries of
    the EKF state, eq. 22) from its covariance ``(..., n, n)``: ``(..., 2)``."""
    return cov.diagonal(dim1=-2, dim2=-1)[..., :2].clamp_min(0.0).sqrt()


class FilterStd(DerivedEntry):
    """Writes :func:`position_std` of the EKF's covariance (``cov_key``, as
    :class:`~dockingrl.transforms.EKFTransform` keeps it) as ``out_key`` (default
    ``filter_std``), after each step and reset; place it after the filter.

    ``make_env(..., observe_filter_std=True)`` appends it to ``observation`` with
    :class:`~dockingrl.transforms.CompoundObservation`, after the scenario's entries. The
    mirror ``y -> -y`` leaves both numbers unchanged.
    """

    def __init__(self, *, cov_key: str = "ekf_cov", out_key: str = "filter_std") -> None:
        super().__init__(in_keys=[cov_key], out_keys=[out_key])

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict.set(self.out_keys[0], position_std(next_tensordict.get(self.in_keys[0])))
        return next_tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        if self.in_keys[0] not in observation_spec.keys(True):
            raise ValueError(f"FilterStd needs {self.in_keys[0]!r}: place it after the EKF")
        cov = observation_spec[self.in_keys[0]]
        observation_spec[self.out_keys[0]] = Unbounded(
            shape=(*cov.shape[:-2], 2), device=cov.device, dtype=cov.dtype
        )
        return observation_spec
