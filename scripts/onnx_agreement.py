"""The ONNX program of a policy's onboard step against :class:`dockingrl.OnboardPolicy`: fly
approaches at a stress level with the onboard policy, log what the vehicle received, run the
ONNX program (ONNX Runtime, one thread) over the same readings with its own state, and report
the largest differences in the command and the filter's estimate (docs/onboard.md).

    python scripts/onnx_agreement.py --policy P --level L5 --steps 10000 --out results/onboard
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from dockingrl.env import DockingEnv
from dockingrl.env.levels import level_config
from dockingrl.evaluation.machine import describe_machine
from dockingrl.io import write_json
from dockingrl.onboard import OnboardPolicy, export_onnx
from dockingrl.onboard.export import ONNX_OPSET, onnx_names
from dockingrl.onboard.sensor_log import record_episode, ticks


def agreement(policy_path: str, level: str, steps: int, seed: int) -> dict:
    import onnxruntime as ort

    config = level_config(level)
    policy = OnboardPolicy.from_file(policy_path, config=config)
    with tempfile.TemporaryDirectory() as tmp:
        program = export_onnx(policy, Path(tmp) / "step.onnx")
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        session = ort.InferenceSession(str(program), options, providers=["CPUExecutionProvider"])
    inputs, _ = onnx_names(policy)
    worst_command, worst_mean, done, approaches = 0.0, 0.0, 0, 0
    while done < steps:
        env = DockingEnv(1, config=config, seed=seed + approaches)
        log, commands = record_episode(policy, env)
        mean, cov, command, age, *history = (t.numpy() for t in policy.initial_state(1))
        for k, tick in enumerate(ticks(log, config.dt)):
            values = (tick.z[None].numpy(), tick.current[None].numpy(), mean, cov, command, age)
            values += (tick.ages[None].numpy(), *history)
            command, mean, cov, age, *history = session.run(
                None, dict(zip(inputs, values, strict=True))
            )
            worst_command = max(
                worst_command, float(np.abs(command[0] - commands[k].numpy()).max())
            )
            done += 1
        # the onboard policy's own estimate at the approach's end, against the program's
        reference = policy.filter_state[0][0].numpy()
        worst_mean = max(worst_mean, float(np.abs(mean[0] - reference).max()))
        approaches += 1
    return {
        "policy": policy_path,
        "level": level,
        "steps": done,
        "approaches": approaches,
        "episode_seeds": [seed, seed + approaches - 1],
        "opset": ONNX_OPSET,
        "inputs": inputs,
        "max_abs_command_difference": worst_command,
        "max_abs_final_estimate_difference": worst_mean,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", required=True)
    parser.add_argument("--level", default="L5")
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=20_000, help="the first approach's seed")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    start = time.perf_counter()
    report = agreement(args.policy, args.level, args.steps, args.seed)
    report["wall_clock_s"] = round(time.perf_counter() - start, 1)
    report["machine"] = describe_machine()
    report["command"] = "python scripts/onnx_agreement.py " + " ".join(argv or sys.argv[1:])
    write_json(args.out / "onnx_agreement.json", report)
    print(
        f"{report['steps']} steps over {report['approaches']} approaches at {args.level}: "
        f"largest command difference {report['max_abs_command_difference']:.2e}, final "
        f"estimate {report['max_abs_final_estimate_difference']:.2e}; "
        f"{report['wall_clock_s']} s"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
