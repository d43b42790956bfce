"""Table 6 under realistic assumptions: each finished trial's policy evaluated at stress level L5
(the paper's vehicle with realistic sensors, current and dynamics; 1,000 episodes) and at F0
(the Fossen vehicle on the paper's task, zero-shot; 2,000 episodes), on the evaluation seed of a
trained policy at a stress level (training seed + 20,000, ``dockingrl.evaluation.protocol``),
then one table per level of the shape of Table 6, with each cell's nominal figure beside it.

    python scripts/realistic_table6.py --runs runs/table6 --out results/table6 --threads 1

Each trial's evaluations go to ``OUT/realistic/TRIAL.json`` as they finish (a run again skips
them: interrupted, it resumes); ``OUT/realistic.md`` and ``OUT/realistic.json`` hold the tables.
Only held-out training seeds (100 and up) are taken. A trial evaluated once needs its
``policy.pt`` no more (``dockingrl table --prune-policies`` keeps only each cell's best seed's);
one with neither is left out, and named.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

#: each level, with its episodes a policy
LEVELS = {"L5": 1000, "F0": 2000}
SCENARIOS = ("no_noise", "noise", "filtered", "compound")


def finished_runs(root: Path) -> list[Path]:
    """The run folders under ``root`` whose run has finished (summary and eval) on a held-out
    training seed."""
    from dockingrl.evaluation.protocol import HELD_OUT_FROM

    runs = []
    for run in sorted(p for p in root.iterdir() if p.is_dir()):
        files = [run / n for n in ("summary.json", "eval.json", "config.json")]
        if all(f.is_file() for f in files):
            if json.loads((run / "config.json").read_text())["seed"] >= HELD_OUT_FROM:
                runs.append(run)
    return runs


def evaluate_trial(run: Path, threads: int) -> dict:
    """The trial's policy at each of :data:`LEVELS`, as ``{level: metrics}`` with the command,
    the machine and the wall-clock."""
    import torch

    from dockingrl.env import DockingConfig
    from dockingrl.evaluation import describe_machine
    from dockingrl.evaluation.protocol import level_eval_seed
    from dockingrl.policies import resolve_policy, trained_filter_options
    from dockingrl.provenance import script_command
    from dockingrl.stress import stress_ladder

    torch.set_num_threads(threads)
    config = json.loads((run / "config.json").read_text())
    policy, _, scenario, options, trained = resolve_policy(str(run / "policy.pt"))
    options = trained_filter_options(trained, scenario, options)
    seed = level_eval_seed(config["seed"])
    start = time.perf_counter()
    out: dict = {"trial": run.name, "recipe": config.get("recipe") or config["algo"]}
    out.update(scenario=scenario, training_seed=config["seed"], evaluation_seed=seed)
    out["levels"] = {}
    for level, episodes in LEVELS.items():
        result = stress_ladder(
            policy,
            scenario,
            episodes=episodes,
            levels=(level,),
            seed=seed,
            base=DockingConfig(),
            **options,
        )
        (row,) = result["levels"]
        keep = ("episodes", "success_rate", "failures", "time_success_s")
        out["levels"][level] = {k: row[k] for k in keep}
    nominal = json.loads((run / "eval.json").read_text())
    out["nominal"] = {"episodes": nominal["episodes"], "success_rate": nominal["success_rate"]}
    out.update(
        command=script_command("realistic_table6.py"),
        machine=describe_machine("cpu"),
        wall_clock_s=time.perf_counter() - start,
    )
    return out


def table(trials: list[dict]) -> dict:
    """Per level, the cells (recipe, scenario): success per seed, the mean with its Student-t
    interval over seeds and Wilson's over all the cell's episodes, failures summed over seeds,
    the nominal mean beside it."""
    from dockingrl.evaluation.protocol import seeds_label
    from dockingrl.table.claims import episodes_ci, seed_ci

    out: dict = {}
    for level in LEVELS:
        cells = {}
        for t in sorted(trials, key=lambda t: (t["recipe"], t["scenario"], t["training_seed"])):
            key = f"{t['recipe']}__{t['scenario']}"
            c = cells.setdefault(
                key,
                {
                    "recipe": t["recipe"],
                    "scenario": t["scenario"],
                    "seeds": [],
                    "success_per_seed": [],
                    "nominal": [],
                    "failures": {},
                    "episodes": 0,
                },
            )
            row = t["levels"][level]
            c["seeds"].append(t["training_seed"])
            c["success_per_seed"].append(row["success_rate"])
            c["nominal"].append(t["nominal"]["success_rate"])
            c["episodes"] += row["episodes"]
            for k, v in row["failures"].items():
                c["failures"][k] = c["failures"].get(k, 0) + v
        for c in cells.values():
            values = c["success_per_seed"]
            c["seeds_label"] = seeds_label(c["seeds"])
            c["success_mean"] = sum(values) / len(values)
            c["success_ci95_over_seeds"] = seed_ci(values)
            per_seed = [LEVELS[level]] * len(values)
            c["success_ci95_over_episodes"] = episodes_ci(values, per_seed)
            c["nominal_mean"] = sum(c["nominal"]) / len(c["nominal"])
        out[level] = list(cells.values())
    return out


def markdown(tables: dict, command: str) -> str:
    lines = [
        "# Table 6 under realistic assumptions",
        "",
        f"Made by `{command}` from each trial's `realistic/TRIAL.json` (each gives its own "
        "command, machine and wall-clock). L5: the paper's vehicle with all realism options, "
        f"{LEVELS['L5']} episodes a policy; F0: the Fossen vehicle on the paper's task, "
        f"zero-shot, {LEVELS['F0']} episodes a policy; evaluation seed: training seed + 20,000.",
        "",
    ]
    for level, cells in tables.items():
        lines += [f"## {level}", ""]
        if level == "F0":
            lines += [
                "For comparison, the paper's SAC policy, moved without retraining to the "
                "Stonefish simulator's vehicle, docked 40 % of its trials (Section 4.4).",
                "",
            ]
        lines += [
            "| recipe | scenario | seeds | success % (per seed) | 95 % CI over seeds "
            "| 95 % CI over episodes | nominal % | failures: timeout / missed funnel / too fast |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for c in cells:
            ci = c["success_ci95_over_seeds"]
            f = c["failures"]
            per_seed = ", ".join(f"{v:.1f}" for v in c["success_per_seed"])
            lines.append(
                f"| {c['recipe']} | {c['scenario']} | {c['seeds_label']} | "
                f"{c['success_mean']:.1f} ({per_seed}) | "
                + ("-" if ci is None else f"[{ci[0]:.1f}, {ci[1]:.1f}]")
                + " | [{:.1f}, {:.1f}]".format(*c["success_ci95_over_episodes"])
                + f" | {c['nominal_mean']:.1f} | {f.get('timeout', 0)} / "
                f"{f.get('missed_funnel', 0)} / {f.get('too_fast', 0)} |"
            )
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("runs/table6"))
    parser.add_argument("--out", type=Path, default=Path("results/table6"))
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    from dockingrl.io import atomic_write, write_json
    from dockingrl.provenance import script_command

    folder = args.out / "realistic"
    folder.mkdir(parents=True, exist_ok=True)
    trials = []
    for run in finished_runs(args.runs):
        path = folder / f"{run.name}.json"
        if not path.exists():
            if not (run / "policy.pt").is_file():
                print(f"{run.name}: no policy.pt and no evaluation: left out", file=sys.stderr)
                continue
            write_json(path, evaluate_trial(run, args.threads))
            print(f"{run.name}: evaluated", flush=True)
        trials.append(json.loads(path.read_text()))
    if not trials:
        print(f"no finished held-out run under {args.runs}", file=sys.stderr)
        return 1
    tables = table(trials)
    command = script_command("realistic_table6.py", argv)
    write_json(args.out / "realistic.json", tables)
    atomic_write(args.out / "realistic.md", lambda tmp: tmp.write_text(markdown(tables, command)))
    print(markdown(tables, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
