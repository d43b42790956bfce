"""Gradient updates per second of the TorchRL agents at the paper's sizes, beside a minimal
plain-PyTorch implementation of the same update, in the same process, and the floor: the
update's matrix-product FLOPs over this CPU's measured matmul rate at those shapes.

Usage: ``python bench/update_speed.py [--seconds 5] [--rounds 5] [--threads 1]
[--algos sac td3 ppo] [--device cuda] [--no-compile] [--fast-paths]``

TorchRL and plain updates are timed in alternating rounds, so that a drift in the machine's
speed (frequent on shared CPUs) hits all alike; the ratios are medians of per-round ratios.

Rows: the agent as the recipes build it; with ``fast_update`` (fused Adam, and on a CPU the
twin critics as plain matrix products instead of vmap's batched ones: other roundings, hence
opt-in); and each through ``torch.compile`` (TorchRL: the agent's ``compile_update`` option,
which compiles forward and backward of the loss; plain: the whole update function).

The floor: the FLOPs of the matrix products of one plain update (forward and backward, counted
by ``torch.utils.flop_counter``) and the time the same products take, replayed alone on
contiguous operands at the bench's thread count (the best of several repetitions): the update
if everything but its matrix products were free.

SAC and TD3: one update = one minibatch of 256 transitions from a replay buffer (critics,
actor, target networks). PPO: one update = one minibatch of 64 of a rollout (clipped objective,
value loss, gradient clipping); ``--ppo-minibatch 2048`` times the ``ppo`` recipe's size.
Observations are the compound ones (12 numbers).
"""

from __future__ import annotations

import argparse
import copy
import math
import statistics
import time

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictParams
from torch import nn

from dockingrl.agents import make_agent
from dockingrl.agents.config import make_config
from dockingrl.evaluation import describe_machine
from dockingrl.scenarios import make_env

OBS, ACT = 12, 2
DEVICE = torch.device("cpu")  # set by --device
PPO_MINIBATCH = 64  # set by --ppo-minibatch


def transitions(n: int) -> TensorDict:
    g = torch.Generator().manual_seed(0)
    return TensorDict(
        {
            "observation": torch.randn(n, OBS, generator=g),
            "action": torch.rand(n, ACT, generator=g) * 0.6 - 0.3,
            "next": {
                "observation": torch.randn(n, OBS, generator=g),
                "reward": torch.randn(n, 1, generator=g),
                "done": torch.zeros(n, 1, dtype=torch.bool),
                "terminated": torch.zeros(n, 1, dtype=torch.bool),
                "truncated": torch.zeros(n, 1, dtype=torch.bool),
            },
        },
        batch_size=[n],
    ).to(DEVICE)


def _sync() -> None:
    if DEVICE.type == "cuda":
        torch.cuda.synchronize(DEVICE)


def rate(step, seconds: float) -> float:
    for _ in range(20):
        step()
    _sync()
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(10):
            step()
        count += 10
        _sync()
    return count / (time.perf_counter() - start)


# -- TorchRL -------------------------------------------------------------------------------
def torchrl_update(algo: str, compile_update: bool = False, fast_update: bool = False):
    env = make_env("compound", 1, seed=0)
    cfg = make_config(
        algo, "paper", fast_update=fast_update, compile_update=compile_update, device=str(DEVICE)
    )
    agent = make_agent(cfg, OBS, env.action_spec[0], 30.0, DEVICE)
    if algo == "ppo":
        mb = PPO_MINIBATCH
        data = transitions(mb * 32)
        with torch.no_grad():
            data = agent.actor(data)
            agent.advantage.value_network(data)
            data["advantage"] = torch.randn(data.shape[0], 1, device=DEVICE)
            data["value_target"] = torch.randn(data.shape[0], 1, device=DEVICE)
        index = iter(range(10**9))

        def step():
            i = next(index) % 32
            agent._minibatch_update(data[i * mb : (i + 1) * mb])

        return step
    agent.replay_buffer.extend(transitions(10_000))
    return agent._off_policy_update


# -- plain PyTorch --------------------------------------------------------------------------
def mlp(sizes):
    layers = []
    for a, b in zip(sizes[:-1], sizes[1:], strict=True):
        layers += [nn.Linear(a, b), nn.ReLU()]
    return nn.Sequential(*layers[:-1]).to(DEVICE)


