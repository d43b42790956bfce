"""The stress ladders of the recipes for a vehicle on held-out seeds, as one table: each
level's success per training seed, the seeds' mean with its 95 % Student-t interval, and the
95 % Wilson interval over all their episodes. Reads ``STRESS/<recipe>__s<seed>/stress.json``
(``dockingrl stress --out``); writes ``table.json`` and ``table.md`` in ``--out``.
``--second-look RECIPE:FIRST-LAST`` tables those training seeds of a recipe apart, as
``RECIPE (second look)``: seeds that judged an earlier version of the recipe are not held out
from it, so they are not pooled with the seeds that are. ``--compare A:B`` gives, at each level
both recipes have, rliable's probability that a training seed of ``A`` docks more than one of
``B`` (ties half), with its stratified bootstrap interval
(:func:`dockingrl.table.reliable.compare`).

    python scripts/robust_table.py results/robust/stress --out results/robust \
        --second-look ppo-robust:100-102 --compare sac-robust:ppo-robust
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

from dockingrl.io import atomic_write, write_json
from dockingrl.provenance import script_command
from dockingrl.table.claims import episodes_ci, seed_ci
from dockingrl.table.reliable import compare, improvement_verdict


def robust_table(stress_dir: Path, second_look: dict[str, range] | None = None) -> list[dict]:
    """One row per recipe and level, in the order of the ladders' levels; the seeds of
    ``second_look[recipe]`` form rows of their own, ``RECIPE (second look)``."""
    second_look = second_look or {}
    runs: dict[str, dict[int, dict]] = defaultdict(dict)
    for path in sorted(stress_dir.glob("*__s*/stress.json")):
        recipe, seed = path.parent.name.rsplit("__s", 1)
        if int(seed) in second_look.get(recipe, ()):
            recipe += " (second look)"
        runs[recipe][int(seed)] = json.loads(path.read_text())
    if not runs:
        raise ValueError(f"{stress_dir}: no <recipe>__s<seed>/stress.json")
    rows = []
    # by name: a recipe's held-out seeds, then its second look
    for recipe, by_seed in sorted(runs.items()):
        seeds = sorted(by_seed)
        levels = [level["name"] for level in by_seed[seeds[0]]["levels"]]
        episodes = [int(by_seed[s]["episodes"]) for s in seeds]
        episode_seeds = [int(by_seed[s]["seed"]) for s in seeds]
        for name in levels:
            found = [
                next((lv for lv in by_seed[s]["levels"] if lv["name"] == name), None) for s in seeds
            ]
            if None in found:
                raise ValueError(f"{recipe}: level {name} is missing from a seed's ladder")
            success = [float(lv["success_rate"]) for lv in found]
            rows.append(
                {
                    "recipe": recipe,
                    "level": name,
                    "seeds": seeds,
                    "episode_seeds": episode_seeds,
                    "episodes_per_seed": episodes,
                    "success_per_seed": success,
                    "mean": sum(success) / len(success),
                    "seed_ci": seed_ci(success),
                    "episodes_ci": episodes_ci(success, episodes),
                }
            )
    return rows


def seed_range(text: str) -> tuple[str, range]:
    """``RECIPE:FIRST-LAST`` as ``(recipe, range of seeds)``."""
    recipe, _, seeds = text.partition(":")
    first, _, last = seeds.partition("-")
    try:
        span = range(int(first), int(last or first) + 1)
    except ValueError:
        span = range(0)
    if not recipe or not span:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected RECIPE:FIRST-LAST, e.g. ppo-robust:100-102"
        )
    return recipe, span


def pair(text: str) -> tuple[str, str]:
    """``A:B`` as ``(A, B)``."""
    a, _, b = text.partition(":")
    if not a or not b:
        raise argparse.ArgumentTypeError(f"{text!r}: expected A:B, e.g. sac-robust:ppo-robust")
    return a, b


def comparisons(rows: list[dict], pairs: list[tuple[str, str]]) -> list[dict]:
    """For each pair ``(A, B)`` and each level both have: ``P(A > B)`` over their training
    seeds, its interval and its verdict."""
    by = {(r["recipe"], r["level"]): r for r in rows}
    out = []
    for a, b in pairs:
        levels = [r["level"] for r in rows if r["recipe"] == a and (b, r["level"]) in by]
        if not levels:
            raise ValueError(f"--compare {a}:{b}: no level that both recipes have")
        for level in levels:
            x, y = by[(a, level)]["success_per_seed"], by[(b, level)]["success_per_seed"]
            result = compare(x, y)
            out.append(
                {
                    "a": a,
                    "b": b,
                    "level": level,
                    "seeds": [len(x), len(y)],
                    "probability": None if result is None else result["probability"],
                    "ci95": None if result is None else result["ci95"],
                    "verdict": improvement_verdict(result, f"{a} docks more", f"{b} docks more"),
                }
            )
    return out


def comparison_markdown(found: list[dict]) -> str:
    lines = [
        "| A | B | level | seeds (A, B) | P(A > B) [95 % interval] | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for c in found:
        p = (
            "-"
            if c["probability"] is None
            else (f"{c['probability']:.2f} [{c['ci95'][0]:.2f}, {c['ci95'][1]:.2f}]")
        )
        seeds = f"{c['seeds'][0]}, {c['seeds'][1]}"
        lines.append(f"| `{c['a']}` | `{c['b']}` | {c['level']} | {seeds} | {p} | {c['verdict']} |")
    return "\n".join(lines) + "\n"


def markdown(rows: list[dict]) -> str:
    def ci(v):
        return "-" if v is None else f"[{v[0]:.1f}, {v[1]:.1f}]"

    lines = [
        "| recipe | level | success % per seed | mean % | seeds' 95 % interval | episodes' 95 % "
        "interval |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        per_seed = ", ".join(f"{s:.1f}" for s in r["success_per_seed"])
        lines.append(
            f"| `{r['recipe']}` | {r['level']} | {per_seed} | {r['mean']:.1f} | "
            f"{ci(r['seed_ci'])} | {ci(r['episodes_ci'])} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("stress", type=Path, help="folder of <recipe>__s<seed>/stress.json")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument(
        "--second-look",
        type=seed_range,
        action="append",
        default=[],
        metavar="RECIPE:FIRST-LAST",
        help="training seeds of a recipe that judged an earlier version of it, tabled apart",
    )
    parser.add_argument(
        "--compare",
        type=pair,
        action="append",
        default=[],
        metavar="A:B",
        help="rliable's probability of improvement of recipe A over recipe B at each level",
    )
    args = parser.parse_args(argv)
    rows = robust_table(args.stress, dict(args.second_look))
    found = comparisons(rows, args.compare)
    args.out.mkdir(parents=True, exist_ok=True)
    command = script_command("robust_table.py", argv)
    write_json(args.out / "table.json", {"command": command, "rows": rows, "comparisons": found})
    text = markdown(rows)
    if found:
        text += "\n" + comparison_markdown(found)
    atomic_write(args.out / "table.md", lambda tmp: tmp.write_text(text))
    print(text, end="")
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
