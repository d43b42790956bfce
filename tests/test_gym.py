"""The Gymnasium envs (single and vector), their rendering and videos, and stable-baselines3
training and evaluation through them."""

import warnings

import gymnasium
import imageio.v2 as imageio
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode
from PIL import Image, ImageSequence
from torchrl.envs.utils import step_mdp

import dockingrl
from dockingrl import DockingConfig, make_env
from dockingrl.gym import DockingScenarioEnv, DockingVectorEnv
from dockingrl.render import write_video
from dockingrl.transforms import EKFTransform

ID = "dockingrl/Docking-v0"
SCENARIOS = ("no_noise", "noise", "filtered", "compound")


def _random_actions(count, seed=0):
    rng = np.random.default_rng(seed)  # beyond the bounds too: both envs clip
    return rng.uniform([-0.6, -0.5], [1.0, 0.5], size=(count, 2)).astype(np.float32)


def _step_for_step(env, reference, seed, steps):
    """Run the Gymnasium ``env`` and the TorchRL ``reference`` (one env) side by side with the
    same seed and actions, through episode ends; every output must be equal."""
    obs, info = env.reset(seed=seed)
    td = reference.reset()
    np.testing.assert_array_equal(obs, td["observation"][0].numpy())
    ends = 0
    for k, action in enumerate(_random_actions(steps, seed)):
        obs, reward, terminated, truncated, info = env.step(action)
        td["action"] = torch.from_numpy(action).reshape(1, 2)
        nxt = reference.step(td)["next"]
        np.testing.assert_array_equal(obs, nxt["observation"][0].numpy(), err_msg=f"step {k}")
        assert obs.dtype == np.float32 and obs in env.observation_space
        assert reward == float(nxt["reward"])
        assert (terminated, truncated) == (bool(nxt["terminated"]), bool(nxt["truncated"]))
        np.testing.assert_array_equal(info["true_state"], nxt["true_state"][0].numpy())
        assert info["success"] == bool(nxt["success"])
        if terminated or truncated:
            ends += 1
            obs, _ = env.reset()
            td = reference.reset()
            np.testing.assert_array_equal(obs, td["observation"][0].numpy())
        else:
            td = step_mdp(td)
    return ends


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_same_numbers_as_make_env_step_for_step(scenario):
    short = DockingConfig(max_steps=60)  # episode ends and resets within the run
    env = gymnasium.make(ID, scenario=scenario, config=short, fast=False)
    ends = _step_for_step(env, make_env(scenario, 1, seed=11, config=short), 11, 200)
    assert ends >= 3


@pytest.mark.parametrize("vehicle", ["fossen", "mixed"])
@pytest.mark.parametrize("scenario", ["noise", "compound"])
def test_the_fossen_vehicle_steps_as_make_env_steps_it(scenario, vehicle):
    """``vehicle=`` flies the Fossen vehicle (or either per episode) through the batched env's
    own step: the same numbers as the TorchRL pipeline, and a vector env of it too."""
    short = DockingConfig(max_steps=60, vehicle=vehicle)
    env = gymnasium.make(ID, scenario=scenario, config=short)
    assert not env.unwrapped.fast
    ends = _step_for_step(env, make_env(scenario, 1, seed=11, config=short), 11, 200)
    assert ends >= 3
    paper = gymnasium.make(ID, scenario=scenario, config=short.replace(vehicle="paper"))
    ours, theirs = env.reset(seed=4)[0], paper.reset(seed=4)[0]
    np.testing.assert_array_equal(ours, theirs)  # the same start; the vehicles then differ
    action = np.array([0.8, 0.3], dtype=np.float32)
    for _ in range(10):
        ours, theirs = env.step(action)[0], paper.step(action)[0]
    if vehicle == "fossen":
        assert np.abs(ours - theirs).max() > 1e-3
    vec = gymnasium.make_vec(ID, num_envs=3, scenario=scenario, vehicle=vehicle)
    obs, _ = vec.reset(seed=2)
    assert obs.shape == (3, env.observation_space.shape[0])
    assert vec.unwrapped.config.vehicle == vehicle
    with pytest.raises(ValueError, match="step the paper's model only"):
        gymnasium.make(ID, scenario=scenario, vehicle=vehicle, fast=True)


