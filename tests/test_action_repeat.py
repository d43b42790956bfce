"""Holding each action for several steps (``--action-repeat``): the env transform, the onboard
policy and training all count and apply it the same way."""

import pytest
import torch
from helpers import smoke_config, tiny_actor
from tensordict import TensorDict
from torchrl.envs import RewardSum
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from dockingrl import make_env
from dockingrl.agents.config import make_config
from dockingrl.agents.saving import load_policy
from dockingrl.env import DockingConfig
from dockingrl.evaluation import evaluate
from dockingrl.onboard import OnboardPolicy
from dockingrl.training import train
from dockingrl.transforms import ActionRepeat

ENDING_KEYS = ("observation", "ekf_mean", "true_state", "success", "step_count", "contact_speed")


def random_actions(n, steps, seed=1):
    g = torch.Generator().manual_seed(seed)
    low, high = torch.tensor([-0.4, -0.3]), torch.tensor([0.8, 0.3])
    return [low + (high - low) * torch.rand(n, 2, generator=g) for _ in range(steps)]


@pytest.mark.parametrize("repeat", [2, 3])
def test_a_repeated_step_is_the_same_actions_applied_step_by_step(repeat):
    """Reward summed over the held steps (none after an episode ends), the entries of the step
    where it ended (success, step count, final observation, the EKF's estimate), and ``done``
    as soon as one of the held steps ends it; episodes short enough to end mid-repeat."""
    n = 32
    config = DockingConfig(max_steps=40 + 1)  # 41: not a multiple of the repeat
    stepwise = make_env("compound", n, seed=3, config=config, transforms=[RewardSum()])
    held = make_env(
        "compound", n, seed=3, config=config, transforms=[RewardSum()], action_repeat=repeat
    )
    td1, tdk = stepwise.reset(), held.reset()
    torch.testing.assert_close(td1["observation"], tdk["observation"], rtol=0, atol=0)
    done = torch.zeros(n, 1, dtype=torch.bool)
    ended_mid_repeat = 0
    for action in random_actions(n, 100):
        nxt = held.step(tdk.set("action", action))["next"]
        reward, ended = torch.zeros(n, 1), {}
        was_done = done.clone()
        for j in range(repeat):
            step = stepwise.step(td1.set("action", action))["next"]
            live = ~done
            reward += torch.where(live, step["reward"], 0.0)
            for key in (*ENDING_KEYS, "episode_reward"):
                mask = live.reshape(n, *[1] * (step[key].dim() - 1))
                ended[key] = torch.where(mask, step[key], ended.get(key, step[key]))
            if j < repeat - 1:
                ended_mid_repeat += int((step["done"] & live).sum())
            done = done | step["done"]
            td1 = step_mdp(td1.set("next", step))
        live = ~was_done
        assert torch.equal(nxt["done"] & live, done & live)
        torch.testing.assert_close(nxt["reward"][live], reward[live])
        for key, value in ended.items():
            rows = live.squeeze(-1)
            torch.testing.assert_close(nxt[key][rows], value[rows], msg=key)
        if bool(done.all()):
            break
        tdk = step_mdp(tdk.set("next", nxt))
    assert bool(done.all()) and ended_mid_repeat > 0


def test_action_repeat_refuses_bad_values_and_standalone_use():
    for bad in (0, -2, 2.0, True, "3"):
        with pytest.raises(ValueError, match="repeat"):
            ActionRepeat(bad)
        with pytest.raises(ValueError, match="repeat"):
            make_env("noise", 2, action_repeat=bad)
    with pytest.raises(RuntimeError, match="TransformedEnv"):
        ActionRepeat(2)(TensorDict({}, []))
    with pytest.raises(ValueError, match="action_repeat"):
        make_config("sac", "paper", action_repeat=0)


@pytest.mark.parametrize("scenario", ["noise", "compound"])
def test_onboard_policy_holds_its_command_as_the_training_env_did(scenario):
    """The onboard policy fed the readings of every 0.2 s step drives the vehicles along the
    same path as the actor stepping the env with ``action_repeat=3``."""
    n, repeat = 8, 3
    actor = tiny_actor(12 if scenario == "compound" else 6)
    onboard = OnboardPolicy(actor, scenario, action_repeat=repeat)
    held = make_env(scenario, n, seed=5, action_repeat=repeat)
    stepwise = make_env(scenario, n, seed=5)
    tdk, td1 = held.reset(), stepwise.reset()
    decisions, previous = 0, None
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(20):
            action = actor(tdk.select("observation"))["action"]
            tdk = held.step(tdk.set("action", action))
            for j in range(repeat):
                command = onboard.act(td1["observation"][..., :6], td1["ocean_current"])
                if j == 0:
                    torch.testing.assert_close(command, action, rtol=1e-5, atol=1e-6)
                    decisions += 1
                else:
                    assert torch.equal(command, previous)  # held, not recomputed
                previous = command
                td1 = step_mdp(stepwise.step(td1.set("action", command)))
            torch.testing.assert_close(
                td1["true_state"], tdk["next", "true_state"], rtol=1e-5, atol=1e-5
            )
            tdk = step_mdp(tdk)
    assert decisions == 20
    with pytest.raises(ValueError, match="action_repeat"):
        OnboardPolicy(actor, scenario, action_repeat=0)


def test_training_with_action_repeat_counts_env_steps_and_saves_it_with_the_policy(
    tmp_path, short_episodes
):
    repeat = 4
    cfg = smoke_config(
        "sac",
        "compound",
        tmp_path,
        "ar",
        total_steps=768,
        start_steps=192,
        frames_per_batch=192,
        updates_per_step=0.5,
        eval_every=384,
        eval_episodes=3,
        final_eval_episodes=6,
        logger="csv",
        action_repeat=repeat,
    )
    result = train(cfg, progress=False)
    s = result["summary"]
    # env steps are counted, 4 per transition: 4 batches of 48 transitions (12 per env) are
    # 768 env steps, the first 192 of them random
    assert s["frames"] == 768
    assert s["updates"] == int(0.5 * (768 - 192))
    policy, info = load_policy(tmp_path / "ar" / "policy.pt")
    assert info["config"]["action_repeat"] == repeat
    again = evaluate(
        policy, "compound", 6, seed=10_000, action_repeat=repeat, config=short_episodes
    )
    assert again["success_rate"] == result["eval"]["success_rate"]
    assert again["total_reward"] == result["eval"]["total_reward"]
    onboard = OnboardPolicy.from_file(tmp_path / "ar" / "policy.pt")
    assert onboard.step.action_repeat == repeat


def test_exported_onboard_program_holds_its_command_too(tmp_path):
    from dockingrl.onboard import export_onboard

    policy = OnboardPolicy(tiny_actor(12), "compound", action_repeat=3)
    program = torch.export.load(export_onboard(policy, tmp_path / "p.pt2")).module()
    reference = OnboardPolicy(tiny_actor(12), "compound", action_repeat=3)
    env = make_env("compound", 1, seed=7)
    td = env.reset()
    state = policy.initial_state(1)
    commands = []
    for _ in range(7):
        z, current = td["observation"][..., :6], td["ocean_current"]
        command, mean, cov, age = program(z, current, *state)
        torch.testing.assert_close(command, reference.act(z, current), rtol=1e-5, atol=1e-6)
        state = (mean, cov, command, age)
        commands.append(command)
        td = step_mdp(env.step(td.set("action", command)))
    held = [torch.equal(a, b) for a, b in zip(commands[:-1], commands[1:], strict=True)]
    assert held == [True, True, False, True, True, False]
