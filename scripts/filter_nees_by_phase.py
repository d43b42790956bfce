"""NEES of saved filters by phase of the episode, on held-out rollouts under the x2 range and
bearing noise of the filter ablation (README, "Learning the filter's Q and R").

    python scripts/filter_nees_by_phase.py --out results/filter_ablation/nees_by_phase.json \
        results/filter_ablation/mismatched_nll.pt results/filter_ablation/mismatched_supervised.pt

``hand`` in place of a path is the hand-tuned filter of Tables 1-2. For each filter and each
band of steps since the episode's start: the mean NEES (5 when consistent) and the mean
``e_i^2 / P_ii`` per state component (x, y, heading, surge, yaw rate).
"""

from __future__ import annotations

import argparse
import time

import torch

from dockingrl.filter_learning import (
    mismatched_config,
    normalized_errors,
    record_rollouts,
    run_filter,
)
from dockingrl.io import write_json
from dockingrl.provenance import script_command
from dockingrl.transforms import EKFTransform

BANDS = ((10, 30), (30, 60), (60, 100), (100, 150), (150, 200), (200, 300), (300, 600))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("filters", nargs="+", help="filter-parameter files, or 'hand'")
    parser.add_argument("--out", required=True, help="JSON file to write")
    parser.add_argument("--seed", type=int, default=1000, help="held-out rollouts' seed")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    data = record_rollouts(128, 600, config=mismatched_config(2.0), seed=args.seed)
    step = data["step_count"]
    report = {"seed": args.seed, "bands": [list(b) for b in BANDS], "filters": {}}
    for spec in args.filters:
        ekf = EKFTransform()
        if spec != "hand":
            ekf.load_filter_params(spec)
        with torch.no_grad():
            means, covs, _, _ = run_filter(ekf, data)
        nees, per_component = normalized_errors(means, covs, data["true_state"])
        rows = []
        for low, high in BANDS:
            band = (step >= low) & (step < high)
            rows.append(
                {
                    "steps": [low, high],
                    "samples": int(band.sum()),
                    "nees_mean": float(nees[band].mean()),
                    "normalized_error_per_component": per_component[band].mean(0).tolist(),
                }
            )
            print(f"{spec} steps {low}-{high}: NEES {rows[-1]['nees_mean']:.2f}")
        report["filters"][spec] = rows
    report["wall_clock_s"] = time.perf_counter() - start
    # every argument as given, so that --seed and --threads rerun too
    report["command"] = script_command("filter_nees_by_phase.py")
    write_json(args.out, report)


if __name__ == "__main__":
    main()