def test_same_numbers_with_every_option(tmp_path):
    ekf = EKFTransform()
    with torch.no_grad():
        ekf.measurement_noise.log_std.add_(0.3)  # a learned R, not Table 2's
    ekf.save_filter_params(tmp_path / "filter.pt")
    options = dict(
        observe_current=True,
        observe_command=True,
        observe_filter_std=True,
        filter_params=str(tmp_path / "filter.pt"),
    )
    env = gymnasium.make(
        ID,
        fast=False,
        scenario="compound",
        range_noise_scale=2.0,
        bearing_noise_scale=1.5,
        following_current_fraction=1.0,
        lateral_current_fraction=0.5,
        near_start_fraction=1.0,
        config=DockingConfig(max_steps=80),
        **options,
    )
    config = (
        DockingConfig(max_steps=80)
        .scale_usbl_noise(2.0, 1.5)
        .replace(
            following_current_fraction=1.0, lateral_current_fraction=0.5, near_start_fraction=1.0
        )
    )
    reference = make_env("compound", 1, seed=3, config=config, **options)
    assert env.observation_space.shape == (18,)
    _step_for_step(env, reference, 3, 160)
    obs, info = env.reset(seed=4)
    assert info["true_state"][0] > -8.5  # the near start box
    assert info["ocean_current"][0] >= 0  # a following current


def test_the_current_estimating_filter_and_its_error_observed_give_the_pipelines_numbers():
    options = dict(
        ekf_kwargs={"estimate_current": True},
        observe_current=True,
        observe_current_error=True,
        config=DockingConfig(max_steps=80),
    )
    env = gymnasium.make(ID, scenario="filtered", **options)
    assert not env.unwrapped.fast  # the fast path runs the paper's filter only
    reference = make_env("filtered", 1, seed=3, **options)
    assert env.observation_space.shape == (10,)
    _step_for_step(env, reference, 3, 120)
    with pytest.raises(ValueError, match="CurrentEstimatingEKF does not support compile=True"):
        gymnasium.make(ID, scenario="filtered", compile=True, **options)


def test_observation_spaces_and_dtypes():
    shapes = {"no_noise": 6, "noise": 6, "filtered": 6, "compound": 12}
    for scenario, size in shapes.items():
        env = gymnasium.make(ID, scenario=scenario)
        assert env.observation_space.shape == (size,)
        assert env.observation_space.dtype == np.float32
        assert env.action_space.dtype == np.float32
        np.testing.assert_array_equal(env.action_space.low, np.float32([-0.4, -0.3]))
    space = gymnasium.make(
        ID, scenario="filtered", observe_current=True, observe_command=True
    ).observation_space
    low, high = space.low, space.high
    assert low[0] == 0 and high[0] == np.inf and high[1] == high[2] == np.float32(np.pi)
    assert np.isinf(low[3:6]).all()
    assert 0.3 <= high[6] < 0.3 + 1e-6 and -0.3 - 1e-6 < low[7] <= -0.3  # the current
    np.testing.assert_array_equal(high[8:], np.float32([0.8, 0.3]))  # the previous command
    # every observation of a batch under strong lateral currents stays in the box
    vec = DockingVectorEnv(512, "compound", observe_current=True, lateral_current_fraction=1.0)
    obs, _ = vec.reset(seed=0)
    for action in _random_actions(40):
        assert obs in vec.observation_space
        obs, *_ = vec.step(np.tile(action, (512, 1)))


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_gymnasium_check_env(scenario):
    env = gymnasium.make(ID, scenario=scenario)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env.unwrapped)