def plain_sac():
    actor = mlp([OBS, 256, 256, 2 * ACT])
    q1, q2 = mlp([OBS + ACT, 256, 256, 1]), mlp([OBS + ACT, 256, 256, 1])
    t1, t2 = copy.deepcopy(q1), copy.deepcopy(q2)
    qa = torch.optim.Adam([*q1.parameters(), *q2.parameters()], lr=3e-4)
    aa = torch.optim.Adam(actor.parameters(), lr=3e-4)
    data = transitions(10_000)
    low, high = torch.tensor([-0.4, -0.3], device=DEVICE), torch.tensor([0.8, 0.3], device=DEVICE)
    alpha, gamma, tau = 0.2, 0.99, 0.005

    def sample(obs):
        mu, log_std = actor(obs).chunk(2, -1)
        std = nn.functional.softplus(log_std) + 1e-4
        u = mu + std * torch.randn_like(mu)
        t = torch.tanh(u)
        logp = (-0.5 * ((u - mu) / std) ** 2 - std.log() - 0.5 * math.log(2 * math.pi)).sum(-1)
        logp = logp - torch.log((1 - t.pow(2)) * (high - low) / 2 + 1e-6).sum(-1)
        return low + (t + 1) * (high - low) / 2, logp

    def step():
        b = data[torch.randint(0, 10_000, (256,), device=DEVICE)]
        o, a, r = b["observation"], b["action"], b["next", "reward"]
        o2, d = b["next", "observation"], b["next", "terminated"].float()
        with torch.no_grad():
            a2, logp2 = sample(o2)
            x2 = torch.cat((o2, a2), -1)
            q_next = torch.min(t1(x2), t2(x2)) - alpha * logp2.unsqueeze(-1)
            y = r + gamma * (1 - d) * q_next
        x = torch.cat((o, a), -1)
        q_loss = (q1(x) - y).pow(2).mean() + (q2(x) - y).pow(2).mean()
        anew, logp = sample(o)
        xn = torch.cat((o, anew), -1)
        # the actor's loss reaches the actor only: the critics are read with detached weights
        q_new = [
            torch.func.functional_call(q, {k: v.detach() for k, v in q.named_parameters()}, xn)
            for q in (q1, q2)
        ]
        a_loss = (alpha * logp.unsqueeze(-1) - torch.min(*q_new)).mean()
        qa.zero_grad()
        aa.zero_grad()
        (q_loss + a_loss).backward()
        qa.step()
        aa.step()
        with torch.no_grad():
            for net, target in ((q1, t1), (q2, t2)):
                torch._foreach_lerp_(list(target.parameters()), list(net.parameters()), tau)

    return step


def plain_td3():
    actor = mlp([OBS, 400, 300, ACT])
    q1, q2 = mlp([OBS + ACT, 400, 300, 1]), mlp([OBS + ACT, 400, 300, 1])
    ta, t1, t2 = copy.deepcopy(actor), copy.deepcopy(q1), copy.deepcopy(q2)
    qa = torch.optim.Adam([*q1.parameters(), *q2.parameters()], lr=5e-4)
    aa = torch.optim.Adam(actor.parameters(), lr=5e-4)
    data = transitions(10_000)
    low, high = torch.tensor([-0.4, -0.3], device=DEVICE), torch.tensor([0.8, 0.3], device=DEVICE)
    counter = [0]

    def act(net, obs):
        return low + (torch.tanh(net(obs)) + 1) * (high - low) / 2

    def step():
        counter[0] += 1
        b = data[torch.randint(0, 10_000, (256,), device=DEVICE)]
        o, a, r = b["observation"], b["action"], b["next", "reward"]
        o2, d = b["next", "observation"], b["next", "terminated"].float()
        with torch.no_grad():
            noise = (torch.randn(256, ACT, device=DEVICE) * 0.2).clamp(-0.5, 0.5)
            a2 = torch.maximum(torch.minimum(act(ta, o2) + noise, high), low)
            x2 = torch.cat((o2, a2), -1)
            y = r + 0.99 * (1 - d) * torch.min(t1(x2), t2(x2))
        x = torch.cat((o, a), -1)
        q_loss = (q1(x) - y).pow(2).mean() + (q2(x) - y).pow(2).mean()
        qa.zero_grad()
        q_loss.backward()
        qa.step()
        if counter[0] % 2 == 0:
            a_loss = -q1(torch.cat((o, act(actor, o)), -1)).mean()
            aa.zero_grad()
            a_loss.backward()
            aa.step()
            with torch.no_grad():
                for net, target in ((actor, ta), (q1, t1), (q2, t2)):
                    torch._foreach_lerp_(list(target.parameters()), list(net.parameters()), 0.005)

    return step


