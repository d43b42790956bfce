"""The paper's Table 6 and Figures 6-8 from finished runs: per (recipe, scenario) cell, the
seeds' final 500-episode evaluations with intervals, the paper's values beside them, success
at 200 k env steps, learning curves over seeds, and the paper's claims tested.

Statistics are scipy's: the interval of a cell's mean success over seeds is Student's t
(:func:`~dockingrl.table.claims.seed_ci`; why not a bootstrap: :mod:`dockingrl.table.claims`);
the interval of the success rate over all of a cell's episodes is Wilson's
(:meth:`scipy.stats.binomtest.proportion_ci`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from dockingrl.evaluation import PAPER_RESULTS
from dockingrl.evaluation.protocol import require_held_out, seeds_label
from dockingrl.io import atomic_write, write_json
from dockingrl.provenance import shorten_folders
from dockingrl.table.checks import field_problem
from dockingrl.table.claims import (
    claims,
    episodes_ci,
    faster_than_baseline,
    read_baseline,
    seed_ci,
)
from dockingrl.table.markdown import markdown
from dockingrl.table.reliable import BOOTSTRAP_REPS, iqm, scores_matrix

SCENARIO_ORDER = ("no_noise", "noise", "filtered", "compound")
#: env steps at which the sample-efficiency column reads the periodic evaluations
EARLY_STEPS = 200_000


#: what the table reads of each run's files: the keys each must hold
_REQUIRED = {
    "config": ("algo", "scenario", "seed"),
    "summary": ("frames", "train_wall_clock_s"),
    "eval": ("episodes", "success_rate", "time_s", "total_reward"),
}
#: the curves of Figures 6-8: the periodic evaluations' and, for a recipe without them, the
#: training episodes' (key in curves.csv, axis label)
_EVAL_CURVES = (
    ("eval/success_rate", "success %"),
    ("eval/total_reward", "reward"),
    ("eval/episode_time_s", "episode time s"),
)
_TRAIN_CURVES = (
    ("train/success_rate", "success % (training episodes)"),
    ("train/episode_reward", "training reward"),
)
_CURVE_KEYS = {key for key, _ in _EVAL_CURVES + _TRAIN_CURVES}


def _read(run_dir: Path) -> dict | None:
    """A finished run's config, summary, final evaluation and success curve; None for a run
    folder whose run has not finished (no ``summary.json`` or ``eval.json`` yet). A folder that
    does not exist, or a file that is not what a run writes, is a one-line ``ValueError``."""
    if not run_dir.is_dir():
        what = "a file, not a run folder" if run_dir.exists() else "no such run folder"
        raise ValueError(f"{run_dir}: {what}")
    run: dict = {}
    for name, keys in _REQUIRED.items():
        path = run_dir / f"{name}.json"
        if not path.exists():
            return None
        try:
            value = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise ValueError(f"{path}: unreadable ({exc})") from None
        missing = [k for k in keys if not isinstance(value, dict) or k not in value]
        if missing:
            raise ValueError(f"{path}: not a run's {name} (no {', '.join(missing)})")
        if problem := field_problem(name, value):
            raise ValueError(f"{path}: {problem}")
        run[name] = value
    curves: dict[str, list[tuple[int, float]]] = {}
    path = run_dir / "curves.csv"
    if path.exists():
        for number, line in enumerate(path.read_text().splitlines()[1:], start=2):
            try:
                step, key, value = line.split(",")
                if key in _CURVE_KEYS:
                    curves.setdefault(key, []).append((int(step), float(value)))
            except ValueError:
                raise ValueError(f"{path}, line {number}: not step,key,value: {line!r}") from None
    run["curves"] = curves
    run["dir"] = run_dir
    return run


def _pooled(parts: list[dict]) -> dict:
    """Mean and std over the union of groups given as ``{"n", "mean", "std"}``."""
    parts = [p for p in parts if p.get("n")]
    n = sum(p["n"] for p in parts)
    if not n:
        return {"n": 0, "mean": float("nan"), "std": float("nan")}
    mean = sum(p["n"] * p["mean"] for p in parts) / n
    square = sum(p["n"] * (p["std"] ** 2 + p["mean"] ** 2) for p in parts) / n
    return {"n": n, "mean": mean, "std": math.sqrt(max(square - mean**2, 0.0))}


def _at(curve: list[tuple[int, float]], steps: int) -> tuple[int, float] | None:
    """The first periodic evaluation at or after ``steps``."""
    return next(((s, v) for s, v in curve if s >= steps), None)


def _same_split(splits: list[list[dict]]) -> None:
    """Refuse splits of the current (``by_current_x`` lists) whose thirds differ in name or
    range: their rates would be pooled or labelled as one."""
    labels = {tuple((p["oc_x"], tuple(p["range"])) for p in split) for split in splits}
    if len(labels) > 1:
        raise ValueError(f"runs split the current differently: {sorted(labels)}")


def by_current(runs: list[dict]) -> list[dict] | None:
    """A cell's success per third of the along-axis current (the final evaluations'
    ``by_current_x``: ``opposing``, ``weak``, ``following``), pooled over its seeds' episodes,
    with each seed's rate; None when a run's evaluation has no split."""
    splits = [r["eval"].get("by_current_x") for r in runs]
    if any(not s for s in splits):
        return None
    _same_split(splits)
    out = []
    for k, part in enumerate(splits[0]):
        groups = [s[k] for s in splits]
        episodes = sum(g["episodes"] for g in groups)
        # a third with no episode in a run has no rate (None)
        docked = sum((g["success_rate"] or 0.0) * g["episodes"] / 100 for g in groups)
        out.append(
            {
                "oc_x": part["oc_x"],
                "range": part["range"],
                "episodes": episodes,
                "success_rate": 100 * docked / episodes if episodes else None,
                "per_seed": [g["success_rate"] for g in groups],
                "timeouts": sum(g["failures"]["timeout"] for g in groups),
            }
        )
    return out


def by_fifth(runs: list[dict]) -> dict | None:
    """A cell's periodic success per fifth of its runs' env steps: in each fifth, the mean of
    a seed's periodic evaluations there, then the mean over the seeds that have one; with the
    number of seeds whose last fifth is above every earlier one (still rising when the budget
    ended them).
    None when no run has periodic evaluations."""
    per_seed = []
    for r in runs:
        curve, total = r["curves"].get("eval/success_rate") or [], r["summary"]["frames"]
        fifths = []
        for k in range(5):
            low, high = k * total / 5, (k + 1) * total / 5
            values = [v for s, v in curve if low < s <= high or (k == 4 and s > high)]
            fifths.append(float(np.mean(values)) if values else None)
        if any(v is not None for v in fifths):
            per_seed.append(fifths)
    if not per_seed:
        return None
    means = []
    for k in range(5):
        values = [f[k] for f in per_seed if f[k] is not None]
        means.append(float(np.mean(values)) if values else None)
    last_best = sum(
        f[4] is not None and all(v is None or f[4] > v for v in f[:4]) for f in per_seed
    )
    return {"mean": means, "per_seed": per_seed, "seeds_still_rising": int(last_best)}


def _configs_differ(runs: list[dict]) -> list[str]:
    """The fields beyond the seed, its first stage (``init_from``) and where and how fast each
    ran in which the configs of a cell's runs differ; a field a config lacks counts as its
    algorithm's default."""
    from dockingrl.agents.config import CONFIGS
    from dockingrl.agents.config_diff import config_mismatch

    first = runs[0]["config"]
    config_class = CONFIGS.get(first["algo"])
    defaults = config_class().to_dict() if config_class else {}
    wanted = {**defaults, **first}
    changed = {k for r in runs[1:] for k in config_mismatch(r["config"], wanted, defaults)}
    return sorted(changed - {"seed", "init_from"})  # each seed's own (a fine-tune's first stage)