def test_refusals_are_one_clear_line():
    with pytest.raises(ValueError, match="render_mode must be None, 'human' or 'rgb_array'"):
        DockingScenarioEnv("noise", render_mode="video")
    with pytest.raises(ValueError, match="unknown scenario 'noisy'"):
        gymnasium.make(ID, scenario="noisy")
    env = gymnasium.make(ID).unwrapped
    with pytest.raises(ValueError, match="reset options must be a mapping with keys among pose"):
        env.reset(options={"start": (0, 0, 0)})
    with pytest.raises(ValueError, match=r"options\['pose'\] must be \(x, y, alpha\), 3 finite"):
        env.reset(options={"pose": (0.0, 1.0)})
    with pytest.raises(ValueError, match=r"must lie in ocean_current_range \[-0.3, 0.3\] m/s"):
        env.reset(options={"ocean_current": (0.5, 0.0)})
    vec = DockingVectorEnv(4)
    vec.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(4, 2\) \[v_d, w_d\], got shape \(2,\)"):
        vec.step(np.zeros(2))
    with pytest.raises(ValueError, match=r"env 2 got \[nan, 0.0\]"):
        vec.step(np.array([[0, 0], [0, 0], [np.nan, 0], [0, 0]]))
    with pytest.raises(ValueError, match="seed must be an int or None"):
        vec.reset(seed=[1, 2, 3, 4])
    with pytest.raises(ValueError, match="autoreset_mode must be one of 'NextStep', 'SameStep'"):
        DockingVectorEnv(2, autoreset_mode="Disabled")
    # a constructor seed would be overwritten by the first reset: refused, for both envs
    for make in (lambda: gymnasium.make(ID, seed=5), lambda: DockingVectorEnv(2, seed=5)):
        with pytest.raises(
            ValueError, match=r"seeded by reset\(seed=...\), not by its constructor"
        ):
            make()
    # the realism options leave the observation space (a believed current beyond the range)
    from dockingrl.env.levels import level_config

    with pytest.raises(ValueError, match="steps the paper's task, on either vehicle"):
        DockingVectorEnv(2, "compound", observe_current=True, config=level_config("L5"))


@pytest.mark.parametrize("fast", [False, True])
def test_a_step_after_the_episode_ends_or_after_close_needs_a_reset(fast):
    """Stepping on past a terminal step would go on adding the docked reward: refused until
    the next reset, as is a step of a closed env."""
    env = DockingScenarioEnv("no_noise", fast=fast)
    env.reset(seed=0, options={"pose": (-3.0, 0.0, 0.0), "ocean_current": (0.0, 0.0)})
    steps, terminated, truncated = 0, False, False
    while not (terminated or truncated):
        _, _, terminated, truncated, _ = env.step(np.array([0.8, 0.0]))
        steps += 1
    assert terminated and steps < 100
    with pytest.raises(RuntimeError, match=r"the episode has ended .*: call reset\(\)"):
        env.step(np.array([0.8, 0.0]))
    env.reset(seed=1)
    env.step(np.array([0.8, 0.0]))  # a new episode steps again
    env.close()
    with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
        env.step(np.array([0.8, 0.0]))


def test_reset_options_pin_the_start():
    env = gymnasium.make(ID, scenario="noise").unwrapped
    _, info = env.reset(seed=0, options={"pose": (-20.0, 3.0, 0.5), "ocean_current": (0.1, -0.2)})
    np.testing.assert_allclose(info["true_state"][:3], [-20.0, 3.0, 0.5], rtol=1e-6)
    np.testing.assert_allclose(info["ocean_current"], [0.1, -0.2], rtol=1e-6)
    _, info = env.reset()  # the pin held for one episode only
    assert info["true_state"][0] <= -25.0


