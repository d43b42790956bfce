"""Bad input to the config, the batched env and the Gymnasium env: refused in one clear line;
every accepted config stays finite; ``check_finite`` names where a NaN appears."""

import dataclasses
import json
import math

import gymnasium
import numpy as np
import pytest
import torch
from tensordict import TensorDict

import dockingrl  # noqa: F401  (registers the gymnasium id)
from dockingrl import DockingConfig, DockingEnv
from dockingrl.agents.config import make_config
from dockingrl.env.config import BOUNDS
from dockingrl.env.dynamics import pid_thrust, velocity_update
from dockingrl.filter_learning import mismatched_config
from dockingrl.recipes import load_recipe, recipe_names
from dockingrl.scenarios import make_env
from dockingrl.training import env_kwargs, training_draws


def refusal(call, *args, kind=ValueError, **kwargs) -> str:
    with pytest.raises(kind) as info:
        call(*args, **kwargs)
    message = str(info.value)
    assert "\n" not in message
    return message


# -- DockingConfig ---------------------------------------------------------------------------
NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize(
    "field, value",
    [
        ("dt", 1e3),  # the EKF's covariance went NaN from step 32
        ("dt", 0.6),
        ("dt", 0.0),
        ("dt", -0.1),
        ("dt", 1e-6),
        ("bearing_noise", 1e40),  # inf observations from step 0
        ("bearing_noise", 1.0),
        ("range_noise_fraction", 1e6),  # negative ranges
        ("range_noise_fraction", 1e40),
        ("range_noise_fraction", 0.2),
        ("range_noise_fraction", -0.01),
        ("heading_noise", 4.0),
        ("velocity_noise", 2.0),
        ("velocity_noise", -1.0),
        ("yaw_rate_noise", 1e6),
        ("mass", 0.0),
        ("mass", -60.0),
        ("mass", 1e40),
        ("yaw_inertia", 0.0),
        ("linear_damping", -1.0),
        ("quadratic_damping", 1e40),
        ("max_thrust", 0.0),
        ("max_thrust", 1e40),
        ("max_acceleration", 1e3),
        ("max_velocity", 0.0),
        ("surge_kp", -1.0),
        ("surge_ki", 1e40),
        ("yaw_kd", 1e7),
        ("ocean_current_range", (-10.0, 10.0)),
        ("init_x", (-1e6, -25.0)),
        ("init_heading", (-4.0, 0.0)),
        ("max_steps", 0),
        ("max_steps", 10**7),
        ("max_dist", 1e-300),
        ("thrust_weight", 0.0),
        ("contact_weight", 0.0),
    ],
)
def test_out_of_range_config_value_is_refused_naming_field_range_and_value(field, value):
    message = refusal(DockingConfig, **{field: value})
    assert message.startswith(f"DockingConfig.{field}: ")
    assert BOUNDS[field].describe() in message
    assert message.endswith(f"(got {value!r})")


@pytest.mark.parametrize(
    "field, value, why",
    [
        ("dt", NAN, "must be finite"),
        ("dt", INF, "must be finite"),
        ("velocity_noise", NAN, "must be finite"),
        ("init_y", (0.0, NAN), "must be finite"),
        ("dt", "0.2", "must be a number"),
        ("mass", True, "must be a number"),
        ("max_steps", 2.5, "must be an integer"),
        ("max_steps", True, "must be an integer"),
        ("noise", "yes", "must be True or False"),
        ("init_x", [-30.0, -25.0], "must be a (low, high) tuple of two numbers"),
        ("dock_y", (-0.5, 0.0, 0.5), "must be a (low, high) tuple of two numbers"),
    ],
)
def test_malformed_config_value_is_refused(field, value, why):
    message = refusal(DockingConfig, **{field: value})
    assert message.startswith(f"DockingConfig.{field}: {why}")
    assert message.endswith(f"(got {value!r})")


