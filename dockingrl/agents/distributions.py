"""The actors' action distribution: a Normal squashed by tanh into the action bounds.

:class:`BoundedTanhNormal` computes what TorchRL's ``TanhNormal`` (``tanh_loc=False``,
``safe_tanh=True``, one event dimension) computes, with the same operations in the same order,
so samples, log-probabilities and their gradients are equal to the last bit for the same random
state (``tests/test_algorithms.py``; bounds given as numbers take the parameters' dtype here,
where ``TanhNormal`` keeps them in the default dtype, so float64 parameters with number bounds
differ by rounding). It builds no ``torch.distributions`` transform chain and
checks no argument on construction: SAC builds two distributions per update, and that
construction and the chain's log-determinant bookkeeping were 11 % of an eager SAC update at the
paper's sizes on a 2-core CPU (``results/bench/update_speed.md``).
"""

from __future__ import annotations

import math

import torch
from torch import distributions as D
from torch.distributions.utils import _standard_normal
from torch.nn.functional import softplus
from torchrl.modules.distributions.utils import safeatanh_noeps as torchrl_safeatanh_noeps

_LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))
_LOG_2 = math.log(2.0)


def _bound(x: torch.Tensor) -> float:
    """How close to 1 a tanh may come in ``x``'s dtype (TorchRL's ``safetanh`` bound)."""
    return 1.0 - torch.finfo(x.dtype).resolution


class _SafeTanh(torch.autograd.Function):
    """TorchRL's ``safetanh_noeps``: tanh clamped inside ``(-1, 1)``, with the gradient
    ``1 - output**2`` of the clamped output; the same operations, as a Function of the older
    style, whose ``apply`` skips the signature binding the newer style does on every call
    (about 40 us, twice per SAC update)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        lim = _bound(x)
        output = x.tanh().clamp(-lim, lim)
        ctx.save_for_backward(output)
        return output

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (output,) = ctx.saved_tensors
        return grad * (1 - output.pow(2))


def safetanh_noeps(x: torch.Tensor) -> torch.Tensor:
    """TorchRL's ``safetanh_noeps`` (:class:`_SafeTanh`)."""
    return _SafeTanh.apply(x)


def safeatanh_noeps(value: torch.Tensor) -> torch.Tensor:
    """TorchRL's ``safeatanh_noeps``: atanh of the value clamped inside ``(-1, 1)``; without a
    gradient to carry (a stored action), its forward operations alone, without the Function."""
    if value.requires_grad and torch.is_grad_enabled():
        return torchrl_safeatanh_noeps(value)
    lim = _bound(value)
    return value.clamp(-lim, lim).atanh()


class BoundedTanhNormal(D.Distribution):
    """``low + (high - low) (tanh(u) + 1) / 2`` with ``u ~ Normal(loc, scale)``, per action
    entry; the last dimension is the event (log-probabilities sum over it).

    ``deterministic_sample`` (what ``ExplorationType.DETERMINISTIC`` reads) is the squashed
    ``loc``. ``rsample_and_log_prob`` scores the exact pre-tanh draw, so saturated samples get
    their true log-probability; ``log_prob`` of a given action inverts the squashing with
    TorchRL's clamped ``atanh``.
    """

    has_rsample = True
    arg_constraints: dict = {}

    def __init__(
        self,
        loc: torch.Tensor,
        scale: torch.Tensor,
        low: torch.Tensor | float = -1.0,
        high: torch.Tensor | float = 1.0,
    ) -> None:
        low = torch.as_tensor(low, dtype=loc.dtype, device=loc.device)
        high = torch.as_tensor(high, dtype=loc.dtype, device=loc.device)
        self.loc, self.scale, self.low, self.high = loc, scale, low, high
        self._centre, self._half_width = (high + low) / 2, (high - low) / 2
        super().__init__(loc.shape[:-1], loc.shape[-1:], validate_args=False)

    @property
    def support(self):
        return D.constraints.independent(D.constraints.interval(self.low, self.high), 1)

    def _squash(self, preimage: torch.Tensor) -> torch.Tensor:
        return self._centre + self._half_width * safetanh_noeps(preimage)

    def _preimage(self, sample_shape, reparameterised: bool = True) -> torch.Tensor:
        """A Normal draw, as ``torch.distributions.Normal`` makes it: ``rsample`` shifts and
        scales a standard draw, ``sample`` calls ``torch.normal`` without gradient."""
        shape = self._extended_shape(torch.Size(sample_shape))
        if not reparameterised:
            with torch.no_grad():
                return torch.normal(self.loc.expand(shape), self.scale.expand(shape))
        eps = _standard_normal(shape, dtype=self.loc.dtype, device=self.loc.device)
        return self.loc + eps * self.scale

    def _log_prob_of_preimage(self, preimage: torch.Tensor) -> torch.Tensor:
        """The Normal's log-density of ``preimage`` minus the log-determinant of the squashing
        (tanh's, in its overflow-free form, then the affine map's)."""
        normal = (
            -((preimage - self.loc) ** 2) / (2 * self.scale**2) - self.scale.log() - _LOG_SQRT_2PI
        )
        tanh_log_det = 2.0 * (_LOG_2 - preimage - softplus(-2.0 * preimage))
        log_det = tanh_log_det + self._half_width.abs().log()
        return normal.sum(-1) - log_det.sum(-1)

    def rsample_and_log_prob(self, sample_shape=()) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised sample and its log-probability (SAC's actor loss and target)."""
        preimage = self._preimage(sample_shape)
        return self._squash(preimage), self._log_prob_of_preimage(preimage)

    def sample_and_log_prob(self, sample_shape=()) -> tuple[torch.Tensor, torch.Tensor]:
        """A sample without pathwise gradient and its differentiable log-probability."""
        preimage = self._preimage(sample_shape, reparameterised=False)
        with torch.no_grad():
            sample = self._squash(preimage)
        return sample, self._log_prob_of_preimage(preimage)

    def rsample(self, sample_shape=()) -> torch.Tensor:
        return self._squash(self._preimage(sample_shape))

    def sample(self, sample_shape=()) -> torch.Tensor:
        with torch.no_grad():
            return self._squash(self._preimage(sample_shape, reparameterised=False))

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        preimage = safeatanh_noeps((value - self._centre) / self._half_width)
        return self._log_prob_of_preimage(preimage)

    @property
    def deterministic_sample(self) -> torch.Tensor:
        return self._squash(self.loc)
