"""The position and heading error of the paper's EKF and of the EKF that estimates the
current's error (for several random walks of that error), at every ladder level, with and
without the chi-square gate (``--gates``), for several rates of the motion model's surge and
yaw-rate responses (``--rates``, k_v = k_w of eq. 24), all compensating the USBL latency, on
the same recorded rollouts of the managed surge controller (200 envs x 400 steps, ``--seed``,
0 by default; the first 10 steps of each episode left out, as ``evaluate_filter`` does). The
position error is also given within ``--near`` m of the station, where a policy lines up.

    python scripts/current_filter_accuracy.py results/stress/current_estimation/filter_accuracy.json

Each filter runs through its transform's own ``filter_step`` (``filter_estimates``: what the
env runs), so that the 7-entry state of the estimating filter is handled as in training.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import torch

from dockingrl.env.levels import LEVELS, level_config
from dockingrl.evaluation import describe_machine
from dockingrl.filter_learning import filter_estimates, record_rollouts
from dockingrl.filter_learning.consistency import state_error
from dockingrl.io import write_json
from dockingrl.provenance import script_command
from dockingrl.scenarios import make_filter
from dockingrl.transforms.ekf import STATE_DIM


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", help="JSON file to write")
    parser.add_argument("--envs", type=int, default=200)
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--levels", default=",".join(LEVELS))
    parser.add_argument("--near", type=float, default=6.0, help="range (m) of the near split")
    parser.add_argument(
        "--error-stds",
        default="0.005,0.05,0.1",
        help="random walks of the estimating filter's current error to compare (m/s a step)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the recorded rollouts")
    parser.add_argument(
        "--gates",
        default="none,13.8",
        help="chi-square gates to compare, comma-separated ('none': no gate)",
    )
    parser.add_argument(
        "--rates",
        default="2.5",
        help="rates (1/s) of the filter's surge and yaw-rate responses to compare, "
        "comma-separated (2.5: eq. 24's)",
    )
    args = parser.parse_args(argv)
    gates = [None if g.strip() == "none" else float(g) for g in args.gates.split(",")]
    rates = [float(r) for r in args.rates.split(",")]
    torch.set_num_threads(1)
    rows, wall = [], {}
    for level in args.levels.split(","):
        config = level_config(level)
        start = time.perf_counter()
        data = record_rollouts(args.envs, args.steps, config=config, seed=args.seed)
        keep = data["step_count"] >= 10
        near = keep & (data["true_state"][..., :2].norm(dim=-1) < args.near)
        stds = [float(x) for x in args.error_stds.split(",")]
        for estimate, std in [(False, None)] + [(True, x) for x in stds]:
            for gate, rate in [(g, r) for g in gates for r in rates]:
                options = {"estimate_current": estimate, "k_v": rate, "k_w": rate}
                if estimate:
                    options["current_error_std"] = std
                ekf = make_filter(config, gate=gate, compensate_latency=True, **options)
                means = filter_estimates(ekf, data)
                full = state_error(means[..., :STATE_DIM], data["true_state"]).double()
                error = full[keep]
                row = {
                    "level": level,
                    "estimate_current": estimate,
                    "current_error_std": std,
                    "gate": gate,
                    "response_rate": rate,
                    "rmse_position_m": float(error[:, :2].pow(2).sum(-1).mean().sqrt()),
                    "rmse_position_near_m": float(full[near][:, :2].pow(2).sum(-1).mean().sqrt()),
                    "near_samples": int(near.sum()),
                    "rmse_heading_rad": float(error[:, 2].pow(2).mean().sqrt()),
                    "rmse_surge_m_s": float(error[:, 3].pow(2).mean().sqrt()),
                }
                rows.append(row)
                print(json.dumps(row), flush=True)
        wall[level] = time.perf_counter() - start
    result = {
        "command": script_command("current_filter_accuracy.py", argv),
        "machine": describe_machine("cpu"),
        "wall_clock_s": wall,
        "rows": rows,
    }
    write_json(args.out, result)
    return result


if __name__ == "__main__":
    main(sys.argv[1:])