def cell(runs: list[dict]) -> dict:
    """One cell of the table from its seeds' runs (every per-seed list in the order of
    ``seeds``). Raises ``ValueError`` for a seed given twice or runs of different configs
    (budgets, or any other field but the seed)."""
    runs = sorted(runs, key=lambda r: r["config"]["seed"])
    name = f"{runs[0]['config'].get('recipe') or runs[0]['config']['algo']} "
    name += runs[0]["config"]["scenario"]
    seeds = [r["config"]["seed"] for r in runs]
    twice = sorted({s for s in seeds if seeds.count(s) > 1})
    if twice:
        dirs = [str(r["dir"]) for r in runs if r["config"]["seed"] in twice]
        raise ValueError(f"cell {name}: seed {twice[0]} given twice ({', '.join(dirs)})")
    budgets = sorted({r["config"].get("total_steps") for r in runs}, key=str)
    if len(budgets) > 1:
        raise ValueError(f"cell {name}: its runs train for different total_steps {budgets}")
    differ = _configs_differ(runs)
    if differ:
        raise ValueError(
            f"cell {name}: its runs differ in {', '.join(differ)} beyond their seeds "
            f"({', '.join(str(r['dir']) for r in runs)}): not seeds of one config"
        )
    success = [r["eval"]["success_rate"] for r in runs]
    episodes = [r["eval"]["episodes"] for r in runs]
    early = [_at(r["curves"].get("eval/success_rate", []), EARLY_STEPS) for r in runs]
    early = [e for e in early if e is not None]
    algo = runs[0]["config"]["algo"]
    paper = PAPER_RESULTS.get((algo, runs[0]["config"]["scenario"]))
    best = max(runs, key=lambda r: r["eval"]["success_rate"])
    return {
        "recipe": runs[0]["config"].get("recipe", ""),
        "algo": algo,
        "scenario": runs[0]["config"]["scenario"],
        "seeds": seeds,
        "seeds_label": seeds_label(seeds),
        "success_per_seed": success,
        "success_mean": float(np.mean(success)),
        "success_ci95_over_seeds": seed_ci(success),
        "success_iqm": iqm(scores_matrix([success])) if len(success) > 1 else None,
        "success_ci95_over_episodes": episodes_ci(success, episodes),
        "episodes": sum(episodes),
        "time_docked_s": _pooled([r["eval"]["time_s"] for r in runs]),
        "time_success_s": _pooled([r["eval"].get("time_success_s") or {} for r in runs]),
        "total_reward": _pooled([r["eval"]["total_reward"] for r in runs]),
        "success_at_200k": {
            "mean": float(np.mean([v for _, v in early])) if early else None,
            "per_seed": [v for _, v in early],
            "steps": [s for s, _ in early],
        },
        "success_by_current_x": by_current(runs),
        "periodic_success_by_fifth": by_fifth(runs),
        "env_steps": [r["summary"]["frames"] for r in runs],
        "train_wall_clock_s": [r["summary"]["train_wall_clock_s"] for r in runs],
        "machine": sorted({r["summary"].get("machine", "") for r in runs}),
        "code": sorted({(r["summary"].get("code") or {}).get("commit") or "" for r in runs}),
        "best_seed": best["config"]["seed"],
        "paper": None
        if paper is None
        else dict(
            zip(
                ("success", "time_mean", "time_std", "reward_mean", "reward_std"),
                paper,
                strict=True,
            )
        ),
    }


