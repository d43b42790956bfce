"""The held-out protocol (docs/reproduction.md, "The held-out protocol"): every choice (a
recipe, a hyperparameter, a stage length, a checkpoint) is made on the tuning seeds 0-9; a
reported figure comes from training seeds 100 and up, evaluated on episodes whose seeds no
choice has seen.

Evaluation seeds are offsets from the training seed, one per purpose, so that a policy's
figures never share episodes with the evaluations that chose it: its run's final evaluation
(``seed + 10,000``, :class:`~dockingrl.training.trainer.Trainer`), its evaluation at a stress
level or on another vehicle after training (``seed + 20,000``). Periodic evaluations and the
choice of the final actor use ``1,000,000 +`` the env steps, the same for every seed, and never
a reported figure."""

from __future__ import annotations

from collections.abc import Iterable

#: training seeds on which choices are made
TUNING_SEEDS = range(0, 10)
#: the first training seed of reported figures
HELD_OUT_FROM = 100
#: the evaluation seed of a run's own final evaluation: the training seed plus this
FINAL_EVAL_OFFSET = 10_000
#: the evaluation seed of a trained policy at a stress level or on another vehicle
LEVEL_EVAL_OFFSET = 20_000


def seed_role(seed: int) -> str:
    """``"tuning"`` (0-9), ``"held-out"`` (100 and up) or ``"unassigned"`` (the rest)."""
    if seed in TUNING_SEEDS:
        return "tuning"
    return "held-out" if seed >= HELD_OUT_FROM else "unassigned"


def _ranges(seeds: list[int]) -> str:
    """``[100, 101, 102, 104]`` -> ``"100-102, 104"``."""
    parts, start = [], None
    for i, s in enumerate(seeds):
        if start is None:
            start = s
        if i + 1 == len(seeds) or seeds[i + 1] != s + 1:
            parts.append(f"{start}" if start == s else f"{start}-{s}")
            start = None
    return ", ".join(parts)


def seeds_label(seeds: Iterable[int]) -> str:
    """Which training seeds a figure is on and what they are for, e.g. ``"held-out seeds
    100-104"``, ``"tuning seed 0"`` or ``"seeds 0, 100 (tuning and held-out)"``."""
    seeds = sorted(set(int(s) for s in seeds))
    if not seeds:
        return "no seeds"
    roles = sorted({seed_role(s) for s in seeds})
    word = "seed" if len(seeds) == 1 else "seeds"
    if len(roles) == 1:
        return f"{roles[0]} {word} {_ranges(seeds)}"
    return f"{word} {_ranges(seeds)} ({' and '.join(roles)})"


def require_held_out(seeds: Iterable[int], what: str) -> None:
    """Refuse, in one line, a reported figure (``what``) on a seed below :data:`HELD_OUT_FROM`."""
    early = sorted(s for s in set(seeds) if s < HELD_OUT_FROM)
    if early:
        raise ValueError(
            f"{what}: training seed(s) {_ranges(early)} are not held out (tuning seeds are "
            f"{TUNING_SEEDS.start}-{TUNING_SEEDS.stop - 1}; reported figures use seeds "
            f">= {HELD_OUT_FROM}, docs/reproduction.md)"
        )


def level_eval_seed(train_seed: int) -> int:
    """The evaluation seed of a trained policy at a stress level or on another vehicle."""
    return train_seed + LEVEL_EVAL_OFFSET
