import math

import gymnasium
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from torchrl.envs.utils import check_env_specs

import dockingrl  # noqa: F401  (registers the gymnasium id)
from dockingrl.env import DockingConfig, DockingEnv, contact_score, observation_from_state
from dockingrl.env.dynamics import pose_from_observation, wrap_angle
from dockingrl.env.reward import distance_reward, entry_velocity_reward, thrust_reward


def set_state(env, pose, velocity=(0.0, 0.0, 0.0), current=(0.0, 0.0)):
    """Place every env of ``env`` at the given state (after a reset)."""
    n = env.num_envs
    env._pose = torch.tensor(pose, dtype=env.dtype).expand(n, 3).clone()
    env._velocity = torch.tensor(velocity, dtype=env.dtype).expand(n, 3).clone()
    env._current = torch.tensor(current, dtype=env.dtype).expand(n, 2).clone()


def step(env, td, action):
    td["action"] = torch.as_tensor(action, dtype=env.dtype).expand(env.num_envs, 2).clone()
    return env.step(td)["next"]


@pytest.mark.parametrize("num_envs", [1, 64])
@pytest.mark.parametrize("noise", [True, False])
def test_check_env_specs(num_envs, noise):
    check_env_specs(DockingEnv(num_envs, config=DockingConfig(noise=noise), seed=0))


def random_rollout(seed, steps=120, num_envs=8):
    env = DockingEnv(num_envs, seed=seed)
    gen = torch.Generator().manual_seed(123)
    td = env.reset()
    out = []
    for _ in range(steps):
        td["action"] = env.action_spec.low + torch.rand(num_envs, 2, generator=gen) * (
            env.action_spec.high - env.action_spec.low
        )
        td_out, td = env.step_and_maybe_reset(td)
        out.append(td_out["next"].clone())
    return torch.stack(out, dim=1)


def test_a_seed_beyond_the_generators_is_one_line():
    env = DockingEnv(1)
    for seed in (2**70, -1):
        with pytest.raises(ValueError, match=r"seed must be an integer in \[0, 2\*\*63\)"):
            env.set_seed(seed)
    with pytest.raises(TypeError, match="seed must be an integer, got float"):
        env.set_seed(1.5)


def test_same_seed_gives_identical_rollouts():
    a, b = random_rollout(seed=7), random_rollout(seed=7)
    for key in ("observation", "true_state", "reward", "ocean_current", "done"):
        assert torch.equal(a[key], b[key]), key
    c = random_rollout(seed=8)
    assert not torch.equal(a["observation"], c["observation"])


def test_partial_reset_changes_only_masked_envs():
    env = DockingEnv(5, seed=3)
    td = env.reset()
    for _ in range(10):
        td = step(env, td, (0.5, 0.1))
    before = td.clone()
    velocity_before = env._velocity.clone()
    mask = torch.tensor([False, True, False, False, True]).unsqueeze(-1)
    td["_reset"] = mask
    after = env.reset(td)
    keep = ~mask.squeeze(-1)
    for key in ("true_state", "ocean_current", "observation", "step_count"):
        assert torch.equal(after[key][keep], before[key][keep]), key
        assert not torch.equal(after[key][~keep], before[key][~keep]), key
    assert (after["step_count"][~keep] == 0).all()
    assert (after["step_count"][keep] == 10).all()
    # the hidden state of the kept envs is untouched too; the reset ones start at rest
    assert torch.equal(env._velocity[keep], velocity_before[keep])
    assert (env._velocity[~keep] == 0).all()


def test_contact_score_hand_computed():
    x = torch.tensor([-0.5, -0.5, -0.5, -0.5, -0.3])
    y = torch.tensor([0.0, 0.3, 0.3, 0.3, -0.2])
    alpha = torch.tensor([0.0, 0.0, 1.0, -1.0, 0.2])
    g = contact_score(x, y, alpha)
    a0 = math.atan2(0.3, -0.5) - math.pi  # eq. 7, = -0.5404 rad
    a0b = math.atan2(-0.2, -0.3) + math.pi  # eq. 7 wrapped into (-pi, pi], = +0.5880 rad
    expected = [
        1.0,  # perfect entry on the axis, heading straight in
        1 - 1.0 * abs(0 - a0) * (1 + abs(a0)),  # e > 0, y > 0: w_1
        1 - 1.0 * abs(1 - a0) * (1 + abs(a0)),  # e > 0, y > 0: w_1, too steep
        1 - 3.05 * abs(-1 - a0) * (1 + abs(a0)),  # e < 0, y > 0: w_2
        1 - 1.0 * abs(0.2 - a0b) * (1 + abs(a0b)),  # e < 0, y < 0: w_1
    ]
    torch.testing.assert_close(g, torch.tensor(expected), rtol=0, atol=1e-5)
    assert g[0] == 1.0
    assert g[2] <= 0 and g[3] <= 0, "steep or wrong-side entries miss the funnel"
    assert 0 < g[1] < 1


