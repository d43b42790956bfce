"""Success of the privileged planner (:mod:`dockingrl.planning`) over ocean-current cells:
which cells of Figure 9's map can be docked at all under eq. 3's command bounds and the
0.3 m/s contact limit.

    python scripts/oracle_map.py --oc-x-min 0.075 --abs-oc-y-min 0.225 --trials 10 \
        --samples 256 --horizon 30 --iterations 4 --out results/oracle/hard_cells.json \
        --figure results/oracle/hard_cells \
        --compare results/oracle/sac_without_bonus_map/success_map.json

Cells are those of ``dockingrl eval --map`` (``--cells`` values per axis in
``[-limit, limit]``), optionally only the ones with ``oc_x >= --oc-x-min`` and
``|oc_y| >= --abs-oc-y-min``. ``--vehicle fossen`` flies (and plans on) the Fossen vehicle
(docs/vehicles.md) instead of the paper's model. Each cell runs ``--trials`` episodes from
random start poses (``--seed``), the planner choosing every command from the true state or,
with ``--state filter``, from the EKF's estimate in the compound scenario's noisy world.
``--compare`` prints a learner's ``success_map.json`` beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch

from dockingrl.env.config import DockingConfig
from dockingrl.evaluation import (
    base_env,
    current_grid,
    describe_machine,
    episode_record,
    run_episodes,
)
from dockingrl.io import write_json
from dockingrl.planning import PlannerConfig, PlannerPolicy
from dockingrl.plots import plot_success_map, plot_trajectories
from dockingrl.provenance import script_command
from dockingrl.scenarios import make_env


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="JSON file to write")
    parser.add_argument("--cells", type=int, default=9)
    parser.add_argument("--limit", type=float, default=0.3)
    parser.add_argument("--oc-x-min", type=float, default=-np.inf)
    parser.add_argument("--abs-oc-y-min", type=float, default=0.0)
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="start poses' seed")
    parser.add_argument("--samples", type=int, default=PlannerConfig.samples)
    parser.add_argument("--iterations", type=int, default=PlannerConfig.iterations)
    parser.add_argument("--horizon", type=int, default=PlannerConfig.horizon)
    parser.add_argument(
        "--state",
        choices=("true", "filter"),
        default="true",
        help="plan from the true state (true observation) or from the EKF's estimate of "
        "the noisy readings (the compound scenario's world)",
    )
    parser.add_argument("--speed-margin", type=float, default=PlannerConfig.speed_margin)
    parser.add_argument("--min-score", type=float, default=PlannerConfig.min_score)
    parser.add_argument("--compare", default="", help="a learner's success_map.json")
    parser.add_argument(
        "--figure",
        default="",
        help="also draw PREFIX_map.png (the planner's success per cell) and PREFIX_paths.png "
        "(the final approach of each cell's first trial)",
    )
    parser.add_argument(
        "--vehicle",
        choices=("paper", "fossen"),
        default="paper",
        help="the vehicle the planner flies and plans on (docs/vehicles.md)",
    )
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    grid = current_grid(args.cells, args.limit)
    eps = 1e-9
    cells = [
        (float(x), float(y))
        for y in grid
        for x in grid
        if x >= args.oc_x_min - eps and abs(y) >= args.abs_oc_y_min - eps
    ]
    if not cells:
        parser.error("no cell matches --oc-x-min and --abs-oc-y-min")
    currents = np.repeat(np.array(cells), args.trials, axis=0)
    planner = PlannerPolicy(
        PlannerConfig(
            samples=args.samples,
            iterations=args.iterations,
            horizon=args.horizon,
            elites=max(2, args.samples // 10),
            seed=args.seed,
            state=args.state,
            speed_margin=args.speed_margin,
            min_score=args.min_score,
        )
    )
    scenario = "no_noise" if args.state == "true" else "compound"
    config = DockingConfig(vehicle=args.vehicle)
    env = make_env(scenario, len(currents), seed=args.seed, config=config)
    base_env(env).set_initial_state(ocean_current=torch.as_tensor(currents))
    start = time.perf_counter()
    out = run_episodes(planner, env, progress=sys.stderr.isatty(), record_trajectories=True)
    wall = time.perf_counter() - start
    learner = {}
    if args.compare:
        with open(args.compare) as f:
            data = json.load(f)
        for i, y in enumerate(data["oc_y"]):
            for j, x in enumerate(data["oc_x"]):
                learner[(round(x, 6), round(y, 6))] = data["success_rate"][i][j]
    rows = []
    shape = (len(cells), args.trials)
    success = out["success"].reshape(shape)
    for c, (x, y) in enumerate(cells):
        rows.append(
            {
                "oc_x": x,
                "oc_y": y,
                "success_rate": float(success[c].double().mean() * 100),
                "docked": out["docked"].reshape(shape)[c].tolist(),
                "contact_speed": out["contact_speed"].reshape(shape)[c].tolist(),
                "contact_score": out["contact_score"].reshape(shape)[c].tolist(),
                "time_s": (out["steps"].reshape(shape)[c] * base_env(env).config.dt).tolist(),
            }
        )
        other = learner.get((round(x, 6), round(y, 6)))
        other = "" if other is None else f"   learner {other:5.1f} %"
        print(f"oc = ({x:+.3f}, {y:+.3f})  planner {rows[-1]['success_rate']:5.1f} %{other}")
    rate = float(success.double().mean() * 100)
    print(f"planner success over these cells: {rate:.1f} % ({wall:.0f} s)")
    command = script_command("oracle_map.py", argv)
    if args.figure:
        draw(args.figure, grid, rows, out, args.trials, base_env(env).config, command, wall)
    write_json(
        args.out,
        {
            "command": command,
            "planner": vars(planner.config),
            "scenario": scenario,
            "vehicle": args.vehicle,
            "trials_per_cell": args.trials,
            "seed": args.seed,
            "success_rate": rate,
            "cells": rows,
            "wall_clock_s": wall,
            "machine": describe_machine("cpu"),
        },
    )
    return 0


def draw(prefix, grid, rows, out, trials, config, command, wall) -> None:
    """The planner's success per cell (NaN where not run) and each cell's first approach."""
    index = {round(float(v), 6): i for i, v in enumerate(grid)}
    rate = np.full((len(grid), len(grid)), np.nan)
    cases = []
    for c, row in enumerate(rows):
        rate[index[round(row["oc_y"], 6)], index[round(row["oc_x"], 6)]] = row["success_rate"]
        first = episode_record(out, c * trials, config)
        cases.append({"ocean_current": (row["oc_x"], row["oc_y"]), **first})
    footer = f"{command}  |  {describe_machine('cpu')}, {wall:.0f} s"
    result = {"oc_x": grid.tolist(), "oc_y": grid.tolist(), "success_rate": rate}
    title = f"privileged planner: success %, {trials} trials per cell"
    plot_success_map(result, f"{prefix}_map.png", title=title, footer=footer)
    plot_trajectories(
        cases, f"{prefix}_paths.png", columns=4, footer=footer, window=(-6.0, 2.0, -4.0, 4.0)
    )


if __name__ == "__main__":
    sys.exit(main())
