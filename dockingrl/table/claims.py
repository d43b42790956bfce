"""The paper's claims about Table 6, tested on its cells: compound against each other scenario
(the difference of the seeds' mean success, and rliable's probability of improvement over seeds
with its stratified bootstrap interval, :mod:`dockingrl.table.reliable`, the paper's difference
beside it), success at 200 k env steps per recipe (the same test), and the time to dock
successfully against the managed surge controller (Welch's t-test over episodes, scipy's: a
comparison of episodes, not of runs).

A cell's interval of its mean over seeds is Student's t (:func:`seed_ci`): a percentile
bootstrap of the mean of a few seeds is about their range, which covers the true mean less
often than it says.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from dockingrl.evaluation import PAPER_RESULTS
from dockingrl.io import first_line
from dockingrl.table.checks import field_problem
from dockingrl.table.reliable import compare, improvement_verdict

#: confidence level of every interval
LEVEL = 0.95


def episodes_ci(success_per_seed, episodes_per_seed) -> list[float]:
    """95 % Wilson interval (%) of the success rate over all the episodes of the seeds'
    evaluations (``success_per_seed`` in %, over ``episodes_per_seed`` episodes each),
    :meth:`scipy.stats.binomtest.proportion_ci`."""
    from scipy.stats import binomtest

    pairs = zip(success_per_seed, episodes_per_seed, strict=True)
    docked = round(sum(s * n / 100 for s, n in pairs))
    wilson = binomtest(docked, sum(episodes_per_seed)).proportion_ci(method="wilson")
    return [100 * wilson.low, 100 * wilson.high]


def seed_ci(values, low: float = 0.0, high: float = 100.0) -> list[float] | None:
    """95 % Student-t interval of the mean of ``values`` (one per seed; :mod:`scipy.stats.t`),
    clipped to [``low``, ``high``]. None for fewer than two values or values that all agree:
    there is then no spread between seeds to estimate one from."""
    from scipy.stats import t

    values = np.asarray(values, dtype=float)
    if values.size < 2 or np.all(values == values[0]):
        return None
    sem = values.std(ddof=1) / np.sqrt(values.size)
    lo, hi = t.interval(LEVEL, values.size - 1, loc=values.mean(), scale=sem)
    return [float(max(lo, low)), float(min(hi, high))]


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
            improvement = compare(compound["success_per_seed"], c["success_per_seed"])
            verdict = improvement_verdict(
                improvement, "holds: compound higher", "fails: compound lower"
            )
            paper_c = PAPER_RESULTS.get((compound["algo"], "compound"))
            paper_o = PAPER_RESULTS.get((compound["algo"], other))
            out.append(
                {
                    "claim": f"compound >= {other}",
                    "recipe": recipe,
                    "difference_points": diff,
                    "probability_of_improvement": improvement,
                    "verdict": verdict,
                    "paper_difference_points": None
                    if paper_c is None or paper_o is None
                    else paper_c[0] - paper_o[0],
                }
            )
    for recipe in sorted({r for r, _ in cells}):
        early = {
            s: c["success_at_200k"]["per_seed"]
            for (r, s), c in cells.items()
            if r == recipe and c["success_at_200k"]["per_seed"]
        }
        if "compound" in early and len(early) > 1:
            out.append(
                _ahead(
                    f"compound learns fastest ({recipe}: success at 200 k env steps)",
                    early,
                    lambda scenario: scenario == "compound",
                    recipe,
                )
            )
    early = {
        r: c["success_at_200k"]["per_seed"]
        for (r, s), c in cells.items()
        if s == "compound" and c["success_at_200k"]["per_seed"]
    }
    algos = {r: c["algo"] for (r, s), c in cells.items()}
    if any(algos[r] == "sac" for r in early) and any(algos[r] != "sac" for r in early):
        out.append(
            _ahead(
                "SAC most sample-efficient (success at 200 k env steps, compound)",
                early,
                lambda recipe: algos[recipe] == "sac",
                "",
            )
        )
    return out


def _ahead(claim: str, groups: dict[str, list[float]], claimed, recipe: str) -> dict:
    """The claim that the groups ``claimed`` picks (a scenario, a recipe) are ahead of the
    others: the best of them against the best of the rest (means over seeds), Welch's t-test
    over their seeds' values."""
    means = {k: float(np.mean(v)) for k, v in groups.items()}
    mine = max((k for k in groups if claimed(k)), key=means.get)
    rest = max((k for k in groups if not claimed(k)), key=means.get)
    improvement = compare(groups[mine], groups[rest])
    verdict = improvement_verdict(improvement, f"holds: {mine} ahead", f"fails: {rest} ahead")
    return {
        "claim": claim,
        "recipe": recipe or mine,
        "values": means,
        "compared": [mine, rest],
        "difference_points": means[mine] - means[rest],
        "probability_of_improvement": improvement,
        "verdict": verdict,
    }


def read_baseline(path: Path) -> dict:
    """An evaluation's ``eval.json`` with its time to dock successfully (``time_success_s``:
    n, mean, std), checked as the table checks a run's (:func:`field_problem`)."""
    try:
        base = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"baseline {path}: not a readable eval.json ({first_line(e)})") from None
    if not isinstance(base, dict) or base.get("time_success_s") is None:
        raise ValueError(f"baseline {path}: not an evaluation's eval.json with time_success_s")
    problem = field_problem("eval", {"time_success_s": base["time_success_s"]})
    if problem:
        raise ValueError(f"baseline {path}: {problem}")
    return base


def _sample_std(stats: dict) -> float:
    """The sample standard deviation (``ddof=1``) of ``{"n", "mean", "std"}``, whose ``std`` an
    evaluation writes over its episodes with ``ddof=0``, as Welch's test takes it."""
    return stats["std"] * math.sqrt(stats["n"] / (stats["n"] - 1))


def faster_than_baseline(cells: dict[tuple[str, str], dict], baseline: dict) -> list[dict]:
    """The paper's claim that learned policies dock faster than the managed surge controller
    (Table 7): per recipe, the mean time of its ``noise`` and ``compound`` cells' successful
    dockings (pooled over seeds) against ``baseline``'s (an ``eval.json`` of the controller),
    with the p-value of Welch's t-test over the episodes
    (:func:`scipy.stats.ttest_ind_from_stats`). Only successes count: a contact too fast or
    beside the funnel ends an episode early without docking. Episodes of one cell's seeds are
    pooled as if independent, so the p-value is of these policies, not of the recipe."""
    from scipy.stats import ttest_ind_from_stats

    base = baseline["time_success_s"]
    out = []
    for (recipe, scenario), c in sorted(cells.items()):
        t = c["time_success_s"]
        if scenario not in ("noise", "compound") or t["n"] < 2 or base["n"] < 2:
            continue
        p = float(
            ttest_ind_from_stats(
                t["mean"],
                _sample_std(t),
                t["n"],
                base["mean"],
                _sample_std(base),
                base["n"],
                equal_var=False,
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
                "episodes": t["n"],
                "baseline_episodes": base["n"],
                "recipe": recipe,
                "difference_s": diff,
                "time_s": t["mean"],
                "baseline_time_s": base["mean"],
                "p_value": p,
                "verdict": verdict,
            }
        )
    return out
