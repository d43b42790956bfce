"""What a grid costs on this machine, estimated before it runs: each recipe's trial trained for a
few minutes, its training rate measured past its warm-up, and its training time extrapolated.

Usage: ``python bench/grid_cost.py [table6] [--seconds 300] [--scenario compound] [--threads 1]
[--recipes sac td3]``

For each recipe of the grid, its first trial on ``--scenario`` (the trial's own config: the
grid's and the group's overrides included) trains for ``--seconds`` of wall-clock
(``time_budget_s``), with a CSV logger and a short selection and final evaluation, in a
temporary folder. From its ``curves.csv`` (``time/elapsed_s`` at each batch's env step), the
rate is that of the later two thirds of the window, past the uniformly random start steps and a
compiled update's first calls; the trial's training time is the time to the window's start plus
the remaining env steps at that rate (periodic evaluations included, as they fall in the
window). It is what a trial's ``train_wall_clock_s`` counts: the training loop, not the
selection among kept actors nor the final evaluation.

The grid runs one trial per core, two at once on 2 cores: run this beside one other 1-thread
job (a grid trial, or a second copy of this bench) to measure that condition. Recipes are run
one after another; rows print as each ends, then the grid's total in core-hours, beside the
mean ``train_wall_clock_s`` of the trials already in the grid's ``collect`` folder.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import statistics
import tempfile
import time
from pathlib import Path

import torch

from dockingrl.evaluation import describe_machine
from dockingrl.grid.files import Trial, load_grid


def elapsed_by_step(run_dir: Path) -> list[tuple[int, float]]:
    """``(env step, time/elapsed_s)`` of each logged batch of a run's ``curves.csv``."""
    with (run_dir / "curves.csv").open() as f:
        return [
            (int(row["step"]), float(row["value"]))
            for row in csv.DictReader(f)
            if row["key"] == "time/elapsed_s"
        ]


def extrapolate(points: list[tuple[int, float]], total_steps: int, warm_steps: int) -> dict:
    """The training time of ``total_steps`` env steps from ``points`` (step, elapsed s): the rate
    over the points past the first third of the time and past ``warm_steps`` env steps."""
    if len(points) < 3:
        raise ValueError(f"{len(points)} logged batches: train for longer (--seconds)")
    last_step, last_s = points[-1]
    start = next(
        (p for p in points if p[1] >= last_s / 3 and p[0] > warm_steps and p != points[-1]), None
    )
    if start is None:
        raise ValueError(f"no batch past {warm_steps} env steps within the window: --seconds")
    rate = (last_step - start[0]) / (last_s - start[1])
    return {
        "window_steps": [start[0], last_step],
        "window_s": round(last_s - start[1], 1),
        "steps_per_s": round(rate, 1),
        "estimate_s": round(start[1] + (total_steps - start[0]) / rate),
    }


def measure(trial: Trial, seconds: float, threads: int, out: Path) -> dict:
    """Train ``trial`` for ``seconds`` in ``out`` and extrapolate its training time."""
    from dockingrl.training import train

    short = {"logger": "csv", "final_eval_episodes": 10, "checkpoint_every": 0}
    short["time_budget_s"] = seconds
    if trial.config(out, threads).keep_best:
        short["select_episodes"] = 10  # the selection follows the training time measured
    cfg = dataclasses.replace(trial, overrides={**trial.overrides, **short}).config(out, threads)
    start = time.perf_counter()
    train(cfg, progress=False, command="bench/grid_cost.py")
    warm = getattr(cfg, "start_steps", 0) + 2 * getattr(cfg, "frames_per_batch", 0)
    row = extrapolate(elapsed_by_step(out / trial.name), cfg.total_steps, warm)
    return {
        "recipe": trial.recipe,
        "total_steps": cfg.total_steps,
        **row,
        "bench_wall_clock_s": round(time.perf_counter() - start, 1),
    }


def recorded_mean(collect: Path | None, recipe: str) -> tuple[int, float | None]:
    """How many of ``recipe``'s trials ``collect`` holds, and their mean training time."""
    if collect is None or not collect.is_dir():
        return 0, None
    times = [
        json.loads(p.read_text())["train_wall_clock_s"]
        for p in sorted(collect.glob(f"{recipe}__*/summary.json"))
    ]
    return len(times), (statistics.fmean(times) if times else None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("grid", nargs="?", default="table6", help="a shipped grid or a YAML file")
    parser.add_argument("--seconds", type=float, default=300.0, help="training window a recipe")
    parser.add_argument("--scenario", default="compound")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--recipes", nargs="*", help="only these recipes of the grid")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    grid = load_grid(args.grid)
    counts: dict[str, int] = {}
    for t in grid.trials:
        counts[t.recipe] = counts.get(t.recipe, 0) + 1
    firsts = {}
    for t in grid.trials:
        if t.scenario == args.scenario and t.recipe not in firsts:
            firsts[t.recipe] = t
    unknown = [r for r in args.recipes or () if r not in firsts]
    if unknown:
        parser.error(f"grid {grid.name} has no {args.scenario} trial of {', '.join(unknown)}")
    chosen = [firsts[r] for r in (args.recipes or firsts)]
    print(
        f"# {describe_machine('cpu')}; grid {grid.name}, "
        f"{args.seconds:.0f} s a recipe on {args.scenario}"
    )
    print("| recipe | trials | env steps | rate (steps/s) | estimate s | recorded mean s (n) |")
    print("|---|---|---|---|---|---|")
    total = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for trial in chosen:
            row = measure(trial, args.seconds, args.threads, Path(tmp))
            n, mean = recorded_mean(grid.collect, trial.recipe)
            total += counts[trial.recipe] * row["estimate_s"]
            shown = f"{mean:,.0f} ({n})" if mean is not None else "-"
            print(
                f"| {trial.recipe} | {counts[trial.recipe]} | {row['total_steps']:,} | "
                f"{row['steps_per_s']:,.1f} | {row['estimate_s']:,} | {shown} |",
                flush=True,
            )
    print(f"grid: {total / 3600:.1f} core-hours for the recipes measured")


if __name__ == "__main__":
    main()
