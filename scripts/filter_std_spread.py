"""The spread of the EKF's position standard deviations (``--observe-filter-std``) at ladder
levels: percentiles of ``filter_std`` (along track ``x``, across ``y``, m) over steps
``--from``-``--to`` of ``--envs`` approaches at a constant command (surge 0.4 m/s, no yaw
rate), the paper's filter at L0 and the compensating, current-estimating, gated filter
(chi-square 13.816) at the other levels, as ``dockingrl stress --compensate-latency
--estimate-current --gate 13.816`` runs them.

    python scripts/filter_std_spread.py --levels L0,L1,L5

Prints one row a level and, with ``--out FILE``, writes them to a JSON file with the command,
machine and wall-clock.
"""

from __future__ import annotations

import argparse
import time

import torch

from dockingrl.env.levels import LEVELS, level_config
from dockingrl.evaluation import describe_machine
from dockingrl.io import write_json
from dockingrl.provenance import script_command
from dockingrl.scenarios import make_env
from dockingrl.transforms.ekf import CHI2_2DOF_999

PERCENTILES = (10, 50, 90)


def spread(level: str, envs: int, first: int, last: int, seed: int) -> dict:
    """Percentiles of ``filter_std`` over steps ``first``-``last`` at ``level``."""
    harsh = {"gate": CHI2_2DOF_999, "compensate_latency": True, "estimate_current": True}
    ekf = {} if level == "L0" else harsh
    env = make_env(
        "compound",
        envs,
        seed=seed,
        config=level_config(level),
        ekf_kwargs=ekf,
        observe_filter_std=True,
    )
    td = env.reset()
    action = torch.tensor([0.4, 0.0]).expand(envs, 2).clone()
    samples = []
    for step in range(1, last + 1):
        td["action"] = action
        td = env.step(td)["next"]
        if step >= first:
            alive = ~td["done"].reshape(envs)
            samples.append(td["filter_std"][alive])
        if td["done"].all():
            break
    values = torch.cat(samples).double()
    q = torch.tensor([p / 100 for p in PERCENTILES], dtype=torch.float64)
    row = {"level": level, "samples": int(values.shape[0])}
    for column, name in enumerate(("along_track_m", "across_m")):
        quantiles = torch.quantile(values[:, column], q)
        row[name] = {
            f"p{p}": round(float(v), 3) for p, v in zip(PERCENTILES, quantiles, strict=True)
        }
    return row


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--levels", default=",".join(LEVELS))
    parser.add_argument("--envs", type=int, default=32)
    parser.add_argument("--from", dest="first", type=int, default=20)
    parser.add_argument("--to", dest="last", type=int, default=150)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", help="JSON file to write")
    args = parser.parse_args(argv)
    if not 1 <= args.first <= args.last:
        parser.error(f"--from {args.first} and --to {args.last}: need 1 <= from <= to")
    levels = args.levels.split(",")
    for level in levels:
        if level not in LEVELS:
            parser.error(f"unknown level {level!r}; valid: {', '.join(LEVELS)}")
    torch.set_num_threads(1)
    start = time.perf_counter()
    rows = []
    for level in levels:
        row = spread(level, args.envs, args.first, args.last, args.seed)
        rows.append(row)
        print(
            f"{level}: along track {row['along_track_m']}, across {row['across_m']} "
            f"({row['samples']} samples)",
            flush=True,
        )
    wall = time.perf_counter() - start
    print(f"{describe_machine('cpu')}, {wall:.1f} s")
    if args.out:
        command = script_command("filter_std_spread.py", argv)
        payload = {"command": command, "machine": describe_machine("cpu"), "wall_clock_s": wall}
        write_json(args.out, {**payload, "rows": rows})
    return rows


if __name__ == "__main__":
    main()
