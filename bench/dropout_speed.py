"""SAC updates per second with the critics' ``critic_dropout`` (DroQ) on the ``sac``
recipe's update paths (``fast_update``, layer-normed critics, 256 x 256, batches of 256):
without dropout, with ``torch.nn.Dropout``, with dockingrl's :class:`SparseDropout`, each
eager and through ``compile_update``. Variants are timed in alternating rounds; the figure is
the median of the rounds.

Usage: ``python bench/dropout_speed.py [--updates 300] [--rounds 3] [--threads 1]
[--p 0.01]``
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from torch import nn
from torch._dynamo.utils import counters

from dockingrl.agents import make_agent, networks
from dockingrl.agents.config import make_config
from dockingrl.agents.networks import SparseDropout
from dockingrl.evaluation import describe_machine
from dockingrl.scenarios import make_env


def build(p: float, dense: bool, compile_update: bool, data):
    """A SAC agent with critic dropout ``p`` (``torch.nn.Dropout`` where ``dense``), warmed
    up on ``data``."""
    cfg = make_config(
        "sac",
        "paper",
        hidden=(256, 256),
        critic_layer_norm=True,
        critic_dropout=p,
        fast_update=True,
        compile_update=compile_update,
        batch_size=256,
        buffer_size=10_000,
        normalize_observation=True,
    )
    # the networks are built with the class that dockingrl.agents.networks names
    networks.SparseDropout = nn.Dropout if dense else SparseDropout
    try:
        agent = make_agent(cfg, 12, make_env("compound", 1, seed=0).action_spec[0], 30.0)
    finally:
        networks.SparseDropout = SparseDropout
    agent.learn(data, num_updates=100)
    return agent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--updates", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--p", type=float, default=0.01)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    # three compiled agents, each with its graphs of the shared loss code (grad mode on and
    # off...): past dynamo's default of 8 per code object it would run the rest eager
    torch._dynamo.config.recompile_limit = 64
    data = make_env("compound", 4, seed=0).rollout(300, break_when_any_done=False)
    variants = {
        f"{label}, {'compiled' if comp else 'eager'}": build(p, dense, comp, data)
        for comp in (False, True)
        for label, p, dense in (
            ("no dropout", 0.0, False),
            ("nn.Dropout", args.p, True),
            ("SparseDropout", args.p, False),
        )
    }
    rates: dict[str, list[float]] = {name: [] for name in variants}
    graphs_before = counters["stats"]["unique_graphs"]
    for _ in range(args.rounds):
        for name, agent in variants.items():
            start = time.perf_counter()
            agent.learn(data[:, :1], num_updates=args.updates)
            rates[name].append(args.updates / (time.perf_counter() - start))
    print(f"{describe_machine()}; {args.threads} thread(s); dropout p = {args.p}")
    # the compiled agents share their loss code: each keeps its own graphs in dynamo's cache
    # (raised limit above); a graph compiled while timing would make the figures compile time
    again = counters["stats"]["unique_graphs"] - graphs_before
    print(f"  graphs compiled while timing: {again}")
    for name, values in rates.items():
        print(f"  {name:28s} {statistics.median(values):6.1f} updates/s")


if __name__ == "__main__":
    main()
