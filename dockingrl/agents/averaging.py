"""The actor's exponential moving average (``actor_average``, not in the paper)."""

from __future__ import annotations

import copy

import torch
from torch import nn


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