def test_reward_terms_hand_computed():
    assert distance_reward(torch.tensor(15.0), 30.0) == -0.5
    assert torch.isclose(thrust_reward(torch.tensor([30.0, 40.0]), 100.0), torch.tensor(-0.5))
    # inside d_appro: -w_vel * (V - v_max) * (d_appro - rho) / d_appro
    r = entry_velocity_reward(torch.tensor(0.5), torch.tensor(1.0), 0.3, 3.0, 10.0)
    assert torch.isclose(r, torch.tensor(-10 * 0.2 * 2 / 3))
    assert entry_velocity_reward(torch.tensor(0.5), torch.tensor(3.5), 0.3, 3.0, 10.0) == 0
    assert entry_velocity_reward(torch.tensor(0.2), torch.tensor(1.0), 0.3, 3.0, 10.0) == 0


def test_contact_step_reward_success_and_speed():
    cfg = DockingConfig(noise=False)
    env = DockingEnv(2, config=cfg, seed=0)
    td = env.reset()
    # at cruise through the water, zero PID error so tau = 0, dead ahead of the funnel
    set_state(env, pose=(-0.82, 0.0, 0.0), velocity=(0.2, 0.0, 0.0))
    env._velocity[1, 0] = 0.5  # the second one arrives too fast
    td["action"] = torch.tensor([[0.2, 0.0], [0.5, 0.0]])
    out = env.step(td)["next"]
    k = cfg.linear_damping * 0.2 + cfg.quadratic_damping * 0.04
    u = 0.2 - cfg.dt * k / cfg.mass  # eqs. 36-37 with tau = 0
    x = -0.82 + u * cfg.dt  # eq. 38
    assert out["terminated"].all() and out["done"].all() and not out["truncated"].any()
    assert torch.isclose(out["true_state"][0, 0], torch.tensor(x))
    assert out["contact_score"][0, 0] == 1.0
    assert torch.isclose(out["contact_speed"][0, 0], torch.tensor(u))
    expected = -abs(x) / 30.0 + 200.0  # r_dist + r_g; r_tau = 0, r_entry_vel = 0 below 0.3
    assert torch.isclose(out["reward"][0, 0], torch.tensor(expected), atol=1e-5)
    assert out["success"][0, 0] and not out["success"][1, 0]
    assert out["contact_speed"][1, 0] > cfg.entry_speed_max
    # the fast one pays thrust and the entry-speed penalty of eq. 6 on top of r_dist and r_g
    assert out["reward"][1, 0] < -abs(out["true_state"][1, 0]) / 30.0 + 200.0


def test_truncation_after_max_steps():
    cfg = DockingConfig(max_steps=7)
    env = DockingEnv(3, config=cfg, seed=0)
    td = env.reset()
    for i in range(7):
        td = step(env, td, (0.0, 0.0))
        assert td["truncated"].all() == (i == 6)
    assert not td["terminated"].any() and td["done"].all() and not td["success"].any()
    assert (td["step_count"] == 7).all()


def test_noise_free_observation_equals_true_geometry():
    env = DockingEnv(256, config=DockingConfig(noise=False), seed=1)
    td = env.reset()
    for _ in range(20):
        td = step(env, td, (0.6, 0.2))
    x, y, alpha, u, v, r = td["true_state"].unbind(-1)
    oc = td["ocean_current"]
    obs = td["observation"]
    torch.testing.assert_close(obs[:, 0], torch.hypot(x, y))
    bearing = torch.atan2(-y, -x) - alpha
    torch.testing.assert_close(torch.cos(obs[:, 1]), torch.cos(bearing))
    torch.testing.assert_close(torch.sin(obs[:, 1]), torch.sin(bearing))
    torch.testing.assert_close(obs[:, 2], alpha)
    # DVL: velocity over ground in the body frame
    ground_x = torch.cos(alpha) * u - torch.sin(alpha) * v + oc[:, 0]
    ground_y = torch.sin(alpha) * u + torch.cos(alpha) * v + oc[:, 1]
    torch.testing.assert_close(obs[:, 3], torch.cos(alpha) * ground_x + torch.sin(alpha) * ground_y)
    torch.testing.assert_close(
        obs[:, 4], -torch.sin(alpha) * ground_x + torch.cos(alpha) * ground_y
    )
    torch.testing.assert_close(obs[:, 5], r)
    # and the pose is recovered from it
    torch.testing.assert_close(
        pose_from_observation(obs), td["true_state"][:, :3], atol=1e-4, rtol=0
    )


