"""The EKF's accuracy at the ladder levels with a late USBL fix, with and without latency
compensation and the innovation gate, on the same recorded rollouts of the managed surge
controller (200 envs x 400 steps, seed 0): ``evaluate_filter``'s RMSE and consistency.

    python scripts/latency_filter_accuracy.py \
        results/stress/latency_compensation/filter_accuracy.json
"""

import json
import sys
import time

import torch

from dockingrl.env.levels import level_config
from dockingrl.evaluation import describe_machine
from dockingrl.filter_learning import evaluate_filter, record_rollouts
from dockingrl.provenance import script_command
from dockingrl.scenarios import make_filter

KEYS = ("rmse_position_m", "rmse_heading_rad", "rmse_surge_m_s", "nees_mean", "nis_mean")

torch.set_num_threads(1)
result = {
    "command": script_command("latency_filter_accuracy.py"),
    "machine": describe_machine("cpu"),
}
rows, wall = [], {}
for level in ("L1", "L5"):
    config = level_config(level)
    start = time.perf_counter()
    data = record_rollouts(200, 400, config=config, seed=0)
    episodes = int((data["step_count"] == 0).sum())
    for gate in (None, 13.8):
        for compensate in (False, True):
            ekf = make_filter(config, gate=gate, compensate_latency=compensate)
            report = evaluate_filter(ekf, data)
            row = {"level": level, "episodes": episodes, "gate": gate}
            row |= {"compensate_latency": compensate, **{k: report[k] for k in KEYS}}
            rows.append(row)
            print(json.dumps(row), flush=True)
    wall[level] = time.perf_counter() - start
result |= {"wall_clock_s": wall, "rows": rows}
with open(sys.argv[1], "w") as f:
    json.dump(result, f, indent=1)