def plain_ppo(compile_gradients: bool = False):
    """``compile_gradients``: ``torch.compile`` of the loss's forward and backward, what the
    agents' ``compile_update`` compiles (compiling the whole update, clipping and Adam
    included, grew past 20 GB of memory at 1 thread)."""
    actor, critic = mlp([OBS, 256, 256, 2 * ACT]), mlp([OBS, 256, 256, 1])
    params = [*actor.parameters(), *critic.parameters()]
    optim = torch.optim.Adam(params, lr=3e-4)
    mb = PPO_MINIBATCH
    n = mb * 32
    g = torch.Generator().manual_seed(0)
    obs, raw = torch.randn(n, OBS, generator=g), torch.randn(n, ACT, generator=g)
    old_logp, adv, ret = (
        torch.randn(n, generator=g),
        torch.randn(n, generator=g),
        torch.randn(n, generator=g),
    )
    obs, raw, old_logp, adv, ret = (x.to(DEVICE) for x in (obs, raw, old_logp, adv, ret))
    index = iter(range(10**9))

    def gradients(obs, raw, old_logp, a, ret):
        mu, log_std = actor(obs).chunk(2, -1)
        std = nn.functional.softplus(log_std) + 1e-4
        logp = torch.distributions.Normal(mu, std).log_prob(raw).sum(-1)
        a = (a - a.mean()) / (a.std() + 1e-8)
        ratio = (logp - old_logp).exp()
        objective = -torch.min(ratio * a, ratio.clamp(0.8, 1.2) * a).mean()
        value = 0.5 * (critic(obs).squeeze(-1) - ret).pow(2).mean()
        (objective + value).backward()

    if compile_gradients:
        gradients = torch.compile(gradients)

    def step():
        i = next(index) % 32
        sl = slice(i * mb, (i + 1) * mb)
        optim.zero_grad()
        gradients(obs[sl], raw[sl], old_logp[sl], adv[sl], ret[sl])
        torch.nn.utils.clip_grad_norm_(params, 0.5)
        optim.step()

    return step


PLAIN = {"sac": plain_sac, "td3": plain_td3, "ppo": plain_ppo}


def alternating_rates(steps: dict, seconds: float, rounds: int) -> list[dict[str, float]]:
    """Rates (updates/s) of each update function in ``steps``, measured in ``rounds``
    alternating rounds (so that a drift in the machine's speed hits all alike): one dict of
    rates per round."""
    return [
        {name: rate(step, seconds / rounds) for name, step in steps.items()} for _ in range(rounds)
    ]


def medians(rounds: list[dict[str, float]], base: str) -> tuple[dict, dict]:
    """Median rate of each variant, and the median over rounds of its time over ``base``'s
    (``base``'s rate over its)."""
    names = rounds[0]
    return (
        {n: statistics.median(r[n] for r in rounds) for n in names},
        {n: statistics.median(r[base] / r[n] for r in rounds) for n in names},
    )


def paired_rates(ours, plain, seconds: float, rounds: int) -> tuple[float, float, float]:
    """Median rates of two update functions measured in alternating rounds, and the median of
    the per-round time ratios (ours / plain)."""
    rounds_ = alternating_rates({"ours": ours, "plain": plain}, seconds, rounds)
    rates, ratios = medians(rounds_, "plain")
    return rates["ours"], rates["plain"], ratios["ours"]


# -- the floor ------------------------------------------------------------------------------
MATMULS = {"aten::mm", "aten::addmm", "aten::bmm", "aten::baddbmm"}


def matmul_shapes(step, calls: int) -> list[tuple[int, int, int, int]]:
    """``(batch, m, k, n)`` of every matrix product ``calls`` calls of ``step`` run, forward
    and backward (``torch.profiler``'s recorded input shapes)."""
    from torch.profiler import profile

    with profile(record_shapes=True) as prof:
        for _ in range(calls):
            step()
    shapes = []
    for event in prof.events():
        if event.name not in MATMULS:
            continue
        dims = [d for d in event.input_shapes if len(d) >= 2]
        left, right = dims[-2], dims[-1]  # addmm / baddbmm: (bias, left, right)
        batch = left[0] if len(left) == 3 else 1
        shapes.append((batch, left[-2], left[-1], right[-1]))
    return shapes


