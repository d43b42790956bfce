"""The paper's claims about Table 6, tested on its cells: compound against each other scenario
(difference of the seeds' mean success with a bootstrap interval, the paper's difference beside
it), success at 200 k env steps per recipe, and the time to dock against the managed surge
controller (Welch's t-test). Statistics are scipy's."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dockingrl.evaluation import PAPER_RESULTS

#: bootstrap resamples of every interval
RESAMPLES = 10_000


def bootstrap_ci(values, statistic=np.mean) -> list[float] | None:
    """95 % percentile-bootstrap interval of ``statistic`` over ``values`` (None for fewer
    than two values; the value itself twice when they are all equal)."""
    from scipy.stats import bootstrap

    values = np.asarray(values, dtype=float)
    if values.size < 2:
        return None
    if np.all(values == values[0]):
        return [float(values[0])] * 2
    res = bootstrap(
        (values,),
        statistic,
        n_resamples=RESAMPLES,
        method="percentile",
        random_state=np.random.default_rng(0),
    )
    return [float(res.confidence_interval.low), float(res.confidence_interval.high)]


def difference_ci(a, b) -> list[float] | None:
    """95 % percentile-bootstrap interval of mean(a) - mean(b), seeds resampled per group."""
    from scipy.stats import bootstrap

    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.size < 2 or b.size < 2:
        return None
    if np.all(a == a[0]) and np.all(b == b[0]):
        return [float(a[0] - b[0])] * 2
    res = bootstrap(
        (a, b),
        lambda x, y, axis=-1: x.mean(axis) - y.mean(axis),
        n_resamples=RESAMPLES,
        method="percentile",
        random_state=np.random.default_rng(0),
    )
    return [float(res.confidence_interval.low), float(res.confidence_interval.high)]


def claims(cells: dict[tuple[str, str], dict]) -> list[dict]:
    """The paper's claims about Table 6, measured on the cells: per recipe, compound against
    each other scenario (difference of mean success over seeds, with its interval), and which
    recipe has the highest success at 200 k env steps on the compound scenario."""
    out = []
    for recipe in sorted({r for r, _ in cells}):
        compound = cells.get((recipe, "compound"))
        if compound is None:
            continue
        for other in ("noise", "filtered", "no_noise"):
            c = cells.get((recipe, other))
            if c is None:
                continue
            diff = compound["success_mean"] - c["success_mean"]
            ci = difference_ci(compound["success_per_seed"], c["success_per_seed"])
            if ci is None:
                verdict = "too few seeds to tell"
            elif ci[0] > 0:
                verdict = "holds: compound higher"
            elif ci[1] < 0:
                verdict = "fails: compound lower"
            else:
                verdict = "not resolved: the interval contains 0"
            paper_c = PAPER_RESULTS.get((compound["algo"], "compound"))
            paper_o = PAPER_RESULTS.get((compound["algo"], other))
            out.append(
                {
                    "claim": f"compound >= {other}",
                    "recipe": recipe,
                    "difference_points": diff,
                    "ci95": ci,
                    "verdict": verdict,
                    "paper_difference_points": None
                    if paper_c is None or paper_o is None
                    else paper_c[0] - paper_o[0],
                }
            )
    for recipe in sorted({r for r, _ in cells}):
        early = {
            s: c["success_at_200k"]["mean"]
            for (r, s), c in cells.items()
            if r == recipe and c["success_at_200k"]["mean"] is not None
        }
        if len(early) > 1:
            out.append(
                {
                    "claim": f"compound learns fastest ({recipe}: success at 200 k env steps)",
                    "values": early,
                    "best": max(early, key=early.get),
                }
            )
    early = {
        r: c["success_at_200k"]["mean"]
        for (r, s), c in cells.items()
        if s == "compound" and c["success_at_200k"]["mean"] is not None
    }
    if early:
        out.append(
            {
                "claim": "most sample-efficient (success at 200 k env steps, compound)",
                "values": early,
                "best": max(early, key=early.get),
            }
        )
    return out


def read_baseline(path: Path) -> dict:
    """An evaluation's ``eval.json`` with its time to dock (``time_s``: n, mean, std)."""
    try:
        base = json.loads(path.read_text())
        time = base["time_s"]
        if not all(isinstance(time[k], (int, float)) for k in ("n", "mean", "std")):
            raise TypeError("time_s n, mean and std must be numbers")
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(
            f"baseline {path}: not an evaluation's eval.json with time_s ({e})"
        ) from None
    return base


def faster_than_baseline(cells: dict[tuple[str, str], dict], baseline: dict) -> list[dict]:
    """The paper's claim that learned policies dock faster than the managed surge controller
    (Table 7): per recipe, the mean time to dock of its ``noise`` and ``compound`` cells (pooled
    over seeds' docked episodes) against ``baseline``'s (an ``eval.json`` of the controller),
    with the p-value of Welch's t-test over the episodes
    (:func:`scipy.stats.ttest_ind_from_stats`)."""
    from scipy.stats import ttest_ind_from_stats

    base = baseline["time_s"]
    out = []
    for (recipe, scenario), c in sorted(cells.items()):
        t = c["time_docked_s"]
        if scenario not in ("noise", "compound") or t["n"] < 2 or base["n"] < 2:
            continue
        p = float(
            ttest_ind_from_stats(
                t["mean"], t["std"], t["n"], base["mean"], base["std"], base["n"], equal_var=False
            ).pvalue
        )
        diff = t["mean"] - base["mean"]
        if p >= 0.05:
            verdict = "not resolved: p >= 0.05"
        else:
            verdict = "holds: faster" if diff < 0 else "fails: slower"
        out.append(
            {
                "claim": f"docks faster than the managed surge controller ({scenario})",
                "recipe": recipe,
                "difference_s": diff,
                "time_s": t["mean"],
                "baseline_time_s": base["mean"],
                "p_value": p,
                "verdict": verdict,
            }
        )
    return out