def test_noise_statistics_match_table_2():
    cfg = DockingConfig()
    env = DockingEnv(40_000, config=cfg, seed=2)
    td = env.reset()
    td = step(env, td, (0.5, 0.2))
    x, y, alpha, u, v, r = td["true_state"].double().unbind(-1)
    true = observation_from_state(x, y, alpha, u, v, r, td["ocean_current"].double())
    residual = td["observation"].double() - true
    residual[:, 1:3] = wrap_angle(residual[:, 1:3])
    residual[:, 0] /= true[:, 0]  # the range noise is relative
    std = residual.std(dim=0)
    expected = torch.tensor(cfg.observation_noise_std, dtype=torch.float64)
    # 40,000 samples: the sample std is within 1 % of sigma with ~4 sigma confidence
    torch.testing.assert_close(std, expected, rtol=0.02, atol=0)
    assert (residual.mean(dim=0).abs() < 4 * expected / math.sqrt(40_000)).all()


def test_step_response_matches_first_order_model():
    """The chosen PID gains and yaw inertia follow eq. 24 (k = 2.5 1/s) within the actuator's
    linear range (|tau| = kp * step <= 40 N): RMS error over 8 s under 5 % of the step, peak
    error under 8 %, settled within 1 %. Larger steps saturate the thrust (40 N / 60 kg)."""
    cfg = DockingConfig(noise=False)
    env = DockingEnv(2, config=cfg, seed=0)
    steps = torch.tensor([[0.25, 0.2], [-0.25, -0.25]])
    td = env.reset()
    set_state(env, pose=(-200.0, 0.0, 0.0))
    measured, model = [], []
    reference = torch.zeros(2, 2)
    for _ in range(40):
        td["action"] = steps
        td = env.step(td)["next"]
        measured.append(env._velocity[:, 0::2].clone())
        reference = reference + 2.5 * cfg.dt * (steps - reference)  # eq. 24, Euler as the EKF
        model.append(reference.clone())
    measured, model = torch.stack(measured), torch.stack(model)
    error = (measured - model) / steps.abs()
    assert error.pow(2).mean(0).sqrt().max() < 0.05
    assert error.abs().max() < 0.08
    assert error[-1].abs().max() < 0.01


def test_bad_actions():
    env = DockingEnv(3, seed=0)
    td = env.reset()
    for bad in (float("nan"), float("inf")):
        td["action"] = torch.tensor([[0.1, 0.0], [bad, 0.0], [0.1, 0.0]])
        with pytest.raises(ValueError, match="NaN or inf"):
            env.step(td)
    with pytest.raises(ValueError, match=r"\(3, 2\)"):
        env._validated_action(torch.zeros(3, 3))


def test_out_of_bound_actions_are_clipped():
    a, b = DockingEnv(2, seed=5), DockingEnv(2, seed=5)
    ta, tb = a.reset(), b.reset()
    oa = step(a, ta, (5.0, -9.0))
    ob = step(b, tb, (0.8, -0.3))
    assert torch.equal(oa["true_state"], ob["true_state"])


@pytest.mark.parametrize(
    "field, value",
    [
        ("dt", -0.1),
        ("max_steps", 0),
        ("init_x", (-25.0, -30.0)),
        ("mass", 0.0),
        ("velocity_noise", -1.0),
        ("surge_command_min", 1.0),
        ("max_dist", float("nan")),
        ("following_current_fraction", 1.5),
        ("lateral_current_fraction", -0.1),
        ("near_start_fraction", 2.0),
    ],
)
def test_impossible_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        DockingConfig(**{field: value})


def test_bad_constructor_arguments():
    with pytest.raises(ValueError, match="num_envs"):
        DockingEnv(0)
    with pytest.raises(TypeError, match="DockingConfig"):
        DockingEnv(1, config={"dt": 0.1})