# -- vector env ------------------------------------------------------------------------------
def test_make_vec_is_the_batched_env_with_the_same_numbers_as_make_env():
    vec = gymnasium.make_vec(
        ID, num_envs=8, vectorization_mode="vector_entry_point", scenario="compound"
    )
    assert isinstance(vec, DockingVectorEnv)
    assert vec.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert vec.observation_space.shape == (8, 12) and vec.action_space.shape == (8, 2)
    assert isinstance(gymnasium.make_vec(ID, num_envs=2), DockingVectorEnv)  # the default
    reference = make_env("compound", 8, seed=5)
    obs, info = vec.reset(seed=5)
    td = reference.reset()
    np.testing.assert_array_equal(obs, td["observation"].numpy())
    assert info["_success"].all() and info["true_state"].shape == (8, 6)
    rng = np.random.default_rng(0)
    for _ in range(30):  # no episode ends this early
        actions = rng.uniform(-0.5, 0.9, size=(8, 2)).astype(np.float32)
        obs, reward, terminated, truncated, info = vec.step(actions)
        td["action"] = torch.from_numpy(actions)
        td = reference.step(td)
        np.testing.assert_array_equal(obs, td["next", "observation"].numpy())
        np.testing.assert_array_equal(reward, td["next", "reward"].reshape(-1).double().numpy())
        assert reward.dtype == np.float64 and terminated.dtype == truncated.dtype == bool
        td = step_mdp(td)
    # a batch of one gives the single env's numbers
    single = gymnasium.make(ID, scenario="compound", fast=False)
    one = DockingVectorEnv(1, "compound")
    np.testing.assert_array_equal(single.reset(seed=9)[0], one.reset(seed=9)[0][0])
    action = np.float32([0.5, 0.1])
    np.testing.assert_array_equal(single.step(action)[0], one.step(action[None])[0][0])


def test_next_step_autoreset():
    config = DockingConfig(max_steps=5)
    twins = [DockingVectorEnv(4, "noise", config=config) for _ in range(2)]
    for vec in twins:
        vec.reset(seed=1)
        for _ in range(2):
            vec.step(np.full((4, 2), 0.3))
        vec.reset(options={"reset_mask": np.array([True, True, False, False])})
        for _ in range(2):
            vec.step(np.full((4, 2), 0.3))
    results = [vec.step(np.full((4, 2), 0.3)) for vec in twins]  # the 5th step of envs 2-3
    _, _, terminated, truncated, info = results[0]
    assert truncated.tolist() == [False, False, True, True] and not terminated.any()
    assert info["step_count"].tolist() == [3, 3, 5, 5]
    # the next step: envs 2-3 start over (their actions ignored), envs 0-1 step on
    results = [vec.step(np.full((4, 2), a)) for vec, a in zip(twins, (0.3, -0.4), strict=True)]
    (obs_a, reward, terminated, truncated, info), (obs_b, *_) = results
    assert info["step_count"].tolist() == [4, 4, 0, 0]
    np.testing.assert_array_equal(reward[2:], 0.0)
    assert reward[0] != 0 and not (terminated | truncated).any()
    np.testing.assert_array_equal(obs_a[2:], obs_b[2:])  # the action was ignored
    assert not np.array_equal(obs_a[:2], obs_b[:2])
    _, _, _, truncated, info = twins[0].step(np.full((4, 2), 0.3))
    assert info["step_count"].tolist() == [5, 5, 1, 1]
    assert truncated.tolist() == [True, True, False, False]
    _, _, _, truncated, info = twins[0].step(np.full((4, 2), 0.3))
    assert info["step_count"].tolist() == [0, 0, 2, 2] and not truncated.any()


def test_same_step_autoreset_keeps_the_final_observation():
    config = DockingConfig(max_steps=3)
    same = DockingVectorEnv(3, "filtered", config=config, autoreset_mode="SameStep")
    nxt = DockingVectorEnv(3, "filtered", config=config)
    assert same.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    for vec in (same, nxt):
        vec.reset(seed=2)
        for _ in range(2):
            vec.step(np.full((3, 2), 0.2))
    obs, _, _, truncated, info = same.step(np.full((3, 2), 0.2))
    last, *_ = nxt.step(np.full((3, 2), 0.2))
    assert truncated.all() and info["_final_obs"].all() and info["_final_info"].all()
    np.testing.assert_array_equal(np.stack(info["final_obs"]), last)
    assert info["final_info"]["step_count"].tolist() == [3, 3, 3]
    assert info["step_count"].tolist() == [0, 0, 0]  # obs: the new episodes' first
    assert not np.array_equal(obs, last)


