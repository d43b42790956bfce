"""The update's speed paths: the soft target update as one foreach lerp gives TorchRL's
``SoftUpdate`` numbers exactly; ``fast_update`` (fused Adam, the twin critics as plain matrix
products on a CPU) computes the default update up to rounding."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.objectives import SoftUpdate

from dockingrl.agents import make_agent
from dockingrl.agents.config import make_config
from dockingrl.scenarios import make_env

OBS = 12


def transitions(n: int) -> TensorDict:
    g = torch.Generator().manual_seed(0)
    return TensorDict(
        {
            "observation": torch.randn(n, OBS, generator=g),
            "action": torch.rand(n, 2, generator=g) * 0.6 - 0.3,
            "next": {
                "observation": torch.randn(n, OBS, generator=g),
                "reward": torch.randn(n, 1, generator=g),
                "done": torch.zeros(n, 1, dtype=torch.bool),
                "terminated": torch.zeros(n, 1, dtype=torch.bool),
                "truncated": torch.zeros(n, 1, dtype=torch.bool),
            },
        },
        batch_size=[n],
    )


def trained(algo: str, updates: int, stock_soft_update: bool = False, **options):
    """The loss state of an agent of ``algo`` (tiny networks) after ``updates`` updates on a
    fixed buffer, from fixed seeds."""
    spec = make_env("compound", 1, seed=0).action_spec[0]
    torch.manual_seed(0)
    cfg = make_config(algo, "paper", hidden=(32, 32), batch_size=64, **options)
    agent = make_agent(cfg, OBS, spec, 30.0, "cpu")
    if stock_soft_update:
        agent.target_updater = SoftUpdate(agent.loss, tau=cfg.tau)
    agent.replay_buffer.extend(transitions(500))
    torch.manual_seed(1)
    for _ in range(updates):
        agent._off_policy_update()
    return agent, agent.loss.state_dict()


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_the_foreach_soft_update_gives_softupdates_numbers(algo):
    _, ours = trained(algo, 6)
    _, stock = trained(algo, 6, stock_soft_update=True)
    targets = [k for k in ours if k.startswith("target_")]
    assert targets
    for key in ours:
        assert torch.equal(ours[key], stock[key]), key
    # the targets moved: the updater ran
    _, start = trained(algo, 0)
    assert any(not torch.equal(ours[k], start[k]) for k in targets)


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_fast_update_computes_the_default_update_up_to_rounding(algo):
    fast, ours = trained(algo, 4, fast_update=True)
    _, default = trained(algo, 4)
    assert fast.loss.deactivate_vmap
    assert all(o.defaults["fused"] for o in fast.optimizers.values())
    _, start = trained(algo, 0)
    for key in ours:
        assert torch.allclose(ours[key], default[key], rtol=1e-4, atol=1e-5), key
    # the updates moved the weights well beyond the tolerance
    assert any((default[k] - start[k]).abs().max() > 1e-3 for k in ours)


def test_fast_update_ppo_estimates_the_same_advantages_in_chunks():
    spec = make_env("compound", 1, seed=0).action_spec[0]
    agents = {}
    for fast in (False, True):
        torch.manual_seed(0)
        cfg = make_config(
            "ppo", "paper", hidden=(32, 32), steps_per_env=8, minibatch_size=8, fast_update=fast
        )
        agents[fast] = make_agent(cfg, OBS, spec, 30.0, "cpu")
    assert agents[True].advantage.value_chunk_size == 2048 // 8
    data = transitions(600 * 8).reshape(600, 8)  # three chunks of 256 envs and fewer
    data["next", "done"][::7, 3] = True
    data["next", "terminated"][::7, 3] = True
    with torch.no_grad():
        default, chunked = (agents[f].advantage(data.clone()) for f in (False, True))
    for key in ("advantage", "value_target", "state_value"):
        assert torch.allclose(default[key], chunked[key], rtol=1e-5, atol=1e-5), key
    assert default["advantage"].std() > 0.1
