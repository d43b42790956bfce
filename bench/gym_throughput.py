"""Env steps per second of the Gymnasium envs, beside the TorchRL pipeline's in the same run.

Usage: ``python bench/gym_throughput.py [--sizes 1 64 4096] [--seconds 3] [--threads 1]
[--compile]``

Rows: the single env (``gymnasium.make("dockingrl/Docking-v0", scenario=...)``) with
``fast=True`` (the step and the filter on Python floats) and with its tensor step (the
batched env's transition on one env, without TensorDict), the vector env
(``gymnasium.make_vec(..., num_envs=n)``, NEXT_STEP autoreset) and the TorchRL pipeline
(``dockingrl.make_env(scenario, n)``, a ``step_and_maybe_reset`` per step as a collector
does), for ``noise`` and ``compound`` (EKF included). Actions are uniform in the bounds, drawn
before the clock starts. ``--compile`` adds the single env with ``compile=True``
(``torch.compile`` of the same step functions; the first steps compile, outside the clock).
"""

from __future__ import annotations

import argparse
import time

import gymnasium
import numpy as np
import torch

import dockingrl
from dockingrl.evaluation import describe_machine

SCENARIOS = ("noise", "compound")


def _actions(n: int, count: int = 256) -> np.ndarray:
    low, high = dockingrl.DockingConfig().action_low, dockingrl.DockingConfig().action_high
    rng = np.random.default_rng(0)
    return rng.uniform(low, high, size=(count, n, 2)).astype(np.float32)


def _timed(step, seconds: float, batch: int) -> float:
    for _ in range(20):  # warm-up (and compilation)
        step()
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(20):
            step()
        steps += 20
    return steps * batch / (time.perf_counter() - start)


def single_env(scenario: str, seconds: float, compile: bool = False, fast: bool = False) -> float:
    env = gymnasium.make(
        "dockingrl/Docking-v0", scenario=scenario, compile=compile, fast=fast
    ).unwrapped
    env.reset(seed=0)
    actions = _actions(1)[:, 0]
    count = iter(range(1 << 62))

    def step() -> None:
        _, _, terminated, truncated, _ = env.step(actions[next(count) % len(actions)])
        if terminated or truncated:
            env.reset()

    return _timed(step, seconds, 1)


def vector_env(scenario: str, n: int, seconds: float) -> float:
    env = gymnasium.make_vec("dockingrl/Docking-v0", num_envs=n, scenario=scenario)
    env.reset(seed=0)
    actions = _actions(n, 64)
    count = iter(range(1 << 62))

    def step() -> None:
        env.step(actions[next(count) % len(actions)])

    return _timed(step, seconds, n)


def torchrl_env(scenario: str, n: int, seconds: float) -> float:
    env = dockingrl.make_env(scenario, n, seed=0)
    actions = torch.from_numpy(_actions(n, 64))
    count = iter(range(1 << 62))
    state = {"td": env.reset()}

    def step() -> None:
        td = state["td"]
        td["action"] = actions[next(count) % len(actions)]
        _, state["td"] = env.step_and_maybe_reset(td)

    return _timed(step, seconds, n)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 4096])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--compile", action="store_true", help="add the compiled single env")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    print(f"machine: {describe_machine('cpu')}, envs on cpu")
    rows: list[tuple[str, list[str]]] = []
    empty = ["" for _ in args.sizes[1:]]
    for scenario in SCENARIOS:
        fast = single_env(scenario, args.seconds, fast=True)
        rows.append((f"single env, fast=True ({scenario})", [f"{fast:,.0f}", *empty]))
        single = single_env(scenario, args.seconds)
        rows.append((f"single env, tensor step ({scenario})", [f"{single:,.0f}", *empty]))
        if args.compile:
            compiled = single_env(scenario, args.seconds, compile=True)
            rows.append((f"single env, compile=True ({scenario})", [f"{compiled:,.0f}", *empty]))
        for name, bench in (
            (f"vector env, gymnasium.make_vec ({scenario})", vector_env),
            (f"TorchRL, make_env + step_and_maybe_reset ({scenario})", torchrl_env),
        ):
            rows.append((name, [f"{bench(scenario, n, args.seconds):,.0f}" for n in args.sizes]))
    print("| pipeline | " + " | ".join(f"n={n}" for n in args.sizes) + " |")
    print("|---|" + "---|" * len(args.sizes))
    for name, values in rows:
        print(f"| {name} | " + " | ".join(values) + " |")
    print("(env steps per second, summed over the batch; the single env is n=1)")


if __name__ == "__main__":
    main()