# -- rendering -------------------------------------------------------------------------------
def test_rgb_array_frames_follow_the_vehicle(tmp_path):
    env = gymnasium.make(ID, scenario="compound", render_mode="rgb_array")
    env.reset(seed=0, options={"pose": (-20.0, 0.0, 0.0), "ocean_current": (0.0, 0.2)})
    first = env.render()
    assert first.shape == (400, 640, 3) and first.dtype == np.uint8
    for _ in range(25):
        env.step(np.float32([0.8, 0.0]))
    moved = env.render()
    changed = (first != moved).any(-1)
    assert changed.mean() > 0.003
    # the vehicle (blue) moved right: its pixels' mean column grew
    blue = (moved[..., 2] > 150) & (moved[..., 0] < 80)
    blue_first = (first[..., 2] > 150) & (first[..., 0] < 80)
    assert np.nonzero(blue)[1].mean() > np.nonzero(blue_first)[1].mean() + 10
    human = gymnasium.make(ID, render_mode="human")
    human.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert human.render() is None
    human.close()


def test_write_video_gif_and_mp4(tmp_path):
    def forward(td):
        return td.set("action", torch.tensor([[0.8, 0.0]]).expand(td.batch_size[0], 2))

    config = DockingConfig(max_steps=12)
    path = write_video(
        forward, "noise", tmp_path / "a.gif", episodes=2, every=4, fps=5, config=config
    )
    frames = imageio.mimread(path)
    # per episode: steps 0, 4, 8 and the last (12), held for a second
    assert len(frames) == 2 * 4 and frames[0].shape[:2] == (400, 640)
    with Image.open(path) as gif:
        durations = [frame.info["duration"] for frame in ImageSequence.Iterator(gif)]
    assert durations == [200, 200, 200, 1000] * 2
    mp4 = write_video(forward, "noise", tmp_path / "a.mp4", episodes=1, every=6, config=config)
    assert mp4.stat().st_size > 1000
    with pytest.raises(ValueError, match="the suffix must be one of .gif, .mp4"):
        write_video(forward, "noise", tmp_path / "a.avi")


def test_a_track_has_one_pose_per_decision_with_action_repeat(tmp_path):
    """With ``action_repeat`` 4, a 12-step episode is 3 decisions: its track has 4 poses, the
    last one where the episode ended, and the video's clock counts env steps."""
    from dockingrl.evaluation import episode_record, run_episodes

    def forward(td):
        return td.set("action", torch.tensor([[0.8, 0.0]]).expand(td.batch_size[0], 2))

    config = DockingConfig(max_steps=12)
    env = make_env("noise", 2, seed=0, config=config, action_repeat=4)
    outcomes = run_episodes(forward, env, record_trajectories=True)
    record = episode_record(outcomes, 0, config)
    assert len(record["path"]) == 4 and record["time_s"] == pytest.approx(12 * config.dt)
    assert record["path"][-1] == outcomes["end"][0].tolist()
    assert record["path"][0] == outcomes["start"][0].tolist()


def test_eval_writes_a_video_and_refuses_a_bad_suffix_first(tmp_path, capsys):
    from dockingrl.cli import main

    path = tmp_path / "run.gif"
    assert main(["eval", "--episodes", "2", "--video", str(path), "--video-episodes", "1"]) == 0
    assert len(imageio.mimread(path)) > 2
    with pytest.raises(SystemExit, match="--video a.avi: the suffix must be one of .gif, .mp4"):
        main(["eval", "--episodes", "2", "--video", "a.avi"])