@pytest.mark.parametrize(
    "changes, field, inertia",
    [
        ({"mass": 1.0}, "surge_kp", "mass"),  # the paper's gains on a 1 kg vehicle
        ({"yaw_kd": 100.0}, "yaw_kp", "yaw_inertia"),
        ({"dt": 0.5, "surge_kp": 300.0}, "surge_kp", "mass"),
    ],
)
def test_a_diverging_pid_loop_is_refused(changes, field, inertia):
    message = refusal(DockingConfig, **changes)
    assert message.startswith(f"DockingConfig.{field}: ")
    assert "spectral radius" in message and inertia in message


def unchecked(**changes) -> DockingConfig:
    """The paper's config with ``changes`` that validation would refuse."""
    config = DockingConfig()
    for name, value in changes.items():
        object.__setattr__(config, name, value)
    return config


@pytest.mark.parametrize(
    "config",
    [DockingConfig(quadratic_damping=0.0), unchecked(dt=0.8, quadratic_damping=0.0)],
    ids=["settles", "diverges"],
)
def test_velocity_loop_radius_is_the_simulated_loop_growth(config):
    """The env's own PID and velocity step, unclipped and with linear damping only, shrink or
    grow an error by the radius per step."""
    kp = torch.tensor([config.surge_kp, config.yaw_kp], dtype=torch.float64)
    ki = torch.tensor([config.surge_ki, config.yaw_ki], dtype=torch.float64)
    kd = torch.tensor([config.surge_kd, config.yaw_kd], dtype=torch.float64)
    inertia = torch.tensor([config.mass, config.mass, config.yaw_inertia], dtype=torch.float64)
    velocity = torch.tensor([[1.0, 0.0, 1.0]], dtype=torch.float64)
    integral, error = torch.zeros(1, 2, dtype=torch.float64), torch.zeros(1, 2, dtype=torch.float64)
    norms = []
    for _ in range(400):
        error_now = -velocity[:, 0::2]
        tau, integral = pid_thrust(error_now, integral, error, kp, ki, kd, config.dt, 1e300)
        error = error_now
        tau3 = torch.stack((tau[:, 0], torch.zeros(1, dtype=torch.float64), tau[:, 1]), -1)
        velocity = velocity_update(
            velocity, tau3, inertia, config.linear_damping, 0.0, 1e300, 1e300, config.dt
        )
        norms.append(float(torch.linalg.vector_norm(torch.cat((velocity, integral), -1))))
    growth = (norms[-1] / norms[199]) ** (1 / 200)
    assert growth == pytest.approx(config.velocity_loop_radius("surge"), rel=1e-3)


def test_paper_values_and_the_repos_configs_are_accepted():
    paper = DockingConfig()
    assert paper.velocity_loop_radius("surge") < 0.96
    for scale in (2.0, 3.0, 4.0):  # the filter ablation's and the tests' mismatches
        mismatched_config(scale)
        paper.scale_usbl_noise(scale, scale)
    DockingConfig(ocean_current_range=(-1e-6, 1e-6))
    DockingConfig(
        init_x=(-3.0, -2.0),
        init_y=(-0.5, 0.5),
        ocean_current_range=(-0.02, 0.02),
        dock_y=(50.0, 50.5),
        max_steps=20_000,
    )
    DockingConfig(init_y=(-7.5, 5.0), max_steps=np.int64(7), contact_speed_tolerance=0.05)
    DockingConfig(surge_ki=0.0, yaw_ki=0.0)
    DockingConfig(surge_kp=0.0, yaw_kp=0.0)
    for name in recipe_names():
        cfg = load_recipe(name).make_config()
        training_draws(cfg, env_kwargs(cfg)["config"])
    # the paper's values lie well inside: any one of them doubled or halved is accepted
    for field in dataclasses.fields(DockingConfig):
        value = getattr(paper, field.name)
        if field.name in ("noise", "vehicle"):
            continue
        for factor in (2, 0.5):
            if isinstance(value, tuple):
                paper.replace(**{field.name: tuple(v * factor for v in value)})
            else:
                paper.replace(**{field.name: type(value)(value * factor)})