def test_pinned_starts_of_a_wrong_shape_are_one_line_errors():
    env = DockingEnv(4, seed=0)
    for value, shape in [(torch.zeros(2), "(2,)"), (torch.zeros(3, 3), "(3, 3)")]:
        with pytest.raises(ValueError) as err:
            env.set_initial_state(pose=value)
        assert str(err.value) == f"pose must be (4, 3) or (3,), got {shape}"
    with pytest.raises(ValueError, match="ocean_current must be finite"):
        env.set_initial_state(ocean_current=torch.tensor([float("nan"), 0.0]))
    # one start for every env; a current beyond the training range may be pinned
    env.set_initial_state(pose=torch.tensor([20.0, 0.0, 0.1]), ocean_current=torch.tensor([0.5, 0]))
    td = env.reset()
    assert torch.equal(env._current, torch.tensor([[0.5, 0.0]] * 4, dtype=env.dtype))
    assert td["observation"].shape == (4, 6)


def test_gymnasium_registration_and_checker():
    env = gymnasium.make("dockingrl/Docking-v0", fast=False)
    check_env(env.unwrapped)
    obs, info = env.reset(seed=3)
    assert obs.shape == (6,) and obs.dtype == np.float32
    obs2, _ = env.reset(seed=3)
    np.testing.assert_array_equal(obs, obs2)
    # step for step the batched env of one vehicle with the same seed
    reference = DockingEnv(1, seed=3)
    td = reference.reset()
    np.testing.assert_array_equal(obs, td["observation"][0].numpy())
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(np.array([0.5, 0.0], np.float32))
        td = reference.step(td.set("action", torch.tensor([[0.5, 0.0]])))["next"].clone()
        np.testing.assert_array_equal(obs, td["observation"][0].numpy())
        assert reward == float(td["reward"][0, 0])
        assert (terminated, truncated) == (bool(td["terminated"]), bool(td["truncated"]))
        done = terminated or truncated
    assert terminated or info["step_count"] == 600
    assert info["step_count"] == int(td["step_count"][0])


def test_following_current_fraction_biases_only_the_training_draw():
    n = 2000
    plain = DockingEnv(n, seed=7).reset()["ocean_current"]
    zero = DockingEnv(n, config=DockingConfig(following_current_fraction=0.0), seed=7).reset()
    torch.testing.assert_close(zero["ocean_current"], plain)  # 0: Sec. 4.1's stream unchanged
    always = DockingEnv(n, config=DockingConfig(following_current_fraction=1.0), seed=7).reset()
    oc = always["ocean_current"]
    assert bool((oc[:, 0] >= 0).all()) and float(oc[:, 0].max()) <= 0.3
    assert float(oc[:, 0].mean()) == pytest.approx(0.15, abs=0.01)  # uniform on [0, 0.3]
    torch.testing.assert_close(oc[:, 1], plain[:, 1])  # oc_y untouched
    half = DockingEnv(n, config=DockingConfig(following_current_fraction=0.5), seed=7).reset()
    assert float((half["ocean_current"][:, 0] > 0).double().mean()) == pytest.approx(0.75, abs=0.04)


def test_lateral_current_and_near_start_fractions_bias_only_their_draws():
    n = 4000
    plain = DockingEnv(n, seed=7).reset()
    config = DockingConfig(lateral_current_fraction=1.0, near_start_fraction=0.5)
    biased = DockingEnv(n, config=config, seed=7).reset()
    oc, plain_oc = biased["ocean_current"], plain["ocean_current"]
    torch.testing.assert_close(oc[:, 0], plain_oc[:, 0])  # oc_x untouched
    assert float(oc[:, 1].abs().min()) >= 0.15 and float(oc[:, 1].abs().max()) <= 0.3
    torch.testing.assert_close(torch.sign(oc[:, 1]), torch.sign(plain_oc[:, 1]))  # sign kept
    assert float(oc[:, 1].abs().mean()) == pytest.approx(0.225, abs=0.005)  # uniform there
    pose = biased["true_state"][:, :3]
    near = pose[:, 0] > -10.0
    assert float(near.double().mean()) == pytest.approx(0.5, abs=0.03)
    assert float(pose[near, 0].min()) >= -8.0 and float(pose[near, 0].max()) <= -3.0
    assert float(pose[near, 1].abs().max()) <= 3.0
    far = plain["true_state"][~near, :3]
    torch.testing.assert_close(pose[~near], far)  # the other starts are Sec. 4.1's
    torch.testing.assert_close(pose[:, 2], plain["true_state"][:, 2])  # headings as drawn
    with pytest.raises(ValueError, match="near_start_x"):
        DockingConfig(near_start_fraction=0.1, near_start_x=(-3.0, -0.5))
