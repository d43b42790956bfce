"""The main job, ``bash main.sh``, run once per training seed, one after another, with nothing
else asked of the machine: each seed's time from the start of training to its printed success
rate, the whole command's time, and its success on its 2,000 final episodes (episode seed:
training seed + 10,000). Writes ``main_job.json`` and ``table.md`` in ``--out``, and each
seed's ``config.json``, ``summary.json`` and ``eval.json`` under
``--out/trials/RECIPE__SCENARIO__s<seed>/`` (as a grid's trials, checked against their recipe).

    bash scripts/install.sh && python scripts/main_job.py --seeds 100 101 102 103 104 --out OUT

Run it from a fresh clone, installed first (the script itself imports dockingrl; ``main.sh``
installs the clone it is in again for each seed). The run folders go to
``--runs`` (default ``runs/main_job``); a seed whose run folder already holds a
``summary.json`` is read, not run again (with the command's time it wrote there), so an
interrupted call resumes at its next seed. Each seed compiles with an empty TorchInductor
cache of its own (``TORCHINDUCTOR_CACHE_DIR``), as on a fresh machine: its compile time is
counted, not read from an earlier run's cache.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dockingrl.io import atomic_write, write_json
from dockingrl.provenance import script_command
from dockingrl.table.claims import episodes_ci

ROOT = Path(__file__).resolve().parents[1]
KEPT = ("config.json", "summary.json", "eval.json")


def run_seed(seed: int, runs: Path) -> dict:
    """``bash main.sh --seed SEED`` into ``runs/s<seed>``: its row of the table."""
    run_dir = runs / f"s{seed}"
    command_s = None
    if not (run_dir / "summary.json").exists():
        shutil.rmtree(run_dir, ignore_errors=True)  # a run cut short starts again
        with tempfile.TemporaryDirectory(prefix="inductor_") as cache:
            start = time.perf_counter()
            subprocess.run(
                ["bash", "main.sh", "--seed", str(seed), "--out", str(runs)]
                + ["--run-name", f"s{seed}"],
                cwd=ROOT,
                check=True,
                env={**os.environ, "TORCHINDUCTOR_CACHE_DIR": cache},
            )
            command_s = time.perf_counter() - start
        write_json(run_dir / "main_job.json", {"command_s": command_s})
    elif (run_dir / "main_job.json").exists():  # run by an earlier call
        command_s = json.loads((run_dir / "main_job.json").read_text())["command_s"]
    summary = json.loads((run_dir / "summary.json").read_text())
    success = float(summary["success_rate"])
    episodes = int(json.loads((run_dir / "eval.json").read_text())["episodes"])
    low, high = episodes_ci([success], [episodes])
    to_success = (
        summary["train_wall_clock_s"]
        + summary.get("selection_wall_clock_s", 0.0)
        + summary["final_eval_wall_clock_s"]
    )
    return {
        "seed": seed,
        "success_rate": success,
        "interval": [low, high],
        "episodes": episodes,
        "train_s": round(summary["train_wall_clock_s"], 1),
        "training_to_success_s": round(to_success, 1),
        "command_s": None if command_s is None else round(command_s, 1),
        "machine": summary["machine"],
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| seed | success % of 2,000 [95 % interval] | training to printed success (s) | "
        "whole command (s) |",
        "|---|---|---|---|",
    ]
    for r in rows:
        whole = "-" if r["command_s"] is None else f"{r['command_s']:.0f}"
        lines.append(
            f"| {r['seed']} | {r['success_rate']:.2f} [{r['interval'][0]:.1f}, "
            f"{r['interval'][1]:.1f}] | {r['training_to_success_s']:.0f} | {whole} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[100, 101, 102, 103, 104])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--runs", type=Path, default=Path("runs/main_job"))
    args = parser.parse_args(argv)
    runs = args.runs if args.runs.is_absolute() else ROOT / args.runs
    rows = []
    for seed in args.seeds:
        rows.append(run_seed(seed, runs))
        config = json.loads((runs / f"s{seed}" / "config.json").read_text())
        dest = args.out / "trials" / f"{config['recipe']}__{config['scenario']}__s{seed}"
        dest.mkdir(parents=True, exist_ok=True)
        for name in KEPT:
            shutil.copyfile(runs / f"s{seed}" / name, dest / name)
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    command = script_command("main_job.py", sys.argv[1:] if argv is None else argv)
    machines = "; ".join(sorted({r["machine"] for r in rows}))
    text = table(rows) + f"\n{command}  |  {machines}\n"
    write_json(args.out / "main_job.json", {"command": command, "seeds": rows})
    atomic_write(args.out / "table.md", lambda tmp: tmp.write_text(text))
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