def aggregates(cells: dict[tuple[str, str], dict]) -> list[dict]:
    """Per recipe whose cells all have the same number of seeds (two or more): rliable's IQM
    of success over its runs and scenarios, with a stratified bootstrap interval."""
    out = []
    for recipe in sorted({r for r, _ in cells}):
        mine = [cells[k] for k in sorted(cells) if k[0] == recipe]
        counts = {len(c["success_per_seed"]) for c in mine}
        if len(counts) != 1 or counts.pop() < 2:
            continue
        scores = scores_matrix([c["success_per_seed"] for c in mine])
        out.append(
            {
                "recipe": recipe,
                "scenarios": [c["scenario"] for c in mine],
                "seeds": mine[0]["seeds_label"],
                **iqm(scores),
            }
        )
    return out


def write_table(
    run_dirs,
    out: str | Path,
    *,
    prune_policies: bool = False,
    command: str = "dockingrl table",
    baseline: str | Path | None = None,
    held_out: bool = False,
) -> dict:
    """Read the finished runs among ``run_dirs``, write ``table.json``, ``table.md`` and one
    learning-curve figure per recipe (``figures_<recipe>.png``) into ``out``; returns the
    table. With ``prune_policies``, ``policy.pt`` is deleted from every run folder but the
    best seed's of each cell. ``baseline``: the managed surge controller's ``eval.json``, whose
    time to dock the learned policies' is tested against. ``held_out``: refuse a run on a
    training seed below 100 (:func:`dockingrl.evaluation.protocol.require_held_out`)."""
    out = Path(out)
    base = None if baseline is None else read_baseline(Path(baseline))
    run_dirs = [str(d) for d in run_dirs]
    runs = [r for r in (_read(Path(d)) for d in run_dirs) if r is not None]
    if not runs:
        raise ValueError("no finished run (config.json, summary.json and eval.json) given")
    if held_out:
        require_held_out((r["config"]["seed"] for r in runs), "dockingrl table --held-out")
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in runs:
        key = (r["config"].get("recipe") or r["config"]["algo"], r["config"]["scenario"])
        groups.setdefault(key, []).append(r)
    cells = {key: cell(group) for key, group in groups.items()}
    # one header labels every cell's thirds of the current in table.md
    _same_split([c["success_by_current_x"] for c in cells.values() if c["success_by_current_x"]])
    order = sorted(
        cells, key=lambda k: (k[0].startswith("paper-"), k[0], SCENARIO_ORDER.index(k[1]))
    )
    table = {
        "cells": [cells[k] for k in order],
        "aggregates": aggregates(cells),
        "claims": claims(cells) + (faster_than_baseline(cells, base) if base else []),
        "statistics": "success_ci95_over_seeds: Student-t interval of the mean over seeds "
        "(scipy.stats.t; '-' below two seeds); success_iqm and each recipe's IQM over its "
        "scenarios: rliable's interquartile mean with a stratified bootstrap interval "
        f"({BOOTSTRAP_REPS} resamples); claims over seeds: rliable's probability of "
        "improvement with its stratified bootstrap interval (holds where the interval lies "
        "above 1/2); success_ci95_over_episodes: Wilson "
        "interval over all the cell's final-evaluation episodes; time over docked episodes "
        "(any contact, as the paper's), reward over all episodes, pooled over seeds; the "
        "claim 'docks faster' over successful episodes only; success_at_200k: the first "
        f"periodic evaluation at or after {EARLY_STEPS} env steps (the step it was read at "
        "in brackets)",
    }
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "table.json", table)
    atomic_write(out / "table.md", lambda tmp: tmp.write_text(markdown(table)))
    shown = shorten_folders(command, run_dirs)
    for recipe in sorted({k[0] for k in cells}):
        group = {s: groups[(r, s)] for r, s in groups if r == recipe}
        machines = sorted({r["summary"].get("machine", "") for g in group.values() for r in g})
        hours = sum(r["summary"]["train_wall_clock_s"] for g in group.values() for r in g) / 3600
        footer = f"{shown}  |  {'; '.join(machines)}  |  {hours:.1f} h of training in all"
        plot_curves(group, recipe, out / f"figures_{recipe}.png", footer)
    if prune_policies:
        for key, group in groups.items():
            for r in group:
                if r["config"]["seed"] != cells[key]["best_seed"]:
                    (r["dir"] / "policy.pt").unlink(missing_ok=True)
    return table