def floor(step, calls: int = 2, repeats: int = 30) -> tuple[float, float, float]:
    """The floor of the update ``step``, per call over ``calls`` calls (TD3 steps its actor
    every second one): its matrix products' GFLOP, the seconds they take replayed alone on
    contiguous operands (best of ``repeats``), and their GFLOP/s."""
    from torch.utils.flop_counter import FlopCounterMode

    for _ in range(3):
        step()
    counter = FlopCounterMode(display=False)
    with counter:
        for _ in range(calls):
            step()
    gflop = counter.get_total_flops() / 1e9 / calls
    operands = [
        (torch.randn(b, m, k, device=DEVICE), torch.randn(b, k, n, device=DEVICE))
        for b, m, k, n in matmul_shapes(step, calls)
    ]
    best = float("inf")
    for _ in range(repeats):
        _sync()
        start = time.perf_counter()
        for left, right in operands:
            torch.bmm(left, right) if left.shape[0] > 1 else torch.mm(left[0], right[0])
        _sync()
        best = min(best, (time.perf_counter() - start) / calls)
    return gflop, best, gflop / best


def write_paths(algo: str, seconds: float, rounds: int) -> None:
    """The agents' modules (``networks._WritesTensors``: outputs set directly) against the
    same update through ``TensorDictModule``'s own write path (``TensorDict.from_any`` on each
    output), in alternating rounds."""
    from tensordict.nn import TensorDictModule

    from dockingrl.agents import networks

    writes = {
        "direct": networks._WritesTensors.__dict__["_write_to_tensordict"],
        "from_any": TensorDictModule._write_to_tensordict,
    }

    def variant(name):
        networks._WritesTensors._write_to_tensordict = writes[name]
        update = torchrl_update(algo)

        def step():
            networks._WritesTensors._write_to_tensordict = writes[name]
            update()

        return step

    try:
        fast, slow, ratio = paired_rates(variant("direct"), variant("from_any"), seconds, rounds)
    finally:
        networks._WritesTensors._write_to_tensordict = writes["direct"]
    print(
        f"{algo}: outputs set directly {fast:,.1f} updates/s, through from_any {slow:,.1f}; "
        f"time ratio direct / from_any {ratio:.3f} (median over {rounds} alternating rounds)"
    )


