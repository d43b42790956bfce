"""The simulator-state API of DockingEnv and the privileged planner built on it."""

import pytest
import torch
from torchrl.envs.utils import step_mdp

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


def test_set_state_and_simulate_refuse_bad_input():
    env = DockingEnv(4, seed=0)
    env.reset()
    state = env.get_state()
    with pytest.raises(KeyError, match="integral"):
        env.set_state(state.exclude("integral"))
    with pytest.raises(ValueError, match="batch size"):
        env.set_state(state[:2])
    for key, value, match in (
        ("pose", torch.zeros(4, 2), "shape"),
        ("step_count", torch.zeros(4, dtype=torch.int64), "shape"),
        ("step_count", torch.zeros(4, 1), "integers"),
        ("step_count", torch.full((4, 1), -1), "integers"),
        ("velocity", torch.full((4, 3), float("nan")), "finite"),
    ):
        bad = state.clone()
        bad.set(key, value) if value.shape == bad[key].shape else bad.__setitem__(key, value)
        with pytest.raises(ValueError, match=match):
            env.set_state(bad)
    with pytest.raises(ValueError, match="NaN"):
        env.simulate(state, torch.full((4, 2), float("nan")))
    with pytest.raises(ValueError, match="shape"):
        env.simulate(state, torch.zeros(4, 3))


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


def test_planner_docks_from_the_filter_estimate_in_the_noisy_world():
    config = PlannerConfig(horizon=8, samples=32, iterations=2, elites=4, seed=0, state="filter")
    env = make_env("compound", 2, seed=0)
    base_env(env).set_initial_state(
        pose=torch.tensor([[-5.0, 1.5, 0.3], [-6.0, -2.0, -0.5]]),
        ocean_current=torch.tensor([[0.1, -0.1], [-0.1, 0.15]]),
    )
    assert run_episodes(PlannerPolicy(config), env)["success"].all()
    with pytest.raises(KeyError, match="filtered or compound"):
        run_episodes(PlannerPolicy(config), make_env("noise", 1, seed=0))
    with pytest.raises(ValueError, match="state"):
        PlannerConfig(state="oracle")


def test_planner_needs_its_env_and_a_valid_config():
    with pytest.raises(RuntimeError, match="bind_env"):
        PlannerPolicy()(make_env("no_noise", 1).reset())
    with pytest.raises(ValueError, match="elites"):
        PlannerConfig(samples=8, elites=9)
    with pytest.raises(ValueError, match="elites"):
        PlannerConfig(samples=8, elites=1)  # one elite has no spread
    with pytest.raises(ValueError, match="horizon"):
        PlannerConfig(horizon=0)
    with pytest.raises(ValueError, match="speed_margin"):
        PlannerConfig(speed_margin=0.4)
    with pytest.raises(ValueError, match="action_repeat"):
        PlannerPolicy().bind_env(make_env("no_noise", 1, action_repeat=4))


def bound_planner(pose, current, **config):
    env = make_env("no_noise", len(pose), seed=0)
    base_env(env).set_initial_state(pose=torch.tensor(pose), ocean_current=torch.tensor(current))
    planner = PlannerPolicy(PlannerConfig(**{"samples": 4, "elites": 2, **config}))
    planner.bind_env(env)
    return env, planner


def test_rollout_cost_ends_at_contact_and_at_the_entrance_plane():
    # 0: 0.15 m in front of the box, already moving in at 0.2 m/s; 1: beside the station, carried
    # past its entrance plane by a following current
    env, planner = bound_planner(
        [[-0.95, 0.0, 0.0], [-0.3, 2.0, 0.0]], [[0.0, 0.0], [0.3, 0.0]], horizon=5
    )
    env.reset()
    state = env.get_state()
    state["velocity"][0, 0] = 0.2
    candidates = torch.zeros(2, 3, 5, 2)  # 0 in [-1, 1] units: 0.2 m/s, no turn
    candidates[:, 1, 1:] = 1.0  # differ only after contact (within the first command): ...
    candidates[:, 2, 1:, 1] = -1.0  # ... full surge, or a hard turn
    cost = planner.rollout_cost(state, candidates)
    assert float(cost[0, 0]) < -1000  # a successful contact
    torch.testing.assert_close(cost[0], cost[0, :1].expand(3))  # commands after it are moot
    assert float(cost[1].min()) >= planner.config.passed_penalty  # passed beside the funnel
    # with a margin of 0.15 m/s the 0.2 m/s contact no longer counts as a success in the plan
    planner.config = planner.config.replace(speed_margin=0.15)
    assert float(planner.rollout_cost(state, candidates)[0, 0]) > 1000


def test_planner_replans_every_hold_steps_and_stops_for_ended_episodes():
    env, planner = bound_planner(
        [[-1.6, 0.0, 0.0], [-20.0, 3.0, 0.5]], [[0.0, 0.0], [0.0, 0.0]], horizon=6, hold=3
    )
    calls = []
    plan = planner.plan

    def counting_plan(state, mean):
        calls.append(state.batch_size[0])
        return plan(state, mean)

    planner.plan = counting_plan
    actions, done = [], []
    with torch.no_grad():
        td = env.reset()
        for _ in range(24):
            td = planner(td)
            actions.append(td["action"].clone())
            td = step_mdp(env.step(td), keep_other=True)
            done.append(bool(td["done"][0]))
    actions = torch.stack(actions)
    for start in range(0, 24, 3):  # each command held for 3 steps
        torch.testing.assert_close(actions[start : start + 3], actions[start].expand(3, 2, 2))
    assert len(calls) == 8 and calls[0] == 2  # one plan per 3 steps
    assert any(done), "the first vehicle should have docked"
    ended = done.index(True)
    assert calls[-1] == 1 and all(b == 1 for b in calls[ended // 3 + 1 :])
