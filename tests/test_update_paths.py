"""The update's speed paths: the soft target update as one foreach lerp gives TorchRL's
``SoftUpdate`` numbers exactly; ``fast_update`` (fused Adam, the twin critics as plain matrix
products on a CPU) computes the default update up to rounding."""

import copy
from contextlib import nullcontext

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictParams
from torchrl.objectives import SoftUpdate, TD3Loss

from dockingrl.agents import make_agent
from dockingrl.agents.config import make_config
from dockingrl.agents.torchrl_adapter import CriticsInTurn, ModuleOwnParams
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


def trained(algo: str, updates: int, stock=None, **options):
    """The loss state of an agent of ``algo`` (tiny networks) after ``updates`` updates on a
    fixed buffer, from fixed seeds; ``stock(agent)``, if given, first puts back one of
    TorchRL's own pieces in place of dockingrl's."""
    spec = make_env("compound", 1, seed=0).action_spec[0]
    torch.manual_seed(0)
    cfg = make_config(algo, "paper", hidden=(32, 32), batch_size=64, **options)
    agent = make_agent(cfg, OBS, spec, 30.0, "cpu")
    if stock is not None:
        stock(agent)
    agent.replay_buffer.extend(transitions(500))
    torch.manual_seed(1)
    for _ in range(updates):
        agent._off_policy_update()
    return agent, agent.loss.state_dict()


def stock_soft_update(agent):
    agent.target_updater = SoftUpdate(agent.loss, tau=agent.config.tau)


def stock_critic_loop(agent):
    """TorchRL's own loop over the critics."""
    torchrl_loss = next(c for c in type(agent.loss).__mro__ if c.__module__.startswith("torchrl."))
    torchrl_loss._make_vmap(agent.loss)


def stock_actor_swaps(agent):
    """TorchRL's ``TensorDictParams`` for the actor: a swap into the actor at each call."""
    agent.loss.actor_network_params = TensorDictParams(agent.loss.actor_network_params)


def stock_td3_actor_loss(agent):
    """TorchRL's TD3 actor loss, which evaluates both critics."""
    agent.loss.actor_loss = TD3Loss.actor_loss.__get__(agent.loss)


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_the_foreach_soft_update_gives_softupdates_numbers(algo):
    _, ours = trained(algo, 6)
    _, stock = trained(algo, 6, stock=stock_soft_update)
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


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_critics_in_turn_give_torchrls_loop_numbers(algo):
    ours, ours_state = trained(algo, 4, fast_update=True)
    attr = "_vmap_qnetworkN0" if algo == "sac" else "_vmap_qvalue_network00"
    assert isinstance(getattr(ours.loss, attr), CriticsInTurn)
    agent, stock = trained(algo, 4, stock=stock_critic_loop, fast_update=True)
    assert not isinstance(getattr(agent.loss, attr), CriticsInTurn)
    for key in ours_state:
        assert torch.equal(ours_state[key], stock[key]), key
    # the module keeps its own parameters between calls
    for name, tensor in ours.loss.qvalue_network.module.named_parameters():
        assert isinstance(tensor, torch.nn.Parameter), name
    _, start = trained(algo, 0, fast_update=True)
    assert any((stock[k] - start[k]).abs().max() > 1e-3 for k in stock)


def test_fast_update_ppo_calls_its_modules_directly_with_the_same_gradients():
    spec = make_env("compound", 1, seed=0).action_spec[0]
    grads = {}
    data = transitions(64)
    for fast in (False, True):
        torch.manual_seed(0)
        cfg = make_config("ppo", "paper", hidden=(32, 32), fast_update=fast)
        agent = make_agent(cfg, OBS, spec, 30.0, "cpu")
        assert agent.loss.functional is not fast
        batch = data.clone()
        with torch.no_grad():
            agent.actor(batch)
            agent.advantage.value_network(batch)
        batch["advantage"] = torch.linspace(-1, 1, 64).unsqueeze(-1)
        batch["value_target"] = torch.linspace(0, 2, 64).unsqueeze(-1)
        torch.manual_seed(2)
        agent._gradients("ppo", batch)
        grads[fast] = [p.grad.clone() for p in agent.loss.parameters()]
    assert len(grads[True]) == len(grads[False]) > 0
    for ours, stock in zip(grads[True], grads[False], strict=True):
        assert torch.equal(ours, stock)
    assert any(g.abs().max() > 0 for g in grads[True])