def fast_paths(algo: str, seconds: float, rounds: int) -> None:
    """``fast_update``'s own paths against TorchRL's in the same update, with the default and
    the plain updates beside them, in alternating rounds: for SAC and TD3 the twin critics in
    turn (``torchrl_adapter.CriticsInTurn``) and the actor's own parameters unswapped
    (``torchrl_adapter.ModuleOwnParams``) against TorchRL's loop and swaps, for PPO the loss
    calling its modules directly against its functional calls."""
    import dockingrl.agents.ppo as ppo_module

    def torchrl_paths():
        if algo != "ppo":
            update = torchrl_update(algo, fast_update=True)
            loss = update.__self__.loss
            torchrl_loss = next(
                c for c in type(loss).__mro__ if c.__module__.startswith("torchrl.")
            )
            torchrl_loss._make_vmap(loss)  # the TorchRL loss's own
            # and TorchRL's swap of the actor's parameters at each of its evaluations
            loss.actor_network_params = TensorDictParams(loss.actor_network_params)
            return update
        stock = ppo_module.ClipPPOLoss
        ppo_module.ClipPPOLoss = lambda *a, **k: stock(*a, **{**k, "functional": True})
        try:
            return torchrl_update(algo, fast_update=True)
        finally:
            ppo_module.ClipPPOLoss = stock

    steps = {
        "default": torchrl_update(algo),
        "ours": torchrl_update(algo, fast_update=True),
        "torchrl": torchrl_paths(),
        "plain": PLAIN[algo](),
    }
    rates, ratios = medians(alternating_rates(steps, seconds, rounds), "plain")
    print(
        f"| {algo} | {rates['default']:,.0f} | {rates['ours']:,.0f} | {rates['torchrl']:,.0f} | "
        f"{rates['plain']:,.0f} | {ratios['default']:.2f}x | {ratios['ours']:.2f}x | "
        f"{ratios['torchrl']:.2f}x |"
    )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="per variant, all rounds")
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds per set")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--algos", nargs="+", default=["sac", "td3", "ppo"])
    parser.add_argument("--device", default="cpu", help="torch device of networks and data")
    parser.add_argument("--ppo-minibatch", type=int, default=64, help="PPO's minibatch size")
    parser.add_argument(
        "--no-compile", action="store_true", help="leave out the torch.compile rows"
    )
    parser.add_argument(
        "--write-paths",
        action="store_true",
        help="instead: the agents' direct output writes against TensorDictModule's from_any path",
    )
    parser.add_argument(
        "--fast-paths",
        action="store_true",
        help="instead: fast_update's own paths against TorchRL's (critics' loop, functional PPO)",
    )
    args = parser.parse_args(argv)
    global DEVICE, PPO_MINIBATCH
    DEVICE = torch.device(args.device)
    PPO_MINIBATCH = args.ppo_minibatch
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    print(f"machine: {describe_machine(DEVICE)}, updates on {DEVICE}")
    if args.fast_paths:
        print(
            "| algorithm | TorchRL updates/s | fast_update | fast_update, TorchRL's paths | "
            "plain PyTorch | TorchRL / plain | fast_update / plain | "
            "fast_update, TorchRL's paths / plain |"
        )
        print("|---|---|---|---|---|---|---|---|")
        for algo in args.algos:
            fast_paths(algo, args.seconds, args.rounds)
        print(f"(medians over {args.rounds} alternating rounds, ratios of per-round times)")
        return
    if args.write_paths:
        for algo in args.algos:
            write_paths(algo, args.seconds, args.rounds)
        return
    print(
        "| algorithm | TorchRL updates/s | TorchRL, fast_update | plain PyTorch updates/s | "
        "TorchRL time / plain | fast_update time / plain | floor updates/s | "
        "GFLOP per update | matmul GFLOP/s |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for algo in args.algos:
        plain = PLAIN[algo]()
        gflop, seconds, gflops = floor(plain)
        steps = {
            "torchrl": torchrl_update(algo),
            "fast": torchrl_update(algo, fast_update=True),
            "plain": plain,
        }
        rates, ratios = medians(alternating_rates(steps, args.seconds, args.rounds), "plain")
        print(
            f"| {algo} | {rates['torchrl']:,.0f} | {rates['fast']:,.0f} | {rates['plain']:,.0f} | "
            f"{ratios['torchrl']:.2f}x | {ratios['fast']:.2f}x | {1 / seconds:,.0f} | "
            f"{gflop:.3f} | {gflops:.1f} |"
        )
    print(
        f"(medians over {args.rounds} alternating rounds; a ratio is the median of the per-round "
        f"ratios; the floor: the plain update's matrix products alone, at {args.threads} "
        "thread(s), best of 30)"
    )
    if args.no_compile:
        return
    print()
    print(
        "| algorithm | TorchRL, compile_update | compile_update + fast_update | plain PyTorch | "
        "plain, torch.compile | compile_update / plain | compile_update + fast_update / plain | "
        "compile_update / compiled plain | compile_update + fast_update / compiled plain |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for algo in args.algos:
        # each compiled agent alternates with the plain updates alone: two compiled agents
        # taking turns make dynamo recompile their shared loss code at every turn (each turn's
        # exit from tensordict's pytree context changes a dict it guards on)
        torch._dynamo.reset()  # drop the graphs of the agents before (memory, recompile limits)
        plain = PLAIN[algo]()
        compiled_plain = (
            plain_ppo(compile_gradients=True) if algo == "ppo" else torch.compile(PLAIN[algo]())
        )
        rates, ratios = {}, {}
        for name, fast in (("torchrl", False), ("fast", True)):
            steps = {
                name: torchrl_update(algo, compile_update=True, fast_update=fast),
                "plain": plain,
                "compiled_plain": compiled_plain,
            }
            rounds = alternating_rates(steps, args.seconds, args.rounds)
            rates.update(medians(rounds, "plain")[0])
            ratios[name] = medians(rounds, "plain")[1][name]
            ratios[name, "compiled"] = medians(rounds, "compiled_plain")[1][name]
        print(
            f"| {algo} | {rates['torchrl']:,.0f} | {rates['fast']:,.0f} | {rates['plain']:,.0f} | "
            f"{rates['compiled_plain']:,.0f} | {ratios['torchrl']:.2f}x | {ratios['fast']:.2f}x | "
            f"{ratios['torchrl', 'compiled']:.2f}x | {ratios['fast', 'compiled']:.2f}x |"
        )
    print(
        "(compiled rates exclude the compilation, done during the warm-up; each compiled agent "
        "alternates with both plain updates, whose rates are those of the second set; plain "
        "PPO compiles the loss's forward and backward, as compile_update does, plain SAC and "
        "TD3 the whole update)"
    )


if __name__ == "__main__":
    main()