def _steps_label(steps: float, _position=None) -> str:
    """An env-step tick as ``0``, ``250 k`` or ``1.5 M``."""
    if steps == 0:
        return "0"
    return f"{steps / 1e6:g} M" if abs(steps) >= 1e6 else f"{steps / 1e3:g} k"


def figure_curves(runs: list[dict]) -> tuple[tuple[tuple[str, str], ...], str]:
    """The curves a recipe's figure draws, as (key, axis label), and what they are: the
    periodic evaluations where any run has them, else the training episodes."""
    if any(r["curves"].get("eval/success_rate") for r in runs):
        return _EVAL_CURVES, "periodic evaluations"
    return (
        _TRAIN_CURVES,
        "training episodes (no periodic evaluation; the recipe's own draws and reward)",
    )


def plot_curves(
    by_scenario: dict[str, list[dict]], recipe: str, path: Path, footer: str = ""
) -> Path:
    """Figures 6-8 for one recipe: success, reward and time of the periodic evaluations
    against env steps, one line per scenario (mean over seeds) and a band (min to max). A
    recipe without periodic evaluations (``ppo``'s) gets its training episodes' success and
    reward instead, under the recipe's own draws and reward, and a title that says so."""
    from matplotlib.ticker import FuncFormatter

    from dockingrl.plots import _save, plt

    keys, what = figure_curves([r for group in by_scenario.values() for r in group])
    fig, axes = plt.subplots(1, len(keys), figsize=(5 * len(keys), 4.4))
    steps_format = FuncFormatter(_steps_label)
    for scenario in [s for s in SCENARIO_ORDER if s in by_scenario]:
        for ax, (key, _) in zip(axes, keys, strict=True):
            curves = [r["curves"][key] for r in by_scenario[scenario] if r["curves"].get(key)]
            if not curves:
                continue
            steps = np.array([s for s, _ in curves[0]], dtype=float)
            values = np.array(
                [np.interp(steps, [s for s, _ in c], [v for _, v in c]) for c in curves]
            )
            seeds = f"{len(curves)} seed" + ("s" if len(curves) > 1 else "")
            (line,) = ax.plot(steps, values.mean(0), label=f"{scenario} ({seeds})")
            ax.fill_between(steps, values.min(0), values.max(0), color=line.get_color(), alpha=0.2)
    for ax, (_, label) in zip(axes, keys, strict=True):
        ax.set_xlabel("env steps")
        ax.set_ylabel(label)
        ax.xaxis.set_major_formatter(steps_format)
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize=8)
    fig.suptitle(f"{recipe}: {what}, mean over seeds (band: min to max)")
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    return _save(fig, path, footer=footer)
