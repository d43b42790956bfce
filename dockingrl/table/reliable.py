"""rliable's statistics for Table 6 (Agarwal et al., "Deep reinforcement learning at the edge of
the statistical precipice", NeurIPS 2021): the interquartile mean (IQM) of success over runs
and scenarios, and the probability of improvement of one recipe or scenario over another, each
with a stratified bootstrap interval (resampling the runs of each scenario apart).

Scores are success fractions in [0, 1], one row per training seed and one column per scenario
(a "task" in rliable's terms). The bootstrap is seeded (:data:`BOOTSTRAP_SEED`), so a table
made twice from the same runs is the same table. With five seeds a bootstrap interval is
coarse: a claim holds only where the whole interval of the probability of improvement lies
above 1/2 (fails: below).
"""

from __future__ import annotations

import warnings

import numpy as np

#: resamples of each bootstrap
BOOTSTRAP_REPS = 2000
#: the bootstrap's random state
BOOTSTRAP_SEED = 0
#: confidence level of every interval
LEVEL = 0.95
#: seeds a side of a comparison needs: two seeds of each side apart is one chance in six
MIN_SEEDS = 3


def _rliable():
    """The ``rliable`` package, or a one-line error saying how to install it."""
    try:
        import rliable.library
        import rliable.metrics
    except ImportError as exc:
        raise RuntimeError(
            f"the table's statistics need rliable ({exc}): pip install 'dockingrl[stats]'"
        ) from None
    return rliable


def _interval_estimate(scores: dict, func) -> tuple[float, list[float]]:
    """rliable's point estimate and stratified percentile-bootstrap interval of ``func`` over
    the one entry of ``scores``."""
    library = _rliable().library
    state = np.random.RandomState(BOOTSTRAP_SEED)
    # rliable's bootstraps draw their resamples from NumPy's global generator
    # (``StratifiedBootstrap.update_indices``), not from ``random_state``: seed it for the call
    # and give the caller's state back
    saved = np.random.get_state()
    np.random.seed(BOOTSTRAP_SEED)
    try:
        with warnings.catch_warnings():  # arch's notice that a RandomState will be deprecated
            warnings.simplefilter("ignore", FutureWarning)
            estimate, interval = library.get_interval_estimates(
                scores,
                func,
                reps=BOOTSTRAP_REPS,
                confidence_interval_size=LEVEL,
                random_state=state,
            )
    finally:
        np.random.set_state(saved)
    (key,) = scores
    low, high = np.asarray(interval[key], dtype=float).ravel()[:2]
    return float(np.asarray(estimate[key]).ravel()[0]), [float(low), float(high)]


def scores_matrix(per_seed: list[list[float]]) -> np.ndarray:
    """``(runs, tasks)`` success fractions from per-task lists of per-seed success in %: each
    task keeps its own seeds, so every task needs as many."""
    counts = {len(p) for p in per_seed}
    if len(counts) != 1:
        raise ValueError(f"every scenario needs the same number of seeds (got {sorted(counts)})")
    return np.asarray(per_seed, dtype=float).T / 100.0


def iqm(scores: np.ndarray) -> dict:
    """The IQM of ``scores`` ``(runs, tasks)`` in %, with its stratified bootstrap interval:
    ``{"iqm", "ci95"}``."""
    metrics = _rliable().metrics

    def aggregate(s):
        return np.array([metrics.aggregate_iqm(s)])

    value, (low, high) = _interval_estimate({"x": scores}, aggregate)
    return {"iqm": 100 * value, "ci95": [100 * low, 100 * high]}


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> dict:
    """``P(X > Y)``: the chance that a run of ``x`` scores above a run of ``y`` on the same task
    (ties count half), averaged over the tasks, with its stratified bootstrap interval:
    ``{"probability", "ci95"}``."""
    metrics = _rliable().metrics
    value, interval = _interval_estimate({"x,y": (x, y)}, metrics.probability_of_improvement)
    return {"probability": value, "ci95": interval}


def improvement_verdict(result: dict | None, holds: str, fails: str) -> str:
    """``holds`` where the interval of the probability of improvement lies above 1/2,
    ``fails`` where it lies below, else not resolved."""
    if result is None:
        return "too few seeds to tell"
    low, high = result["ci95"]
    if low > 0.5:
        return holds
    if high < 0.5:
        return fails
    return "not resolved: the interval contains 1/2"


def compare(a: list[float], b: list[float]) -> dict | None:
    """The probability that a seed of ``a`` (success % per seed on one scenario) beats one of
    ``b``, with its interval; None with fewer than :data:`MIN_SEEDS` seeds on a side."""
    if min(len(a), len(b)) < MIN_SEEDS:
        return None
    x = np.asarray(a, dtype=float).reshape(-1, 1) / 100
    y = np.asarray(b, dtype=float).reshape(-1, 1) / 100
    return probability_of_improvement(x, y)