def test_ppo_accepts_compile_update():
    assert make_config("ppo", "paper", compile_update=True).compile_update


def test_td3_actor_loss_reads_the_first_critic_alone_to_torchrls_numbers():
    ours, ours_state = trained("td3", 6, fast_update=True)
    _, stock = trained("td3", 6, stock=stock_td3_actor_loss, fast_update=True)
    for key, value in stock.items():
        assert torch.equal(ours_state[key], value), key
    # one critic pass: the first critic's values, of the batch's size
    calls = []
    critics = ours.loss._vmap_qvalue_network00

    def counted(td, params):
        calls.append(params.batch_size)
        return critics(td, params)

    ours.loss._vmap_qvalue_network00 = counted
    loss, meta = ours.loss.actor_loss(ours.replay_buffer.sample())
    assert calls == [torch.Size([1])] and meta["state_action_value_actor"].shape == (1, 64)
    _, start = trained("td3", 0, fast_update=True)
    assert any(not torch.equal(ours_state[k], start[k]) for k in ours_state if "actor" in k)


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_the_actors_own_parameters_are_not_swapped_and_give_torchrls_numbers(algo):
    ours, ours_state = trained(algo, 4, fast_update=True)
    params, actor = ours.loss.actor_network_params, ours.loss.actor_network
    assert isinstance(params, ModuleOwnParams)
    assert isinstance(params.to_module(actor, preserve_module_state=False), nullcontext)
    agent, stock = trained(algo, 4, stock=stock_actor_swaps, fast_update=True)
    assert type(agent.loss.actor_network_params) is TensorDictParams
    assert ours_state.keys() == stock.keys()
    for key in ours_state:
        assert torch.equal(ours_state[key], stock[key]), key
    _, start = trained(algo, 0, fast_update=True)
    assert any(not torch.equal(ours_state[k], start[k]) for k in ours_state if "actor" in k)
    # the default update keeps TorchRL's
    default, _ = trained(algo, 0)
    assert type(default.loss.actor_network_params) is TensorDictParams


def actor_layer(loss, key):
    """The actor's module that holds the tensor at ``key`` of the loss's actor parameters."""
    layer = loss.actor_network
    for part in key[:-1]:
        layer = getattr(layer, part)
    return layer


def test_a_replaced_actor_parameter_is_swapped_in():
    ours, _ = trained("sac", 0, fast_update=True)
    params, actor = ours.loss.actor_network_params, ours.loss.actor_network
    key, weight = next((k, v) for k, v in params.items(True, True) if k[-1] == "weight")
    layer = actor_layer(ours.loss, key)
    assert layer.weight is weight
    zeros = torch.nn.Parameter(torch.zeros_like(weight))
    params.set(key, zeros)
    with params.to_module(actor, preserve_module_state=False):
        assert layer.weight is zeros
    # out of the swap, the actor holds its own again
    assert layer.weight is weight


def test_a_parameter_replaced_in_the_actor_is_swapped_out():
    ours, _ = trained("sac", 0, fast_update=True)
    params, actor = ours.loss.actor_network_params, ours.loss.actor_network
    key, weight = next((k, v) for k, v in params.items(True, True) if k[-1] == "weight")
    layer = actor_layer(ours.loss, key)
    layer.weight = torch.nn.Parameter(torch.zeros_like(weight))
    with params.to_module(actor, preserve_module_state=False):
        assert layer.weight is weight


def test_another_module_and_a_moved_buffer_are_swapped():
    ours, _ = trained("td3", 0, fast_update=True)
    params, actor = ours.loss.actor_network_params, ours.loss.actor_network
    other = copy.deepcopy(actor)
    assert not isinstance(params.to_module(other, preserve_module_state=False), nullcontext)
    ours.loss.double()  # the loss's buffers move to new memory, the actor's stay
    key, buffer = next((k, v) for k, v in params.items(True, True) if k[-1] == "scale")
    assert actor_layer(ours.loss, key).scale.dtype == torch.float32
    with params.to_module(actor, preserve_module_state=False):
        assert actor_layer(ours.loss, key).scale.dtype == torch.float64
