"""The start state of an episode of :class:`~dockingrl.env.DockingEnv`: Sec. 4.1's uniform
draws of pose and current, then the training curricula's (not in the paper) biases of them,
all from the env's generator in a fixed order, so that a seed gives the same episodes."""

from __future__ import annotations

import torch

from dockingrl.env.config import DockingConfig


def uniform(low: float, high: float, n: int, generator, device, dtype) -> torch.Tensor:
    """``(n,)`` draws of ``U(low, high)``."""
    return low + (high - low) * torch.rand(n, generator=generator, device=device, dtype=dtype)


def paper_start(
    config: DockingConfig, n: int, generator, device, dtype
) -> tuple[torch.Tensor, torch.Tensor]:
    """Sec. 4.1's start of ``n`` episodes: ``(pose, current)``, ``(n, 3)`` ``(x, y, alpha)``
    within ``init_x``, ``init_y``, ``init_heading`` and ``(n, 2)`` ``(oc_x, oc_y)`` within
    ``ocean_current_range``, all uniform and independent."""
    cfg = config
    pose = torch.stack(
        (
            uniform(*cfg.init_x, n, generator, device, dtype),
            uniform(*cfg.init_y, n, generator, device, dtype),
            uniform(*cfg.init_heading, n, generator, device, dtype),
        ),
        dim=-1,
    )
    current = torch.stack(
        (
            uniform(*cfg.ocean_current_range, n, generator, device, dtype),
            uniform(*cfg.ocean_current_range, n, generator, device, dtype),
        ),
        dim=-1,
    )
    return pose, current


def training_start(
    config: DockingConfig, pose: torch.Tensor, current: torch.Tensor, generator, device, dtype
) -> None:
    """Bias the paper's start ``pose`` and ``current`` (:func:`paper_start`, changed in place)
    by the training curricula that are on: ``following_current_fraction``,
    ``lateral_current_fraction`` and ``near_start_fraction`` of :class:`DockingConfig`."""
    cfg, n = config, pose.shape[0]
    if cfg.following_current_fraction > 0:
        # reflect oc_x into the upper half of the range: still uniform there
        mid = 0.5 * sum(cfg.ocean_current_range)
        follow = uniform(0.0, 1.0, n, generator, device, dtype) < cfg.following_current_fraction
        upper = mid + (current[:, 0] - mid).abs()
        current[:, 0] = torch.where(follow, upper, current[:, 0])
    if cfg.lateral_current_fraction > 0:
        # fold |oc_y - mid| into the outer half of the range, sign kept: uniform there
        low, high = cfg.ocean_current_range
        mid, half = 0.5 * (low + high), 0.5 * (high - low)
        strong = uniform(0.0, 1.0, n, generator, device, dtype) < cfg.lateral_current_fraction
        offset = current[:, 1] - mid
        outer = mid + torch.sign(offset) * (0.5 * half + 0.5 * offset.abs())
        current[:, 1] = torch.where(strong, outer, current[:, 1])
    if cfg.near_start_fraction > 0:
        near = uniform(0.0, 1.0, n, generator, device, dtype) < cfg.near_start_fraction
        near_xy = torch.stack(
            (
                uniform(*cfg.near_start_x, n, generator, device, dtype),
                uniform(*cfg.near_start_y, n, generator, device, dtype),
            ),
            dim=-1,
        )
        pose[:, :2] = torch.where(near.unsqueeze(-1), near_xy, pose[:, :2])


def pinned(value, size: int, name: str, n: int, device, dtype) -> torch.Tensor | None:
    """``value`` (``(n, size)`` or ``(size,)``, broadcast to every env) as a checked ``(n,
    size)`` copy on ``device`` in ``dtype``, or ``None`` for ``None``: a start that
    :meth:`DockingEnv.set_initial_state <dockingrl.env.DockingEnv.set_initial_state>` pins."""
    if value is None:
        return None
    value = torch.as_tensor(value, dtype=dtype, device=device)
    if value.shape not in ((size,), (n, size)):
        raise ValueError(f"{name} must be ({n}, {size}) or ({size},), got {tuple(value.shape)}")
    value = value.expand(n, size)
    if not bool(torch.isfinite(value).all()):
        raise ValueError(f"{name} must be finite")
    return value.clone()
