"""Latency of one onboard step (the filter's predict and updates, the observation, the policy's
command) for one vehicle on one thread: the ONNX program under ONNX Runtime, its
``torch.export`` program, and :class:`dockingrl.OnboardPolicy` in eager PyTorch.

Usage: ``python bench/onboard_latency.py --policy P [--level L5] [--steps 2000]``

Each path runs the same recorded readings of an approach at ``--level``, carrying its own
state; the figures are the median and the 99th percentile of the per-step times, after 100
warm-up steps.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import torch

from dockingrl.env import DockingEnv
from dockingrl.env.levels import level_config
from dockingrl.evaluation import describe_machine
from dockingrl.onboard import OnboardPolicy, export_onboard, export_onnx
from dockingrl.onboard.export import onnx_names
from dockingrl.onboard.sensor_log import record_episode, ticks

WARM_UP = 100


def _times(step, inputs, steps: int) -> list[float]:
    out = []
    for k in range(WARM_UP + steps):
        start = time.perf_counter()
        step(inputs[k % len(inputs)])
        if k >= WARM_UP:
            out.append(time.perf_counter() - start)
    return out


def _row(name: str, times: list[float]) -> str:
    ordered = sorted(times)
    p99 = ordered[int(0.99 * (len(ordered) - 1))]
    return f"| {name} | {statistics.median(times) * 1e6:.0f} | {p99 * 1e6:.0f} |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", required=True)
    parser.add_argument("--level", default="L5")
    parser.add_argument("--steps", type=int, default=2000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    import onnxruntime as ort

    config = level_config(args.level)
    policy = OnboardPolicy.from_file(args.policy, config=config)
    log, _ = record_episode(policy, DockingEnv(1, config=config, seed=1))
    readings = [(t.z[None], t.current[None], t.ages[None]) for t in ticks(log, config.dt)]
    state0 = policy.initial_state(1)
    names, _ = onnx_names(policy)
    with tempfile.TemporaryDirectory() as tmp:
        onnx_path = export_onnx(policy, Path(tmp) / "step.onnx")
        pt2 = torch.export.load(export_onboard(policy, Path(tmp) / "step.pt2", sensor_age=True))
        options = ort.SessionOptions()
        options.intra_op_num_threads = options.inter_op_num_threads = 1
        session = ort.InferenceSession(str(onnx_path), options, providers=["CPUExecutionProvider"])
    program = pt2.module()

    state = {"onnx": [t.numpy() for t in state0], "pt2": list(state0), "eager": list(state0)}

    def onnx_step(reading):
        z, current, ages = (x.numpy() for x in reading)
        mean, cov, command, age, *history = state["onnx"]
        values = (z, current, mean, cov, command, age, ages, *history)
        command, mean, cov, age, *history = session.run(None, dict(zip(names, values, strict=True)))
        state["onnx"] = [mean, cov, command, age, *history]

    def torch_step(kind, module):
        def step(reading):
            z, current, ages = reading
            mean, cov, command, age, *history = state[kind]
            with torch.no_grad():
                out = module(z, current, mean, cov, command, age, ages, *history)
            command, mean, cov, age, *history = out
            state[kind] = [mean, cov, command, age, *history]

        return step

    eager = policy.step.eval()
    rows = [
        _row("ONNX Runtime (onnx program)", _times(onnx_step, readings, args.steps)),
        _row(
            "PyTorch, torch.export program",
            _times(torch_step("pt2", program), readings, args.steps),
        ),
        _row(
            "PyTorch, eager OnboardStep", _times(torch_step("eager", eager), readings, args.steps)
        ),
    ]
    print(f"machine: {describe_machine()}; onnxruntime {ort.__version__}, 1 thread")
    print(f"policy: {args.policy}; level {args.level}; {args.steps} steps after {WARM_UP} warm-up")
    print("| path | median us / step | 99th percentile us |")
    print("|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
