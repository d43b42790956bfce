"""n-step transitions of the off-policy agents: sums, episode ends, the carry between
collections, the bootstrap discount, checkpoints and a training run; the critics' options
(LayerNorm, privileged inputs); the actors' tanh-Normal against TorchRL's."""

import pytest
import torch
from helpers import smoke_config
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import TanhNormal, ValueOperator
from torchrl.objectives.value import TD0Estimator

from dockingrl.agents import (
    PRIVILEGED_KEYS,
    TRANSITION_KEYS,
    make_agent,
    n_step_transitions,
    networks,
    privileged_features,
    transition_keys,
)
from dockingrl.agents.config import make_config
from dockingrl.agents.distributions import BoundedTanhNormal
from dockingrl.agents.networks import _WritesTensors
from dockingrl.agents.saving import load_policy
from dockingrl.scenarios import make_env
from dockingrl.training import Trainer, train

GAMMA = 0.9
_stock_write = TensorDictModule._write_to_tensordict


def trajectories(envs: int, steps: int, seed: int = 0) -> TensorDict:
    """Time-ordered transitions with episode ends: terminations and truncations at random."""
    g = torch.Generator().manual_seed(seed)
    terminated = torch.rand(envs, steps, 1, generator=g) < 0.15
    truncated = (torch.rand(envs, steps, 1, generator=g) < 0.1) & ~terminated
    return TensorDict(
        {
            "observation": torch.randn(envs, steps, 3, generator=g),
            "action": torch.randn(envs, steps, 2, generator=g),
            "next": {
                "observation": torch.randn(envs, steps, 3, generator=g),
                "reward": torch.randn(envs, steps, 1, generator=g),
                "done": terminated | truncated,
                "terminated": terminated,
                "truncated": truncated,
            },
        },
        batch_size=[envs, steps],
    )


def reference(data: TensorDict, n: int, env: int, t: int) -> dict:
    """One n-step transition by the definition, one step at a time."""
    reward, m = 0.0, 0
    while m < n:
        reward += GAMMA**m * float(data["next", "reward"][env, t + m])
        m += 1
        if bool(data["next", "done"][env, t + m - 1]):
            break
    last = t + m - 1
    return {
        "reward": reward,
        "steps": m,
        "next_observation": data["next", "observation"][env, last],
        "terminated": bool(data["next", "terminated"][env, last]),
        "truncated": bool(data["next", "truncated"][env, last]),
    }


@pytest.mark.parametrize("n", [1, 2, 4])
def test_n_step_transitions_match_the_definition(n):
    data = trajectories(3, 20)
    out = n_step_transitions(data, n, GAMMA)
    assert out.shape == (3, 20 - n + 1)
    for env in range(3):
        for t in range(out.shape[1]):
            ref = reference(data, n, env, t)
            assert float(out["next", "reward"][env, t]) == pytest.approx(ref["reward"], abs=1e-5)
            assert int(out["steps_to_next_obs"][env, t]) == ref["steps"]
            assert torch.equal(out["next", "observation"][env, t], ref["next_observation"])
            assert bool(out["next", "terminated"][env, t]) == ref["terminated"]
            assert bool(out["next", "truncated"][env, t]) == ref["truncated"]
            assert torch.equal(out["observation"][env, t], data["observation"][env, t])
            assert torch.equal(out["action"][env, t], data["action"][env, t])


def test_n_step_transitions_need_a_whole_window():
    with pytest.raises(ValueError, match="at least 5 steps"):
        n_step_transitions(trajectories(2, 4), 5, GAMMA)


def agent_with(n: int, num_envs: int = 3):
    env = make_env("no_noise", 1, seed=0)
    cfg = make_config(
        "sac",
        "paper",
        n_steps=n,
        gamma=GAMMA,
        hidden=(8,),
        num_envs=num_envs,
        frames_per_batch=30,
        batch_size=4,
    )
    return make_agent(cfg, 6, env.action_spec[0], 30.0)


def test_collections_are_joined_so_no_transition_is_lost_or_cut():
    """Two collections give the transitions of their concatenation: the last n - 1 steps of
    the first wait for the second."""
    data = trajectories(3, 20, seed=1)
    agent = agent_with(4)
    agent.learn(data[:, :10])
    first = len(agent.replay_buffer)
    agent.learn(data[:, 10:])
    stored = agent.replay_buffer[:]
    whole = n_step_transitions(data, 4, GAMMA)
    expected = torch.cat((whole[:, :7].reshape(-1), whole[:, 7:].reshape(-1)))
    assert first == 3 * 7 and len(stored) == len(expected) == 3 * (20 - 3)
    for key in (("next", "reward"), ("next", "observation"), "action", "steps_to_next_obs"):
        assert torch.allclose(stored[key], expected[key])