@pytest.mark.parametrize(
    "range_scale, bearing_scale, named",
    [(1e6, 1.0, "range_scale"), (-1.0, 1.0, "range_scale"), (1.0, 31.0, "bearing_scale")],
)
def test_usbl_noise_scale_out_of_bounds_is_refused(range_scale, bearing_scale, named):
    message = refusal(DockingConfig().scale_usbl_noise, range_scale, bearing_scale)
    assert message.startswith(f"DockingConfig.scale_usbl_noise: {named} must lie in [0, ")


@pytest.mark.parametrize(
    "field, value, why",
    [
        ("range_noise_scale", 1e6, "must lie in [0, 5] so that range_noise_fraction"),
        ("range_noise_scale", -1.0, "must lie in [0, 5]"),
        ("bearing_noise_scale", 31.0, "must lie in [0, 30] so that bearing_noise"),
        ("bearing_noise_scale", NAN, "must be finite"),
    ],
)
def test_train_config_noise_scales_are_bounded(field, value, why):
    message = refusal(make_config, "ppo", **{field: value})
    assert message.startswith(f"PPOConfig.{field}: {why}")
    make_config("ppo", **{field: 4.0})


def test_a_train_config_of_a_wrong_type_is_refused_before_training():
    """A field of the wrong type is refused when the config is made, not when the trained
    policy is saved; ``train`` takes a config and nothing else."""
    said = refusal(load_recipe("sac").make_config, total_steps=200.0)
    assert said == "sac option total_steps: expected <class 'int'>, got 200.0"
    said = refusal(make_config, "ppo", lr="0.1")
    assert said == "ppo option lr: expected <class 'float'>, got '0.1'"
    for bad in (None, {"algo": "ppo"}):
        said = refusal(dockingrl.train, bad, kind=TypeError)
        assert said.startswith("train takes a TrainConfig") and type(bad).__name__ in said


