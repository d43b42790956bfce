"""Env steps per second of the batched docking env, with random actions.

Usage: ``python bench/env_throughput.py [--sizes 1 64 1024 4096] [--seconds 3] [--threads 2]
[--device cuda]``

Each step is a full TorchRL ``step_and_maybe_reset`` (what a collector does), random actions
drawn by ``action_spec.rand()`` included. The ``compound`` row (EKF + compound observation,
once that pipeline exists) shows the filter's cost relative to the bare env.
"""

from __future__ import annotations

import argparse
import time

import torch

from dockingrl.evaluation import describe_machine


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def steps_per_second(env, seconds: float) -> float:
    td = env.reset()
    for _ in range(10):  # warm-up (and compilation, for compiled pipelines)
        td["action"] = env.action_spec.rand()
        _, td = env.step_and_maybe_reset(td)
    _sync(env.device)
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(10):
            td["action"] = env.action_spec.rand()
            _, td = env.step_and_maybe_reset(td)
        steps += 10
        _sync(env.device)
    return steps * env.batch_size[0] / (time.perf_counter() - start)


def pipelines(device: str = "cpu"):
    from dockingrl import make_env
    from dockingrl.env import DockingConfig, DockingEnv

    d = device
    yield "env (noise)", lambda n: DockingEnv(n, seed=0, device=d)
    yield "compound (env + EKF + concat)", lambda n: make_env("compound", n, seed=0, device=d)
    fossen = DockingConfig(vehicle="fossen")
    yield "env (noise), Fossen vehicle", lambda n: DockingEnv(n, seed=0, device=d, config=fossen)
    yield (
        "env (noise), compile_step=True",
        lambda n: DockingEnv(n, seed=0, device=d, compile_step=True),
    )
    yield (
        "compound, make_env(compile=True)",
        lambda n: make_env("compound", n, seed=0, device=d, compile=True),
    )
    yield (
        "env (noise), Fossen vehicle, compile_step=True",
        lambda n: DockingEnv(n, seed=0, device=d, config=fossen, compile_step=True),
    )
    mixed = DockingConfig(vehicle="mixed")
    yield (
        "compound, either vehicle per episode (M0), make_env(compile=True)",
        lambda n: make_env("compound", n, seed=0, device=d, config=mixed, compile=True),
    )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 1024, 4096])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--only", help="run the pipelines whose name holds this text only")
    parser.add_argument("--device", default="cpu", help="torch device of the envs (cpu, cuda)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    print(f"machine: {describe_machine(args.device)}, envs on {args.device}")
    rows = {}
    for name, make in pipelines(args.device):
        if args.only and args.only not in name:
            continue
        rows[name] = [steps_per_second(make(n), args.seconds) for n in args.sizes]
    header = "| pipeline | " + " | ".join(f"n={n}" for n in args.sizes) + " |"
    print(header)
    print("|---|" + "---|" * len(args.sizes))
    for name, values in rows.items():
        print(f"| {name} | " + " | ".join(f"{v:,.0f}" for v in values) + " |")
    if len(rows) > 1:
        base = next(iter(rows.values()))
        for name, values in list(rows.items())[1:]:
            ratio = " | ".join(f"{b / v:.2f}x" for b, v in zip(base, values, strict=True))
            print(f"| {name}: time per step relative to the bare env | {ratio} |")
    print("(env steps per second; one step of one env = 1)")


if __name__ == "__main__":
    main()