def test_a_resumed_agent_does_not_join_steps_across_the_restart():
    """A resumed run restarts its envs' episodes: the steps waiting at the checkpoint have no
    continuation, so the first collection after it starts its own windows."""
    data = trajectories(3, 20, seed=1)
    agent = agent_with(4)
    agent.learn(data[:, :10])
    resumed = agent_with(4)
    resumed.load_state_dict(agent.state_dict())
    resumed.learn(data[:, 10:])
    expected = n_step_transitions(data[:, 10:], 4, GAMMA).reshape(-1)
    stored = resumed.replay_buffer[:]
    assert len(stored) == len(expected) == 3 * 7
    assert torch.allclose(stored["next", "reward"], expected["next", "reward"])


def test_one_step_agents_store_the_collected_transitions_unchanged():
    data = trajectories(3, 10)
    agent = agent_with(1)
    agent.learn(data)
    stored = agent.replay_buffer[:]
    assert "steps_to_next_obs" not in stored.keys()
    assert torch.equal(stored["next", "reward"], data["next", "reward"].reshape(-1, 1))


def test_td0_target_discounts_by_gamma_to_the_steps_summed():
    """TorchRL's TD(0) estimator, which SACLoss and TD3Loss use, bootstraps with
    gamma^steps_to_next_obs and not at all after a termination."""
    value = ValueOperator(torch.nn.Linear(3, 1), in_keys=["observation"])
    data = n_step_transitions(trajectories(2, 30, seed=2), 3, GAMMA).reshape(-1)
    estimator = TD0Estimator(gamma=GAMMA, value_network=value)
    target = estimator.value_estimate(data)
    with torch.no_grad():
        next_value = value(data["next"].clone())["state_value"]
    m = data["steps_to_next_obs"]
    live = (~data["next", "terminated"]).float()
    expected = data["next", "reward"] + GAMMA**m * live * next_value
    assert torch.allclose(target, expected, atol=1e-5)


def test_n_steps_must_fit_one_collection():
    with pytest.raises(ValueError, match="n_steps"):
        make_config("sac", "paper", n_steps=0)
    with pytest.raises(ValueError, match="transitions per env of one collection"):
        make_config("td3", "paper", n_steps=11, num_envs=100, frames_per_batch=1000)
    # with action repeat, a collection holds frames_per_batch // action_repeat env steps
    with pytest.raises(ValueError, match=r"action_repeat // num_envs = 15 \(got 20\)"):
        make_config("sac", "paper", n_steps=20, num_envs=16, action_repeat=4)
    make_config("sac", "paper", n_steps=15, num_envs=16, action_repeat=4)


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_off_policy_agents_train_with_n_step_targets(algo, tmp_path, short_episodes):
    cfg = smoke_config(
        algo,
        "no_noise",
        tmp_path,
        f"{algo}_n3",
        n_steps=3,
        total_steps=400,
        start_steps=100,
        frames_per_batch=100,
        updates_per_step=0.5,
        eval_every=400,
    )
    result = train(cfg, progress=False)
    assert result["summary"]["frames"] == 400
    assert result["summary"]["updates"] == 150
    # the updates trained the saved actor: its weights left their initial values (the same
    # seed builds the same initial agent)
    initial = Trainer(cfg, tmp_path / "initial", progress=False).agent.policy.state_dict()
    trained = load_policy(tmp_path / f"{algo}_n3" / "policy.pt")[0].state_dict()
    assert set(trained) == set(initial)
    assert any(not torch.equal(trained[k], initial[k]) for k in initial)


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_critic_layer_norm_normalises_each_hidden_layer_and_trains(algo):
    env = make_env("no_noise", 4, seed=0)
    spec = env.action_spec[0]
    plain = make_agent(make_config(algo, "paper", hidden=(32, 16)), 6, spec, 30.0)
    normed = make_agent(
        make_config(
            algo,
            "paper",
            hidden=(32, 16),
            critic_layer_norm=True,
            batch_size=16,
            buffer_size=1000,
        ),
        6,
        spec,
        30.0,
    )
    assert not any(isinstance(m, torch.nn.LayerNorm) for m in plain.loss.modules())
    critic = normed.loss.qvalue_network.module
    norms = [m for m in critic.modules() if isinstance(m, torch.nn.LayerNorm)]
    assert [n.normalized_shape for n in norms] == [(32,), (16,)]
    # every hidden activation sees a zero-mean, unit-variance input (before the affine part,
    # which starts as the identity)
    seen = []
    hooks = [
        m.register_forward_hook(lambda _m, inp, _out: seen.append(inp[0]))
        for m in critic.modules()
        if isinstance(m, torch.nn.ReLU)
    ]
    obs = 10.0 * torch.randn(64, 6)
    critic(obs, torch.rand(64, 2))
    for hook in hooks:
        hook.remove()
    assert len(seen) == 2
    for x in seen:
        torch.testing.assert_close(x.mean(-1), torch.zeros(64), atol=1e-4, rtol=0)
        torch.testing.assert_close(x.var(-1, unbiased=False), torch.ones(64), atol=1e-2, rtol=0)
    # the loss's critic parameters (both critics) include the LayerNorm gains, and an update
    # trains them
    params = normed.loss.qvalue_network_params.flatten_keys()
    gains = [k for k in params.keys() if k.endswith(".1.weight") or k.endswith(".4.weight")]
    assert [tuple(params[k].shape) for k in gains] == [(2, 32), (2, 16)]
    before = params.clone()
    normed.learn(env.rollout(20, break_when_any_done=False), num_updates=2)
    after = normed.loss.qvalue_network_params.flatten_keys()
    assert all(not torch.equal(before[k], after[k]) for k in gains)


