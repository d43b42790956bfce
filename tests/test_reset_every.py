"""``reset_every``: SAC and TD3 put their networks back to their built weights, the replay
buffer kept."""

import pytest
import torch
from helpers import tiny_config

from dockingrl.agents import make_agent
from dockingrl.agents.config import make_config
from dockingrl.agents.off_policy import OffPolicyAgent, resets_before
from dockingrl.scenarios import make_env
from dockingrl.training import Trainer, train


def _agent(algo, **options):
    env = make_env("no_noise", 4, seed=0)
    cfg = make_config(algo, "paper", hidden=(32, 16), batch_size=16, buffer_size=1000, **options)
    cfg.validate()
    torch.manual_seed(0)
    return env, make_agent(cfg, 6, env.action_spec[0], 30.0)


def _equal(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize(
    ("algo", "paths"),
    [
        ("sac", {}),
        ("sac", {"fast_update": True}),
        ("td3", {}),
        ("td3", {"fast_update": True}),
    ],
)
def test_a_reset_restores_the_built_weights_and_keeps_the_buffer(algo, paths):
    learned = {"learn_alpha": True} if algo == "sac" else {}
    env, agent = _agent(algo, reset_every=1000, **paths, **learned)
    built = {k: v.clone() for k, v in agent.loss.state_dict().items()}
    actor = {k: v.clone() for k, v in agent.actor.state_dict().items()}
    agent.learn(env.rollout(20, break_when_any_done=False), num_updates=4)
    trained = agent.loss.state_dict()
    assert not _equal(trained, built)
    assert all(o.state for o in agent.optimizers.values())
    stored, updates = len(agent.replay_buffer), agent.updates

    agent.reset_networks()
    # the actor, the critics, their targets (and SAC's learned temperature) as built, the
    # actor that collects and is saved included; no moments; the buffer and the count kept
    assert _equal(agent.loss.state_dict(), built)
    assert _equal(agent.actor.state_dict(), actor)
    assert not any(o.state for o in agent.optimizers.values())
    assert (len(agent.replay_buffer), agent.updates) == (stored, updates)
    # and it trains on from there, on the same tensors (compiled or fused paths stay valid)
    agent.learn(env.rollout(5, break_when_any_done=False), num_updates=2)
    after = agent.loss.state_dict()
    assert all(torch.isfinite(v).all() for v in after.values())
    assert not _equal(after, built)


def test_without_reset_every_an_agent_refuses_to_reset():
    _, agent = _agent("sac")
    assert "built" not in agent.extra
    with pytest.raises(ValueError, match="reset_every > 0"):
        agent.reset_networks()


@pytest.mark.parametrize(
    ("frames", "batch", "expected"),
    [
        (1000, 1000, False),  # the first batch ends at 1,000 < 2,000
        (2000, 1000, True),  # 2,000 falls within (1,000, 2,000]
        (3000, 1000, False),
        (4500, 1000, True),  # 4,000 within (3,500, 4,500]
        (6000, 1000, False),  # the run's last batch: no reset before the end
    ],
)
def test_resets_fall_on_multiples_of_reset_every_before_the_last_batch(frames, batch, expected):
    cfg = make_config("sac", "paper", reset_every=2000, total_steps=6000)
    assert resets_before(cfg, frames, batch) is expected
    assert resets_before(make_config("sac", "paper"), frames, batch) is False


@pytest.mark.parametrize(
    ("options", "says"),
    [
        ({"reset_every": -1}, "reset_every: must be >= 0"),
        ({"reset_every": 1000, "actor_average": 0.99}, "reset_every: cannot go with actor_average"),
    ],
)
def test_impossible_resets_are_refused(options, says):
    with pytest.raises(ValueError, match=f"SACConfig.{says}"):
        make_config("sac", "paper", **options).validate()


def test_a_run_resets_at_its_multiples_and_a_resumed_run_builds_the_same_weights(
    tmp_path, short_episodes, monkeypatch
):
    """The training loop resets before the batches that cross a multiple of ``reset_every``
    (not before its last one); a Trainer built again from the run's config (as ``--resume``
    builds it) holds the same built weights, so a reset after a resume is the same reset."""
    cfg = tiny_config("sac", "noise", tmp_path, reset_every=150)
    seen = []
    original = OffPolicyAgent.reset_networks

    def record(self):
        seen.append(self.updates)
        original(self)

    monkeypatch.setattr(OffPolicyAgent, "reset_networks", record)
    result = train(cfg, progress=False)
    # batches of 100 env steps up to 400: 150 falls in (100, 200], 300 in (200, 300]; the
    # batch ending at 400 is the last; updates start at 100 env steps, half a one per step
    assert seen == [0, 50]
    assert result["summary"]["frames"] == cfg.total_steps
    again = [Trainer(cfg, tmp_path / f"again{i}", progress=False).agent for i in range(2)]
    assert _equal(*(a.extra["built"] for a in again))
