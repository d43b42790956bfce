"""The optimisation loop of a filter fit: Adam on ``Q`` and ``R`` by truncated
backpropagation through time over recorded rollouts (:func:`fit_filter`)."""

from __future__ import annotations

import torch
from tensordict import TensorDict

from dockingrl.env import DockingConfig
from dockingrl.filter_learning.objectives import run_filter
from dockingrl.filter_learning.options import LEARN_R, OBJECTIVES, FilterFit
from dockingrl.filter_learning.rollouts import record_rollouts
from dockingrl.transforms.ekf import MEASUREMENT_DIM
from dockingrl.transforms.filtering import EKFTransform
from dockingrl.transforms.noise import CONTEXT_FEATURES


def fit_filter(
    ekf: EKFTransform,
    fit: FilterFit,
    *,
    config: DockingConfig | None = None,
    data: TensorDict | None = None,
    log=None,
) -> list[float]:
    """Fit ``ekf``'s ``Q`` and ``R`` on rollouts of ``config`` by truncated BPTT; returns the
    loss per window. ``log(metrics, step)`` receives ``losses/...`` scalars."""
    if fit.objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {fit.objective!r}; valid: {', '.join(OBJECTIVES)}")
    if fit.window < 2 or fit.epochs < 1 or fit.num_envs < 1 or fit.steps <= fit.window:
        raise ValueError("need window >= 2, epochs >= 1, num_envs >= 1 and steps > window")
    if fit.whiteness < 0 or (fit.whiteness > 0 and fit.objective != "nll"):
        raise ValueError("whiteness is a non-negative weight of the nll objective only")
    if fit.learn_r not in LEARN_R:
        raise ValueError(f"unknown learn_r {fit.learn_r!r}; valid: {', '.join(LEARN_R)}")
    if fit.whiteness > 0 and not 1 <= fit.lags < fit.window:
        raise ValueError(f"need 1 <= lags < window, got lags={fit.lags}, window={fit.window}")
    if data is None:
        data = record_rollouts(
            fit.num_envs, fit.steps, config=config, behaviour=fit.behaviour, seed=fit.seed
        )
    ekf.set_learnable(True)
    optim = torch.optim.Adam(ekf.noise_parameters(), lr=fit.lr)
    frozen = torch.ones(MEASUREMENT_DIM, dtype=torch.bool)
    frozen[list(LEARN_R[fit.learn_r])] = False
    history = []
    for epoch in range(fit.epochs):
        state = None
        for start in range(0, data.shape[0], fit.window):
            window = data[start : start + fit.window]
            _, _, state, loss = run_filter(
                ekf,
                window,
                state=state,
                objective=fit.objective,
                whiteness=fit.whiteness,
                lags=fit.lags,
            )
            optim.zero_grad(set_to_none=True)
            loss.backward()
            _freeze_measurement_noise(ekf, frozen)
            optim.step()
            state = tuple(x.detach() for x in state)
            history.append(float(loss.detach()))
            if log is not None:
                log({f"losses/{fit.objective}": history[-1], "train/epoch": epoch}, len(history))
    ekf.set_learnable(False)
    return history


def _freeze_measurement_noise(ekf: EKFTransform, frozen: torch.Tensor) -> None:
    """Zero the gradients of ``R``'s ``frozen`` entries (its sigma and, with a context model,
    its context weights): Adam then leaves them where they are."""
    if not bool(frozen.any()):
        return
    grads = [(ekf.measurement_noise.log_std.grad, frozen)]
    if ekf.noise_context is not None:
        grads.append((ekf.noise_context.r_weight.grad, frozen.expand(len(CONTEXT_FEATURES), -1)))
    for grad, mask in grads:
        if grad is not None:
            grad[mask.to(grad.device)] = 0.0