def test_privileged_critic_reads_true_state_and_current_the_policy_does_not():
    algo = "sac"
    env = make_env("compound", 4, seed=0)
    spec = env.action_spec[0]
    cfg = make_config(
        algo, "paper", hidden=(32, 16), privileged_critic=True, batch_size=16, buffer_size=1000
    )
    agent = make_agent(cfg, 12, spec, 30.0)
    plain = make_agent(make_config(algo, "paper", hidden=(32, 16)), 12, spec, 30.0)
    assert plain.loss.qvalue_network.in_keys == ["observation", "action"]
    critic = agent.loss.qvalue_network
    assert critic.in_keys == ["observation", "true_state", "ocean_current", "action"]
    # the policy's input is unchanged: a saved actor runs on the compound observation alone
    actor_keys = {k for m in agent.actor.modules() if hasattr(m, "in_keys") for k in m.in_keys}
    assert "true_state" not in actor_keys and "ocean_current" not in actor_keys

    # the features: x, y over max_dist, cos and sin of the heading, u, v, r, then the current
    state = torch.tensor([[-15.0, 3.0, torch.pi / 2, 0.5, -0.1, 0.2]])
    current = torch.tensor([[0.3, -0.2]])
    expected = torch.tensor([[-0.5, 0.1, 0.0, 1.0, 0.5, -0.1, 0.2, 0.3, -0.2]])
    torch.testing.assert_close(privileged_features(state, current, 30.0), expected)

    # Q depends on the current although the observation and action stay the same
    td = env.reset()
    td["action"] = spec.rand((4,))
    q = critic(td.clone())["state_action_value"]
    td["ocean_current"] = -td["ocean_current"]
    assert not torch.allclose(q, critic(td)["state_action_value"])

    # the replay buffer keeps both steps' privileged entries and the update trains the critic
    before = agent.loss.qvalue_network_params.clone()
    agent.learn(env.rollout(20, break_when_any_done=False), num_updates=2)
    stored = agent.replay_buffer.sample()
    for key in (*PRIVILEGED_KEYS, *(("next", k) for k in PRIVILEGED_KEYS)):
        assert key in stored.keys(include_nested=True)
    after = agent.loss.qvalue_network_params
    assert any(
        not torch.equal(a, b)
        for a, b in zip(before.values(True, True), after.values(True, True), strict=True)
    )
    # without the option nothing extra is stored
    plain_cfg = make_config(algo, "paper", hidden=(32, 16), batch_size=16, buffer_size=1000)
    assert transition_keys(plain_cfg) == TRANSITION_KEYS