def test_a_resumed_run_with_a_bad_saved_value_names_its_config_file(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    cfg = make_config("ppo").to_dict()
    (run / "config.json").write_text(json.dumps({**cfg, "lr": -1.0}))
    said = refusal(dockingrl.train, None, resume=run)
    assert said.startswith(f"{run / 'config.json'}: PPOConfig.lr")


# -- DockingEnv ------------------------------------------------------------------------------
def test_num_envs_any_positive_integral():
    assert DockingEnv(np.int64(4), seed=0).batch_size == torch.Size([4])
    assert type(DockingEnv(np.int32(2), seed=0).num_envs) is int
    for bad, kind in ((True, TypeError), (2.5, TypeError), ("4", TypeError), (None, TypeError)):
        assert "num_envs must be a positive integer" in refusal(DockingEnv, bad, kind=kind)
    for bad in (0, -1, np.int64(0)):
        assert "num_envs must be a positive integer" in refusal(DockingEnv, bad)


def test_env_builders_refuse_a_wrong_config_device_or_filter_params_in_one_line():
    """What the command line checks for itself is checked for the Python API too, before a
    foreign library's error could say it less clearly."""
    for build in (make_env, lambda s, **kw: gymnasium.make("dockingrl/Docking-v0", **kw)):
        for bad in ("paper.yaml", {"dt": 0.2}):
            said = refusal(build, "noise", config=bad, kind=TypeError)
            assert said.startswith(f"config must be a DockingConfig, got {type(bad).__name__}")
    assert refusal(make_env, "noise", device="gpu") == "not a torch device: 'gpu'"
    assert refusal(DockingEnv, 2, device="tpu") == "not a torch device: 'tpu'"
    if not torch.cuda.is_available():
        said = refusal(make_env, "noise", device="cuda")
        assert said == "'cuda': CUDA is not available on this machine"
    said = refusal(make_env, "filtered", filter_params=3, kind=TypeError)
    assert said == "filter_params must be a file path or the payload read from one, got int"


def test_batched_env_refuses_bad_actions_in_one_line():
    env = DockingEnv(3, seed=0)
    td = env.reset()
    td["action"] = torch.tensor([[0.1, 0.0], [0.1, 0.0], [NAN, 0.0]])
    assert "batch entry 2 (flattened) is [nan, 0.0]" in refusal(env.step, td)
    td["action"] = torch.zeros(3, 2, dtype=torch.bool)
    assert "real-valued tensor, got dtype torch.bool" in refusal(env.step, td)
    td["action"] = torch.zeros(3, 2, dtype=torch.complex64)
    assert "got dtype torch.complex64" in refusal(env.step, td)
    td["action"] = torch.zeros(3, 1)
    assert "must have shape (3, 2)" in refusal(env.step, td)
    assert "torch.Tensor" in refusal(env._validated_action, [[0.1, 0.0]] * 3, kind=TypeError)


def step_zero(env, td, steps):
    for _ in range(steps):
        td["action"] = torch.zeros(env.num_envs, 2)
        td = env.step(td)["next"]
    return td


def test_check_finite_names_the_entry_env_and_step():
    env = DockingEnv(3, seed=0, check_finite=True)
    td = step_zero(env, env.reset(), 5)
    state = env.get_state()
    state["pose"][1, 0] = 3e38  # finite, but its range overflows
    env.set_state(state)
    message = refusal(step_zero, env, td, 1, kind=FloatingPointError)
    assert message.startswith("DockingEnv check_finite: 'observation' is not finite after step ")
    assert "in env 1 at its step 6: [nan," in message

    # the same state without the check goes on silently
    quiet = DockingEnv(3, seed=0)
    td = step_zero(quiet, quiet.reset(), 5)
    quiet.set_state(state)
    assert torch.isnan(step_zero(quiet, td, 1)["observation"][1, 0])

    env = DockingEnv(2, seed=0, check_finite=True, config=unchecked(mass=1e-46))  # 0 in float32
    message = refusal(step_zero, env, env.reset(), 3, kind=FloatingPointError)
    assert "'true_state' is not finite after step in env 0 at its step 1" in message

    env = DockingEnv(2, seed=0, check_finite=True, config=unchecked(bearing_noise=1e40))
    message = refusal(env.reset, kind=FloatingPointError)
    assert "'observation' is not finite after reset in env 0 at its step 0" in message


def test_check_finite_changes_no_number():
    runs = []
    for check in (False, True):
        env = DockingEnv(8, seed=4, check_finite=check)
        torch.manual_seed(0)
        runs.append(env.rollout(50, break_when_any_done=False))
    assert (runs[0] == runs[1]).all()


EXTREMES = {
    "largest dt and noise": DockingConfig(
        dt=BOUNDS["dt"].high,
        range_noise_fraction=BOUNDS["range_noise_fraction"].high,
        bearing_noise=BOUNDS["bearing_noise"].high,
        heading_noise=BOUNDS["heading_noise"].high,
        velocity_noise=BOUNDS["velocity_noise"].high,
        yaw_rate_noise=BOUNDS["yaw_rate_noise"].high,
        ocean_current_range=BOUNDS["ocean_current_range"][:2],
        max_steps=300,
    ),
    "smallest dt, fast light vehicle": DockingConfig(
        dt=BOUNDS["dt"].low,
        mass=BOUNDS["mass"].low,
        yaw_inertia=BOUNDS["yaw_inertia"].low * 100,
        max_velocity=BOUNDS["max_velocity"].high,
        max_acceleration=BOUNDS["max_acceleration"].high,
        max_thrust=BOUNDS["max_thrust"].high,
        linear_damping=0.0,
        quadratic_damping=0.0,
        surge_kp=1.0,
        yaw_kp=1.0,
        surge_ki=BOUNDS["surge_ki"].high,
        yaw_ki=BOUNDS["yaw_ki"].high,
        range_noise_fraction=BOUNDS["range_noise_fraction"].high,
        max_steps=2000,
    ),
    "heaviest vehicle, largest dt": DockingConfig(
        dt=BOUNDS["dt"].high,
        mass=BOUNDS["mass"].high,
        yaw_inertia=BOUNDS["yaw_inertia"].high,
        surge_kp=2e5,
        yaw_kp=BOUNDS["yaw_kp"].high,
        yaw_kd=BOUNDS["yaw_kd"].high,
        linear_damping=BOUNDS["linear_damping"].high,
        max_thrust=BOUNDS["max_thrust"].high,
        max_dist=BOUNDS["max_dist"].low,
        thrust_weight=BOUNDS["thrust_weight"].low,
        approach_distance=BOUNDS["approach_distance"].low,
        contact_weight=BOUNDS["contact_weight"].high,
        max_steps=300,
    ),
}


@pytest.mark.parametrize("name", list(EXTREMES))
def test_extreme_accepted_configs_stay_finite_over_long_random_rollouts(name):
    """2,000 steps of random, half of them saturating, actions with ``check_finite`` on (it
    raises at the first NaN or inf), episodes ending and restarting in place."""
    config, n = EXTREMES[name], 64
    env = DockingEnv(n, config=config, seed=1, check_finite=True)
    gen = torch.Generator().manual_seed(2)
    td, ended, lowest_range = env.reset(), 0, math.inf
    for _ in range(2000):
        td["action"] = (torch.rand(n, 2, generator=gen) * 4 - 2) * 0.8  # twice the box
        td = env._step(td)
        lowest_range = min(lowest_range, float(td["observation"][:, 0].min()))
        if td["done"].any():
            ended += int(td["done"].sum())
            td = env._reset(TensorDict({"_reset": td["done"]}, batch_size=[n]))
    assert ended >= n  # every env's episode ended at least once
    assert lowest_range >= 0  # no negative range reading


def test_filter_stays_finite_at_the_largest_dt_and_noise():
    env = make_env("compound", 64, seed=3, config=EXTREMES["largest dt and noise"])
    rollout = env.rollout(400, break_when_any_done=False)
    for key in ("ekf_cov", "filtered_observation", "observation", "reward"):
        assert bool(torch.isfinite(rollout["next", key]).all()), key


# -- Gymnasium env ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "action, said",
    [
        (np.zeros((1, 2)), "got shape (1, 2)"),
        (np.zeros((2, 1)), "got shape (2, 1)"),
        (np.zeros(3), "got shape (3,)"),
        ([0.1, 0.0, 0.0], "got shape (3,)"),
        (0.5, "got shape ()"),
        (None, "got None"),
        (np.array([True, False]), "got dtype bool of shape (2,)"),
        (np.array([0.1 + 0j, 0.0]), "got dtype complex128 of shape (2,)"),
        ("ab", "got dtype <U2 of shape ()"),
        (["0.1", "0.0"], "got dtype <U3 of shape (2,)"),
        ([[0.1], [0.0, 0.1]], "got a ragged [[0.1], [0.0, 0.1]]"),
        ([NAN, 0.0], "got [nan, 0.0]"),
        ([0.1, -INF], "got [0.1, -inf]"),
    ],
)
def test_gym_env_refuses_bad_actions_in_one_line(action, said):
    env = gymnasium.make("dockingrl/Docking-v0", fast=False).unwrapped
    env.reset(seed=0)
    message = refusal(env.step, action)
    assert message.startswith("action must be a finite real action of shape (2,) [v_d, w_d], ")
    assert message.endswith(said)


def test_gym_env_clips_any_finite_action_and_takes_lists_and_tuples():
    low, high = DockingConfig().action_low, DockingConfig().action_high
    results = {}
    for name, action in {
        "array": np.array(high, dtype=np.float32),
        "huge float64": np.array([1e300, 1e300]),
        "list": [5.0, 1.0],
        "tuple of ints": (3, 2),
    }.items():
        env = gymnasium.make("dockingrl/Docking-v0", fast=False).unwrapped
        env.reset(seed=5)
        env.step(action)
        results[name] = env._td["true_state"]
    for name, state in results.items():
        assert torch.equal(state, results["array"]), name
    env = gymnasium.make("dockingrl/Docking-v0", fast=False).unwrapped
    env.reset(seed=5)
    env.step(np.array([-1e300, -1e300]))
    applied = env._env.get_state()["previous_error"]  # the command minus the start's rest
    assert applied.tolist() == [[np.float32(low[0]), np.float32(low[1])]]
    assert math.isfinite(env.step([0.1, 0.0])[1])
