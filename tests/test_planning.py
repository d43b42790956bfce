"""The simulator-state API of DockingEnv and the privileged planner built on it."""

import pytest
import torch

from dockingrl.env import DockingConfig, DockingEnv
from dockingrl.evaluation import base_env, run_episodes
from dockingrl.planning import PlannerConfig, PlannerPolicy
from dockingrl.scenarios import make_env


def random_state(env, generator):
    """Advance ``env`` a few random steps so that its PID memory is not zero."""
    td = env.reset()
    for _ in range(5):
        td["action"] = torch.rand(env.num_envs, 2, generator=generator) * 1.6 - 0.6
        td = env.step(td)["next"]
    return td


def test_get_state_and_set_state_restore_the_simulation():
    env = DockingEnv(8, config=DockingConfig(noise=False), seed=3)
    random_state(env, torch.Generator().manual_seed(0))
    saved = env.get_state()
    action = torch.full((8, 2), 0.2)
    first = env.step(saved.empty().set("action", action))
    env.set_state(saved)
    second = env.step(saved.empty().set("action", action))
    torch.testing.assert_close(first["next", "true_state"], second["next", "true_state"])
    torch.testing.assert_close(first["next", "reward"], second["next", "reward"])
    assert int(second["next", "step_count"][0]) == int(saved["step_count"][0]) + 1


def test_simulate_is_the_env_step_without_noise():
    env = DockingEnv(64, config=DockingConfig(noise=False), seed=5)
    generator = torch.Generator().manual_seed(1)
    random_state(env, generator)
    state = env.get_state()
    action = torch.rand(64, 2, generator=generator) * 2.0 - 1.0  # some outside the bounds
    next_state, out = env.simulate(state, action)
    td = env.step(state.empty().set("action", action))["next"]
    torch.testing.assert_close(
        torch.cat((next_state["pose"], next_state["velocity"]), -1), td["true_state"]
    )
    for key in ("reward", "terminated", "success", "contact_score", "contact_speed"):
        torch.testing.assert_close(out[key], td[key])
    after = env.get_state()  # the env moved with its step, not with simulate
    for key in DockingEnv.STATE_KEYS:
        torch.testing.assert_close(after[key], next_state[key])


def test_set_state_refuses_an_incomplete_or_misshaped_state():
    env = DockingEnv(4, seed=0)
    env.reset()
    state = env.get_state()
    with pytest.raises(KeyError, match="integral"):
        env.set_state(state.exclude("integral"))
    with pytest.raises(ValueError, match="batch size"):
        env.set_state(state[:2])
    state["pose"][0, 0] = float("nan")
    with pytest.raises(ValueError, match="pose"):
        env.set_state(state)


def test_planner_docks_from_near_the_station():
    config = PlannerConfig(horizon=8, samples=32, iterations=2, elites=4, seed=0)
    env = make_env("no_noise", 2, seed=0)
    base_env(env).set_initial_state(
        pose=torch.tensor([[-5.0, 1.5, 0.3], [-6.0, -2.0, -0.5]]),
        ocean_current=torch.tensor([[0.1, -0.1], [-0.1, 0.15]]),
    )
    out = run_episodes(PlannerPolicy(config), env)
    assert out["success"].all(), out
    assert (out["contact_speed"] <= 0.3).all()


def test_planner_needs_its_env_and_a_valid_config():
    with pytest.raises(RuntimeError, match="bind_env"):
        PlannerPolicy()(make_env("no_noise", 1).reset())
    with pytest.raises(ValueError, match="elites"):
        PlannerConfig(samples=8, elites=9)
    with pytest.raises(ValueError, match="horizon"):
        PlannerConfig(horizon=0)