@pytest.mark.parametrize("algo", ["sac", "td3", "ppo"])
def test_agents_modules_write_tensor_outputs_directly_with_torchrls_results(algo, monkeypatch):
    """The actor and critic modules set their tensor outputs without ``TensorDict.from_any``
    (see ``networks._WritesTensors``) and compute exactly what ``TensorDictModule`` does."""
    env = make_env("compound", 4, seed=0)
    spec = env.action_spec[0]
    sizes = (
        {"num_envs": 4, "steps_per_env": 8, "minibatch_size": 16}
        if algo == "ppo"
        else {"batch_size": 16, "buffer_size": 1000}
    )
    cfg = make_config(algo, "paper", hidden=(32, 16), **sizes)
    torch.manual_seed(0)
    with torch.no_grad():  # PPO learns from its own actor's actions and log-probabilities
        data = env.rollout(8, make_agent(cfg, 12, spec, 30.0).actor, break_when_any_done=False)

    def run(patch: bool):
        torch.manual_seed(0)
        agent = make_agent(cfg, 12, spec, 30.0)
        if patch:  # the stock TensorDictModule path, which goes through from_any
            monkeypatch.setattr(_WritesTensors, "_write_to_tensordict", _stock_write)
        torch.manual_seed(1)
        agent.learn(data.clone(), **({} if algo == "ppo" else {"num_updates": 2}))
        monkeypatch.undo()
        return [p.detach().clone() for p in agent.loss.parameters()]

    calls = []
    original = TensorDictBase.from_any.__func__

    def counting(cls, obj, **kwargs):
        calls.append(type(obj))
        return original(cls, obj, **kwargs)

    monkeypatch.setattr(TensorDictBase, "from_any", classmethod(counting))
    stock = run(patch=True)
    stock_calls = len(calls)
    monkeypatch.setattr(TensorDictBase, "from_any", classmethod(counting))
    calls.clear()
    direct = run(patch=False)
    assert stock_calls > 0 and calls == []
    assert len(stock) == len(direct)
    for a, b in zip(stock, direct, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


def _tanh_normal_outputs(cls, method: str):
    """One method of a tanh-Normal on fixed parameters (some of them saturating) and the
    gradients of its outputs' sum with respect to loc and scale."""
    g = torch.Generator().manual_seed(0)
    loc = (3 * torch.randn(256, 2, generator=g)).requires_grad_()
    scale = (torch.rand(256, 2, generator=g) + 1e-3).requires_grad_()
    low, high = torch.tensor([-0.4, -0.3]), torch.tensor([0.8, 0.3])
    dist = cls(loc, scale, low=low, high=high)
    torch.manual_seed(3)
    if method == "log_prob":
        action = low + (high - low) * torch.rand(256, 2, generator=g)
        action[:8] = high  # on the bounds: the clamped atanh
        out = (dist.log_prob(action),)
    elif method == "deterministic_sample":
        out = (dist.deterministic_sample,)
    else:
        out = getattr(dist, method)((3,))
        out = out if isinstance(out, tuple) else (out,)
    differentiable = [o for o in out if o.requires_grad]
    grads = ()
    if differentiable:  # zero where an output does not depend on the parameter
        total = sum(o.sum() for o in differentiable)
        grads = torch.autograd.grad(total, (loc, scale), allow_unused=True)
        grads = tuple(torch.zeros(()) if g is None else g for g in grads)
    return out, grads


@pytest.mark.parametrize(
    "method",
    [
        "rsample_and_log_prob",
        "sample_and_log_prob",
        "rsample",
        "sample",
        "log_prob",
        "deterministic_sample",
    ],
)
def test_bounded_tanh_normal_is_torchrls_tanh_normal_to_the_last_bit(method):
    """Same random state, same samples, log-probabilities and gradients as TorchRL's
    ``TanhNormal`` (``tanh_loc=False``, safe tanh), exactly."""
    ours, ours_grads = _tanh_normal_outputs(BoundedTanhNormal, method)
    theirs, their_grads = _tanh_normal_outputs(TanhNormal, method)
    assert len(ours) == len(theirs) and len(ours_grads) == len(their_grads)
    for a, b in zip((*ours, *ours_grads), (*theirs, *their_grads), strict=True):
        assert a.shape == b.shape
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    low, high = torch.tensor([-0.4, -0.3]), torch.tensor([0.8, 0.3])
    if method != "log_prob":
        assert ((ours[0] >= low) & (ours[0] <= high)).all()


@pytest.mark.parametrize("algo", ["sac", "ppo"])
def test_agents_learn_the_same_with_torchrls_tanh_normal(algo, monkeypatch):
    """Swapping the actors' distribution for TorchRL's ``TanhNormal`` changes no collected
    action or log-probability and no parameter after a few updates, to the last bit."""
    sizes = (
        {"num_envs": 4, "steps_per_env": 8, "minibatch_size": 16}
        if algo == "ppo"
        else {"batch_size": 16, "buffer_size": 1000}
    )
    cfg = make_config(algo, "paper", hidden=(32, 16), **sizes)

    def run(distribution):
        monkeypatch.setattr(networks, "BoundedTanhNormal", distribution)
        env = make_env("compound", 4, seed=0)
        torch.manual_seed(0)
        agent = make_agent(cfg, 12, env.action_spec[0], 30.0)
        with torch.no_grad():
            data = env.rollout(8, agent.actor, break_when_any_done=False)
        assert isinstance(agent.actor.get_dist(data[:, 0]), distribution)
        torch.manual_seed(1)
        agent.learn(data.clone(), **({} if algo == "ppo" else {"num_updates": 3}))
        collected = [data[key] for key in ("action", "action_log_prob") if key in data.keys()]
        assert len(collected) == (2 if algo == "ppo" else 1)
        return collected + [p.detach().clone() for p in agent.loss.parameters()]

    ours, theirs = run(BoundedTanhNormal), run(TanhNormal)
    assert len(ours) == len(theirs)
    for a, b in zip(ours, theirs, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)


@pytest.mark.parametrize("algo", ["sac", "td3", "ppo"])
def test_averaged_actor_follows_the_live_one_by_its_decay(algo):
    """``actor_average``: after each actor step the averaged weights move ``1 - decay`` of the
    way to the live actor's (which the optimiser trains); the agent evaluates and checkpoints
    the averaged actor."""
    env = make_env("no_noise", 4, seed=0)
    spec, decay = env.action_spec[0], 0.75
    extra = {"batch_size": 16, "buffer_size": 1000, "policy_delay": 2} if algo == "td3" else {}
    if algo == "sac":
        extra = {"batch_size": 16, "buffer_size": 1000}
    if algo == "ppo":
        extra = {"epochs": 1, "minibatch_size": 80}
    cfg = make_config(algo, "paper", hidden=(16,), actor_average=decay, **extra)
    agent = make_agent(cfg, 6, spec, 30.0)
    assert agent.policy is agent.averaged and agent.averaged is not agent.actor
    if algo == "ppo":  # PPO learns from its own rollout (log-probabilities)
        with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
            data = env.rollout(20, agent.exploration_policy, break_when_any_done=False)
    else:
        data = env.rollout(20, break_when_any_done=False)
        agent.learn(data, num_updates=0)
    names = [k for k, _ in agent.actor.named_parameters()]
    expected = {k: v.clone() for k, v in agent.averaged.named_parameters()}
    for _ in range(3):
        before = {k: v.clone() for k, v in agent.actor.named_parameters()}
        if algo == "ppo":
            agent.learn(data)  # one epoch of one minibatch: one actor step
        else:  # TD3: the actor steps on every second update
            agent.learn(data[:, :1], num_updates=2 if algo == "td3" else 1)
        live = dict(agent.actor.named_parameters())
        assert any(not torch.equal(before[k], live[k]) for k in names), "the live actor learns"
        for k in names:
            expected[k] = decay * expected[k] + (1 - decay) * live[k].detach()
        for k, v in agent.averaged.named_parameters():
            torch.testing.assert_close(v, expected[k])
    # a checkpoint carries it
    other = make_agent(cfg, 6, spec, 30.0)
    other.load_state_dict(agent.state_dict())
    for (k, v), (_, w) in zip(
        agent.averaged.named_parameters(), other.averaged.named_parameters(), strict=True
    ):
        assert torch.equal(v, w), k
    with pytest.raises(ValueError, match="actor_average"):
        make_config(algo, "paper", actor_average=1.0).validate()


def test_ppo_refuses_a_number_of_updates():
    """PPO's updates are its epochs over minibatches of a collection: a ``num_updates`` (the
    off-policy agents' count) is refused rather than ignored."""
    env = make_env("noise", 2, seed=0)
    cfg = make_config("ppo", "paper", hidden=(8,), num_envs=2, steps_per_env=4, minibatch_size=8)
    agent = make_agent(cfg, 6, env.action_spec[0], 30.0)
    with pytest.raises(ValueError, match="no num_updates"):
        agent.learn(env.rollout(4, agent.actor, break_when_any_done=False), num_updates=1)
