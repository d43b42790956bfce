"""Observations derived from entries of the same step, as TorchRL transforms: the paper's
compound observation (Sec. 3.5, Figure 3), raw and filtered readings side by side, and the
filter's position uncertainty and estimate of the current's error (not in the paper).

The paper's policies read the EKF's estimate (Sec. 3.5) without its covariance: a position
fixed a moment ago and one predicted through a second of lost or refused USBL fixes look the
same to them. With the USBL at its own slow rate, late, with dropouts and gated outliers
(docs/realism.md), how far the estimate may be off changes within an episode; the filter's
covariance says by how much, and onboard the same covariance is at hand
(:class:`dockingrl.OnboardPolicy`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs.transforms import Transform

from dockingrl.transforms.ekf import STATE_DIM


class DerivedEntry(Transform):
    """Base of the transforms that write an entry computed from entries of the same step
    (``_call``), after each step and after each reset alike, with no state of their own."""

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict)

    def _reset(
        self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase
    ) -> TensorDictBase:
        return self._call(tensordict_reset)


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


def position_std(cov: torch.Tensor) -> torch.Tensor:
    """The standard deviations (m) of the estimate's ``x`` and ``y`` (the first two entries of
    the EKF state, eq. 22) from its covariance ``(..., n, n)``: ``(..., 2)``."""
    return cov.diagonal(dim1=-2, dim2=-1)[..., :2].clamp_min(0.0).sqrt()


class FilterPair(DerivedEntry):
    """Base of the transforms that write two numbers read off one of the filter's entries
    (``in_key``: its mean, :attr:`source_dims` 1, or its covariance, 2) as ``out_key``, after
    each step and reset (:meth:`pair`); place them after the filter."""

    source_dims = 1

    def __init__(self, in_key: str, out_key: str) -> None:
        super().__init__(in_keys=[in_key], out_keys=[out_key])

    @staticmethod
    def pair(source: torch.Tensor) -> torch.Tensor:
        """The two numbers ``(..., 2)`` of the filter's entry ``source``."""
        raise NotImplementedError

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict.set(self.out_keys[0], self.pair(next_tensordict.get(self.in_keys[0])))
        return next_tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        if self.in_keys[0] not in observation_spec.keys(True):
            raise ValueError(
                f"{type(self).__name__} needs {self.in_keys[0]!r}: place it after the EKF"
            )
        source = observation_spec[self.in_keys[0]]
        observation_spec[self.out_keys[0]] = Unbounded(
            shape=(*source.shape[: -self.source_dims], 2), device=source.device, dtype=source.dtype
        )
        return observation_spec


def check_estimates_current(ekf) -> None:
    """Refuse, in one line, a filter ``ekf`` (or ``None``) that does not estimate the current's
    error (:class:`~dockingrl.transforms.current_filter.CurrentEstimatingEKF`), for an
    observation of that estimate."""
    if getattr(ekf, "state_dim", None) != STATE_DIM + 2:
        raise ValueError(
            "observe_current_error needs the filter that estimates the current's error "
            "(estimate_current=True)"
        )


class CurrentError(FilterPair):
    """Writes the filter's estimate of the error of the believed current, the last two entries
    of the mean of :class:`~dockingrl.transforms.current_filter.CurrentEstimatingEKF` (eq. 26's
    ``b``: the current it flies by is ``ocean_current + b``), as ``out_key`` (default
    ``current_error``), after each step and reset; place it after that filter.

    ``make_env(..., observe_current_error=True)`` appends it to ``observation``, after the
    current's. The mirror ``y -> -y`` negates its second entry, as the current's.
    """

    def __init__(self, ekf, *, out_key: str = "current_error") -> None:
        check_estimates_current(ekf)
        super().__init__(ekf.mean_key, out_key)

    @staticmethod
    def pair(source: torch.Tensor) -> torch.Tensor:
        return source[..., STATE_DIM:].clone()


class FilterStd(FilterPair):
    """Writes :func:`position_std` of the EKF's covariance (``cov_key``, as
    :class:`~dockingrl.transforms.EKFTransform` keeps it) as ``out_key`` (default
    ``filter_std``), after each step and reset; place it after the filter.

    ``make_env(..., observe_filter_std=True)`` appends it to ``observation`` with
    :class:`~dockingrl.transforms.CompoundObservation`, after the scenario's entries. The
    mirror ``y -> -y`` leaves both numbers unchanged.
    """

    source_dims = 2

    def __init__(self, *, cov_key: str = "ekf_cov", out_key: str = "filter_std") -> None:
        super().__init__(cov_key, out_key)

    @staticmethod
    def pair(source: torch.Tensor) -> torch.Tensor:
        return position_std(source)
