"""``critic_dropout``: DroQ's dropout in the critics of SAC and TD3."""

import pytest
import torch

from dockingrl.agents import make_agent
from dockingrl.agents.config import make_config
from dockingrl.scenarios import make_env


def _agent(algo, **options):
    env = make_env("no_noise", 4, seed=0)
    cfg = make_config(algo, "paper", hidden=(32, 16), batch_size=16, buffer_size=1000, **options)
    return env, make_agent(cfg, 6, env.action_spec[0], 30.0)


@pytest.mark.parametrize("fast_update", [False, True])
@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_dropout_sits_after_each_hidden_linear_layer_and_the_update_trains(algo, fast_update):
    env, agent = _agent(algo, critic_dropout=0.25, critic_layer_norm=True, fast_update=fast_update)
    critic = agent.loss.qvalue_network.module
    layers = [
        type(m).__name__
        for m in critic.modules()
        if isinstance(m, torch.nn.Linear | torch.nn.Dropout | torch.nn.LayerNorm)
    ]
    assert layers == ["Linear", "SparseDropout", "LayerNorm"] * 2 + ["Linear"]
    assert {m.p for m in critic.modules() if isinstance(m, torch.nn.Dropout)} == {0.25}
    # in training the critic's value is random; in evaluation it is not
    obs, act = torch.randn(64, 6), torch.rand(64, 2)
    assert not torch.equal(critic(obs, act), critic(obs, act))
    critic.eval()
    assert torch.equal(critic(obs, act), critic(obs, act))
    critic.train()
    # TorchRL's loss (its vmapped twin critics, or dockingrl's critics in turn) updates
    # through the dropout
    params = agent.loss.qvalue_network_params.flatten_keys()
    before = params.clone()
    agent.learn(env.rollout(20, break_when_any_done=False), num_updates=2)
    after = agent.loss.qvalue_network_params.flatten_keys()
    assert all(torch.isfinite(after[k]).all() for k in after.keys())
    assert any(not torch.equal(before[k], after[k]) for k in after.keys())


def test_without_dropout_the_critic_has_none_and_the_actor_never_does():
    _, plain = _agent("sac")
    _, dropped = _agent("sac", critic_dropout=0.1)
    assert not any(isinstance(m, torch.nn.Dropout) for m in plain.loss.modules())
    assert not any(isinstance(m, torch.nn.Dropout) for m in dropped.actor.modules())


@pytest.mark.parametrize(
    ("value", "says"),
    [
        (-0.1, r"must lie in \[0, 1\)"),
        (1.0, r"must lie in \[0, 1\)"),
        (float("nan"), "must be finite"),
    ],
)
def test_a_dropout_outside_zero_to_one_is_refused(value, says):
    with pytest.raises(ValueError, match=f"SACConfig.critic_dropout: {says}"):
        make_config("sac", "paper", critic_dropout=value).validate()


@pytest.mark.parametrize(("p", "shape"), [(0.01, (64, 256)), (0.3, (8, 50)), (0.5, (1,))])
def test_sparse_dropout_zeroes_each_entry_independently_with_probability_p(p, shape):
    from dockingrl.agents.networks import SparseDropout

    torch.manual_seed(0)
    dropout = SparseDropout(p)
    x = torch.full(shape, 2.0)
    masks = torch.stack([dropout(x) == 0 for _ in range(4000 if shape == (1,) else 200)])
    kept = torch.stack([dropout(x) for _ in range(3)])
    # the kept entries are scaled by 1 / (1 - p)
    assert torch.allclose(kept[kept != 0], torch.tensor(2.0 / (1 - p)))
    # the rate of dropped entries over all draws, within 5 binomial standard deviations of p
    n = masks.numel()
    assert abs(masks.float().mean().item() - p) < 5 * (p * (1 - p) / n) ** 0.5
    # every position alike (the first and the last entry of the mask included) and neighbours
    # uncorrelated
    flat = masks.flatten(1).float()
    for column in (flat[:, 0], flat[:, -1]):
        assert abs(column.mean().item() - p) < 5 * (p * (1 - p) / len(column)) ** 0.5
    if flat.shape[1] > 1:
        pairs = torch.stack((flat[:, :-1].flatten(), flat[:, 1:].flatten()))
        assert abs(torch.corrcoef(pairs)[0, 1].item()) < 5 / pairs.shape[1] ** 0.5
    # evaluation mode and p = 0 leave the input as it is
    assert torch.equal(dropout.eval()(x), x)
    assert torch.equal(SparseDropout(0.0)(x), x)