# -- stable-baselines3 -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def sb3():
    """stable-baselines3 (the ``dev`` extra); its tests alone are skipped without it."""
    return pytest.importorskip("stable_baselines3")


def _train(algo, env, steps, **kwargs):
    torch.manual_seed(0)
    model = algo(
        "MlpPolicy", env, seed=0, device="cpu", policy_kwargs={"net_arch": [16, 16]}, **kwargs
    )
    return model.learn(steps)


@pytest.mark.parametrize("vectorised", [False, True])
def test_sb3_ppo_trains_and_evaluates_through_dockingrl(sb3, vectorised):
    from dockingrl.gym.sb3 import SB3Policy, SB3VecEnv

    if vectorised:
        env = SB3VecEnv(16, "compound", config=DockingConfig(max_steps=50))
        model = _train(sb3.PPO, env, 2048, n_steps=64, batch_size=256, n_epochs=2)
        assert model.num_timesteps == 2048
    else:
        env = gymnasium.make(ID, scenario="compound")
        model = _train(sb3.PPO, env, 512, n_steps=256, batch_size=128, n_epochs=2)
    policy = SB3Policy(model)
    config = DockingConfig(max_steps=150)
    metrics = dockingrl.evaluate(policy, "compound", 1, seed=21, config=config)
    # the same episode in the single Gymnasium env, with SB3's own predict
    single = gymnasium.make(ID, scenario="compound", config=config, fast=False)
    obs, _ = single.reset(seed=21)
    total, done, steps = 0.0, False, 0
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = single.step(action)
        total += reward
        steps += 1
        done = terminated or truncated
    assert metrics["episodes"] == 1 and metrics["success_rate"] == 100.0 * info["success"]
    assert metrics["total_reward"]["mean"] == pytest.approx(total, rel=1e-5)
    assert metrics["time_all_s"]["mean"] == pytest.approx(steps * 0.2)
    assert steps > 1


@pytest.mark.parametrize("vectorised", [False, True])
def test_sb3_sac_trains(sb3, vectorised):
    from stable_baselines3.common.vec_env import VecMonitor

    from dockingrl.gym.sb3 import SB3Policy, SB3VecEnv

    if vectorised:
        env = VecMonitor(SB3VecEnv(8, "compound", config=DockingConfig(max_steps=40)))
        steps = 1600
    else:
        env = gymnasium.make(ID, scenario="compound", config=DockingConfig(max_steps=40))
        steps = 500
    model = _train(sb3.SAC, env, steps, learning_starts=100, batch_size=64)
    assert model.num_timesteps >= steps and model.replay_buffer.size() > 0
    assert len(model.ep_info_buffer) >= 10  # episodes of 40 steps ended and were logged
    metrics = dockingrl.evaluate(SB3Policy(model), "compound", 4, seed=0)
    assert metrics["episodes"] == 4


def test_sb3_vec_env_reports_episode_ends(sb3):
    from dockingrl.gym.sb3 import SB3VecEnv

    env = SB3VecEnv(4, "noise", config=DockingConfig(max_steps=3))
    with pytest.raises(ValueError, match=r"seed must be an integer in \[0, 2\*\*63\), got -1"):
        env.seed(-1)
    with pytest.raises(TypeError, match="seed must be an integer, got float"):
        env.seed(1.5)
    env.seed(7)
    first = env.reset()
    again = SB3VecEnv(4, "noise", config=DockingConfig(max_steps=3))
    again.seed(7)
    np.testing.assert_array_equal(first, again.reset())
    for _ in range(2):
        _, _, done, infos = env.step(np.zeros((4, 2), np.float32))
        assert not done.any() and infos == [{}] * 4
    obs, reward, done, infos = env.step(np.zeros((4, 2), np.float32))
    assert done.all() and reward.dtype == np.float32
    for i, info in enumerate(infos):
        assert info["TimeLimit.truncated"] is True and info["is_success"] is False
        assert info["terminal_observation"].shape == (6,)
        assert not np.array_equal(info["terminal_observation"], obs[i])
