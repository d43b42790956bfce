"""The realism options of DockingConfig (docs/realism.md): each changes what it should and
nothing else; the EKF's asynchronous, gated update."""

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from dockingrl.env import DockingConfig, DockingEnv
from dockingrl.env.config import BOUNDS
from dockingrl.env.dynamics import observation_from_state, pose_from_observation
from dockingrl.env.realism import limit_thrust
from dockingrl.scenarios import make_env
from dockingrl.transforms.ekf import (
    CHI2_2DOF_999,
    ekf_predict,
    ekf_step,
    ekf_update,
    measurement_covariance,
    measurement_function,
    process_covariance,
    sensor_innovation_distance,
)

DT = 0.2


def run(config: DockingConfig, steps: int, num_envs: int = 8, seed: int = 3) -> TensorDict:
    """A rollout under the same fixed random commands for every config."""
    env = DockingEnv(num_envs, config=config, seed=seed)
    commands = torch.rand(steps, num_envs, 2, generator=torch.Generator().manual_seed(1))
    low, high = torch.tensor(config.action_low), torch.tensor(config.action_high)
    commands = low + (high - low) * commands
    keys = ["observation", "true_state", "ocean_current", "step_count"]
    keys += [k for k in ("sensor_age", "true_ocean_current") if k in env.observation_spec.keys()]
    td = env.reset()
    outs = [td.select(*keys)]
    for t in range(steps):
        td = env.step(td.set("action", commands[t]))["next"]
        outs.append(td.select(*keys))
    return torch.stack(outs, dim=1)


def clean_observation(td: TensorDict) -> torch.Tensor:
    x, y, alpha, u, v, r = td["true_state"].unbind(-1)
    current = td.get("true_ocean_current", td["ocean_current"])
    return observation_from_state(x, y, alpha, u, v, r, current)


# -- config ------------------------------------------------------------------------------
def test_default_config_has_every_option_off_and_no_new_entries():
    config = DockingConfig()
    assert not (config.realistic or config.sensor_timing or config.current_model)
    assert not config.dynamics_mismatch
    keys = set(DockingEnv(2, seed=0).observation_spec.keys())
    assert not keys & {"sensor_age", "true_ocean_current"}
    assert DockingEnv(2, seed=0).vehicle_scales is None


@pytest.mark.parametrize(
    "changes, message",
    [
        (
            {"usbl_period": 0.3},
            "DockingConfig.usbl_period: must be 0 or a whole number of steps of dt = 0.2 s "
            "(got 0.3)",
        ),
        ({"usbl_latency": 6.0}, "DockingConfig.usbl_latency: must lie in [0, 5] s"),
        (
            {"usbl_dropout_burst": 0.5},
            "DockingConfig.usbl_dropout_burst: must be 0 (independent losses) or >= 1 fix",
        ),
        (
            {"usbl_dropout_probability": 0.8, "usbl_dropout_burst": 2.0},
            "DockingConfig.usbl_dropout_burst: bursts this short cannot lose 0.8 of the fixes",
        ),
        ({"usbl_dropout_probability": 1.0}, "DockingConfig.usbl_dropout_probability: must lie"),
        (
            {"current_time_constant": 30.0},
            "DockingConfig.current_time_constant: a varying current needs both",
        ),
        ({"mass_scale": (1.3, 0.7)}, "DockingConfig.mass_scale: empty range: needs low <= high"),
        ({"thrust_scale": (0.0, 1.0)}, "DockingConfig.thrust_scale: each entry must lie in (0"),
        ({"reverse_thrust_loss": 1.0}, "DockingConfig.reverse_thrust_loss: must lie in [0, 0.95]"),
        (
            {"pid_gain_scale": (1.0, 3.0), "mass_scale": (0.5, 1.0)},
            "DockingConfig.pid_gain_scale: the surge PID loop diverges at the extremes",
        ),
    ],
)
def test_bad_realism_options_are_refused_in_one_line(changes, message):
    with pytest.raises(ValueError) as info:
        DockingConfig(**changes)
    assert str(info.value).startswith(message)
    assert "\n" not in str(info.value)


def test_bounds_cover_every_realism_option():
    for name in ("usbl_period", "usbl_outlier_distance", "current_variation_std", "mass_scale"):
        assert name in BOUNDS


# -- sensors ---------------------------------------------------------------------------------
def test_usbl_holds_between_fixes_its_age_counts_and_nothing_else_changes():
    nominal = run(DockingConfig(), 23)
    slow = run(DockingConfig(usbl_period=1.0), 23)
    assert torch.equal(slow["true_state"], nominal["true_state"])
    assert torch.equal(slow["observation"][..., 2:], nominal["observation"][..., 2:])
    steps = torch.arange(24)
    fixes = steps - steps % 5  # the step of the last fix
    assert torch.equal(slow["observation"][..., :2], nominal["observation"][:, fixes, :2])
    age = slow["sensor_age"]
    assert torch.allclose(age[..., 0], (steps % 5).float() * DT)
    assert (age[..., 1:] == 0).all()


def test_usbl_latency_describes_the_vehicle_steps_ago():
    late = run(DockingConfig(noise=False, usbl_latency=0.6), 12)
    clean = clean_observation(late)
    delayed = torch.arange(13).sub(3).clamp_min(0)
    assert torch.allclose(late["observation"][..., :2], clean[:, delayed, :2], atol=1e-5)
    assert torch.allclose(late["observation"][..., 2:], clean[..., 2:], atol=1e-6)
    assert (late["sensor_age"] == 0).all()


def test_dropout_bursts_hold_the_reading_for_their_mean_length():
    config = DockingConfig(usbl_dropout_probability=0.3, usbl_dropout_burst=3.0)
    td = run(config, 60, num_envs=400)
    lost = td["sensor_age"][:, 1:, 0] > 0
    assert abs(lost.float().mean().item() - 0.3) < 0.03
    starts = (lost[:, 1:] & ~lost[:, :-1]).sum()
    assert abs(lost[:, 1:].sum().item() / starts.item() - 3.0) < 0.3
    held = td["observation"][:, 1:, :2]
    before = td["observation"][:, :-1, :2]
    assert torch.equal(held[lost], before[lost])
    # independent losses: a loss does not make the next one likelier
    independent = run(config.replace(usbl_dropout_burst=0.0), 60, num_envs=400)
    lost = independent["sensor_age"][:, 1:, 0] > 0
    after_loss = lost[:, 1:][lost[:, :-1]].float().mean().item()
    assert abs(after_loss - 0.3) < 0.03


def test_outlier_fix_is_as_far_as_configured():
    config = DockingConfig(noise=False, usbl_outlier_probability=0.5, usbl_outlier_distance=5.0)
    td = run(config, 20, num_envs=64)
    true_xy = td["true_state"][..., :2]
    read_xy = pose_from_observation(td["observation"])[..., :2]
    error = (read_xy - true_xy).norm(dim=-1)[:, 1:]
    outliers = error > 1.0
    assert torch.allclose(error[outliers], torch.full_like(error[outliers], 5.0), atol=1e-3)
    assert error[~outliers].max() < 1e-3
    assert abs(outliers.float().mean().item() - 0.5) < 0.07
    assert torch.allclose(td["observation"][..., 2:], clean_observation(td)[..., 2:], atol=1e-6)


def test_dvl_and_imu_at_their_own_rates():
    nominal = run(DockingConfig(), 12)
    td = run(DockingConfig(dvl_period=0.4, imu_period=0.6), 12)
    steps = torch.arange(13)
    dvl, imu = steps - steps % 2, steps - steps % 3
    assert torch.equal(td["observation"][..., 3:5], nominal["observation"][:, dvl, 3:5])
    assert torch.equal(td["observation"][..., 2], nominal["observation"][:, imu, 2])
    assert torch.equal(td["observation"][..., 5], nominal["observation"][:, imu, 5])
    assert torch.equal(td["observation"][..., :2], nominal["observation"][..., :2])
    assert torch.allclose(td["sensor_age"][0, :, 1], (steps % 2).float() * DT)
    assert torch.allclose(td["sensor_age"][0, :, 2], (steps % 3).float() * DT)


# -- current ---------------------------------------------------------------------------------
def test_ou_current_has_the_configured_std_and_time_constant():
    config = DockingConfig(current_time_constant=10.0, current_variation_std=0.1)
    nominal = run(DockingConfig(), 60, num_envs=2000)
    varying = run(config, 60, num_envs=2000)
    deviation = varying["true_ocean_current"] - nominal["ocean_current"]  # the drawn means
    assert abs(deviation.std().item() - 0.1) < 0.005
    lag = 50  # 10 s: correlation e^-1
    first, later = deviation[:, 0].flatten(), deviation[:, lag].flatten()
    correlation = (first * later).mean() / (first.std() * later.std())
    assert abs(correlation.item() - math.exp(-lag * DT / 10.0)) < 0.04
    assert torch.equal(varying["ocean_current"], varying["true_ocean_current"])
    assert torch.equal(varying["true_state"][:, 0], nominal["true_state"][:, 0])


def test_current_knowledge_is_biased_per_episode_and_noisy_per_step():
    nominal = run(DockingConfig(), 30, num_envs=1000)
    biased = run(DockingConfig(current_knowledge_bias=0.05), 30, num_envs=1000)
    error = biased["ocean_current"] - biased["true_ocean_current"]
    assert torch.equal(error, error[:, :1].expand_as(error))
    assert abs(error.std().item() - 0.05) < 0.004
    assert torch.equal(biased["true_state"], nominal["true_state"])
    assert torch.equal(biased["observation"], nominal["observation"])
    noisy = run(DockingConfig(current_knowledge_noise=0.02), 30, num_envs=1000)
    error = noisy["ocean_current"] - noisy["true_ocean_current"]
    assert abs(error.std().item() - 0.02) < 0.002
    assert abs(error[:, 1:].mul(error[:, :-1]).mean().item()) < 1e-5  # white


# -- dynamics --------------------------------------------------------------------------------
def test_dynamics_scales_are_drawn_within_ranges_per_episode():
    config = DockingConfig(
        mass_scale=(0.7, 1.3),
        damping_scale=(0.5, 1.5),
        thrust_scale=(0.8, 1.2),
        pid_gain_scale=(0.7, 1.3),
        response_time_scale=(1.0, 3.0),
    )
    env = DockingEnv(500, config=config, seed=0)
    td = env.reset()
    scales = env.vehicle_scales
    ranges = torch.tensor(
        [config.mass_scale, config.damping_scale, config.thrust_scale]
        + [config.pid_gain_scale, config.response_time_scale]
    )
    assert ((scales >= ranges[:, 0]) & (scales <= ranges[:, 1])).all()
    width = ranges[:, 1] - ranges[:, 0]
    assert ((scales.max(0).values - scales.min(0).values) > 0.9 * width).all()
    mask = torch.zeros(500, 1, dtype=torch.bool)
    mask[:250] = True
    env.reset(td.set("_reset", mask))
    again = env.vehicle_scales
    assert torch.equal(again[250:], scales[250:])
    assert (again[:250] != scales[:250]).all()
    nominal = run(DockingConfig(), 10)
    mismatched = run(config, 10)
    assert torch.equal(mismatched["true_state"][:, 0], nominal["true_state"][:, 0])
    assert not torch.allclose(mismatched["true_state"][:, -1], nominal["true_state"][:, -1])


def rise_time(config: DockingConfig, command: tuple[float, float]) -> torch.Tensor:
    """Seconds for surge and yaw rate to reach 63 % of a small step command from rest."""
    env = DockingEnv(1, config=config.replace(noise=False), seed=0)
    td = env.reset()
    action = torch.tensor([command])
    times = torch.full((2,), math.inf)
    for t in range(1, 400):
        td = env.step(td.set("action", action))["next"]
        velocity = td["true_state"][0, 3::2]
        reached = (velocity / action[0] >= 0.632) & torch.isinf(times)
        times[reached] = t * config.dt
    return times


def test_response_time_scale_slows_the_velocity_loops_by_its_factor():
    fine = DockingConfig(dt=0.01)
    # a small step keeps the loops linear (quadratic damping negligible); the retuning divides
    # the closed loop's poles by the factor, but not the PI's zero, so the 63 % rise time
    # grows by a little more than the factor
    nominal = rise_time(fine, (0.02, 0.01))
    slow = rise_time(fine.replace(response_time_scale=(3.0, 3.0)), (0.02, 0.01))
    assert ((slow / nominal > 2.9) & (slow / nominal < 3.6)).all(), (nominal, slow)
    faster = rise_time(fine.replace(response_time_scale=(0.5, 0.5)), (0.02, 0.01))
    assert ((faster / nominal > 0.4) & (faster / nominal < 0.6)).all(), (nominal, faster)


def test_the_dynamics_ranges_stack_at_their_slowest_corner():
    # drawn independently, L3's scales stack: a heavy, lightly damped vehicle with weak thrust
    # and soft gains responds about 6x slower than nominal at response_time_scale 3, where the
    # scale alone gives 3.4x (docs/realism.md)
    fine = DockingConfig(dt=0.01)
    corner = fine.replace(
        mass_scale=(1.3, 1.3),
        damping_scale=(0.7, 0.7),
        thrust_scale=(0.8, 0.8),
        pid_gain_scale=(0.7, 0.7),
        response_time_scale=(3.0, 3.0),
    )
    ratio = rise_time(corner, (0.02, 0.01)) / rise_time(fine, (0.02, 0.01))
    assert ((ratio > 5.5) & (ratio < 6.5)).all(), ratio


def test_reverse_and_turning_losses_limit_the_surge_thrust():
    limit = torch.tensor([[40.0]])
    tau = torch.tensor([[-40.0, 0.0]])
    assert torch.equal(limit_thrust(tau, limit, 0.4, 0.0), torch.tensor([[-24.0, 0.0]]))
    assert torch.equal(limit_thrust(-tau, limit, 0.4, 0.0), -tau)
    turning = torch.tensor([[40.0, -40.0], [40.0, 20.0]])
    limited = limit_thrust(turning, limit.expand(2, 1), 0.0, 0.5)
    assert torch.equal(limited, torch.tensor([[20.0, -40.0], [30.0, 20.0]]))
    fine = DockingConfig(dt=0.01)
    backwards = rise_time(fine, (-0.4, 0.0))[0]
    assert rise_time(fine.replace(reverse_thrust_loss=0.5), (-0.4, 0.0))[0] > 1.2 * backwards


def test_every_option_on_keeps_specs_and_resets_its_state():
    config = DockingConfig(
        max_steps=15,
        usbl_period=1.0,
        usbl_latency=0.4,
        usbl_dropout_probability=0.2,
        usbl_dropout_burst=2.0,
        usbl_outlier_probability=0.05,
        usbl_outlier_distance=5.0,
        dvl_period=0.4,
        current_time_constant=30.0,
        current_variation_std=0.05,
        current_knowledge_bias=0.05,
        current_knowledge_noise=0.02,
        mass_scale=(0.7, 1.3),
        reverse_thrust_loss=0.4,
        turning_surge_loss=0.5,
        response_time_scale=(1.0, 3.0),
    )
    check_env_specs(DockingEnv(4, config=config, seed=0))
    env = DockingEnv(4, config=config, seed=0, check_finite=True)
    torch.manual_seed(0)
    td = env.rollout(40, break_when_any_done=False)
    first = td["next", "step_count"].squeeze(-1) == 1  # the step after each reset
    assert first.sum() == 4 * 3
    assert torch.allclose(td["sensor_age"][..., 0][first], torch.zeros(12))
    torch.manual_seed(0)
    again = DockingEnv(4, config=config, seed=0).rollout(40, break_when_any_done=False)
    assert torch.equal(again["next", "observation"], td["next", "observation"])


# -- the EKF for such sensors ---------------------------------------------------------------------
def filter_inputs(n: int = 16):
    g = torch.Generator().manual_seed(0)
    mean = torch.stack(
        (
            -25 + 5 * torch.rand(n, generator=g),
            -5 + 10 * torch.rand(n, generator=g),
            torch.rand(n, generator=g) - 0.5,
            0.3 * torch.rand(n, generator=g),
            0.1 * torch.randn(n, generator=g),
        ),
        dim=-1,
    )
    cov = torch.diag_embed(torch.tensor([0.3, 0.3, 0.05, 0.02, 0.01]) ** 2).expand(n, 5, 5)
    action = torch.tensor([0.5, 0.1]).expand(n, 2)
    current = 0.2 * torch.rand(n, 2, generator=g) - 0.1
    z = measurement_function(mean, current) + 0.01 * torch.randn(n, 6, generator=g)
    R = measurement_covariance(z[:, 0])
    return mean, cov, action, z, current, process_covariance(), R


def test_asynchronous_update_equals_the_synchronous_one_when_every_sensor_reports():
    mean, cov, action, z, current, Q, R = filter_inputs()
    every = torch.ones(16, 6, dtype=torch.bool)
    sync = ekf_step(mean, cov, action, z, current, Q, R, DT)
    both = ekf_step(mean, cov, action, z, current, Q, R, DT, arrived=every)
    for a, b in zip(sync, both, strict=True):
        assert torch.equal(a, b)
    none = torch.zeros(16, 6, dtype=torch.bool)
    predicted = ekf_predict(mean, cov, action, current, Q, DT)
    held = ekf_step(mean, cov, action, z, current, Q, R, DT, arrived=none)
    assert torch.equal(held[0], predicted[0]) and torch.equal(held[1], predicted[1])


def test_env_with_every_sensor_reporting_gives_the_paper_filter_exactly():
    # an outlier this rare never happens, but it turns the sensor model (and sensor_age) on
    config = DockingConfig(usbl_outlier_probability=1e-12, usbl_outlier_distance=1.0)
    outs = []
    for cfg in (DockingConfig(), config):
        env = make_env("compound", 8, seed=2, config=cfg)
        torch.manual_seed(0)
        outs.append(env.rollout(30, break_when_any_done=False))
    assert "sensor_age" in outs[1]["next"].keys()
    assert torch.equal(outs[0]["next", "observation"], outs[1]["next", "observation"])
    assert torch.equal(outs[0]["next", "ekf_cov"], outs[1]["next", "ekf_cov"])


def test_gated_outlier_leaves_the_estimate_as_predicted():
    mean, cov, action, z, current, Q, R = filter_inputs()
    predicted = ekf_predict(mean, cov, action, current, Q, DT)
    z = measurement_function(predicted[0], current)
    outlier = z.clone()
    outlier[:, 0] += 10.0  # a multipath range, 10 m long
    usbl = torch.tensor([True, True, False, False, False, False]).expand(16, 6)
    gated = ekf_update(*predicted, outlier, current, R, arrived=usbl, gate=CHI2_2DOF_999)
    assert torch.equal(gated[0], predicted[0]) and torch.equal(gated[1], predicted[1])
    fooled = ekf_update(*predicted, outlier, current, R, arrived=usbl)
    assert (fooled[0][:, :2] - predicted[0][:, :2]).norm(dim=-1).min() > 0.1
    # the other sensors' readings still update, as if the USBL's had not arrived
    both = ekf_update(*predicted, outlier, current, R, gate=CHI2_2DOF_999)
    others = ekf_update(*predicted, outlier, current, R, arrived=~usbl)
    assert torch.equal(both[0], others[0]) and torch.equal(both[1], others[1])
    distance = sensor_innovation_distance(*predicted, outlier, current, R)
    assert (distance[:, 0] > CHI2_2DOF_999).all() and (distance[:, 1:] < 1e-6).all()


def test_gated_asynchronous_filter_stays_differentiable():
    mean, cov, action, z, current, Q, R = filter_inputs()
    sigma = torch.tensor([0.025, 0.026, 0.05, 0.02, 0.02, 0.0035], requires_grad=True)
    variances = (sigma * torch.cat((z[:, :1], torch.ones(16, 5)), -1)) ** 2
    arrived = torch.rand(16, 6, generator=torch.Generator().manual_seed(1)) < 0.7
    out = ekf_step(
        mean, cov, action, z, current, Q, variances, DT, diagonal=True, arrived=arrived, gate=9.21
    )
    out[0].square().sum().backward()
    assert torch.isfinite(sigma.grad).all() and sigma.grad.abs().sum() > 0


def test_filter_skips_held_readings_and_beats_one_that_takes_them_as_new():
    config = DockingConfig(usbl_period=2.0, usbl_latency=0.0)
    errors = []
    for age_key in ("sensor_age", "no_such_entry"):
        env = make_env(
            "filtered", 64, seed=5, config=config, ekf_kwargs={"sensor_age_key": age_key}
        )
        torch.manual_seed(0)
        td = env.rollout(150, break_when_any_done=False)["next"]
        error = (td["ekf_mean"][..., :2] - td["true_state"][..., :2]).norm(dim=-1)
        errors.append(error[:, 50:].mean())
    assert errors[0] < 0.9 * errors[1], errors


# -- the stress ladder -------------------------------------------------------------------------
def test_stress_levels_are_valid_configs_and_l5_holds_every_option():
    from dockingrl.env.levels import LEVELS, level_config

    assert level_config("L0") == DockingConfig()
    harshest = level_config("L5")
    assert harshest.sensor_timing and harshest.current_model and harshest.dynamics_mismatch
    for name in LEVELS:
        assert level_config(name).realistic == (name != "L0")
    with pytest.raises(ValueError, match=r"^unknown stress level 'L9'; valid: L0, L1, L2"):
        level_config("L9")


def test_stress_command_writes_table_json_and_plot(tmp_path, capsys):
    import argparse
    import json

    from dockingrl.agents.managed_surge import ManagedSurgePolicy
    from dockingrl.cli.stress import add_stress_command
    from dockingrl.evaluation import evaluate

    parser = argparse.ArgumentParser()
    add_stress_command(parser.add_subparsers())
    args = parser.parse_args(
        ["stress", "--episodes", "3", "--levels", "L0,L5", "--out", str(tmp_path)]
    )
    assert args.func(args) == 0
    result = json.loads((tmp_path / "stress.json").read_text())
    assert [row["name"] for row in result["levels"]] == ["L0", "L5"]
    assert (tmp_path / "stress.png").stat().st_size > 0
    table = (tmp_path / "stress.md").read_text()
    assert "| L5 | sensors, current and dynamics |" in table
    for row in result["levels"]:
        strong = row["by_current_y"][2]
        assert strong["abs_oc_y"] == "strong"
        cell = (
            f"{strong['success_rate']:.1f} ({strong['episodes']})"
            if strong["episodes"]
            else "n/a (0)"
        )
        (line,) = [x for x in table.splitlines() if x.startswith(f"| {row['name']} |")]
        assert line.endswith(f"| {cell} |")
    assert "| L0 |" in capsys.readouterr().out
    nominal = evaluate(ManagedSurgePolicy(), "noise", 3, seed=0)
    row = result["levels"][0]
    assert row["success_rate"] == nominal["success_rate"]
    assert row["failures"] == nominal["failures"]
    assert (
        sum(result["levels"][1]["failures"].values())
        + round(result["levels"][1]["success_rate"] * 3 / 100)
        == 3
    )


def test_stress_table_marks_a_ladder_without_the_lateral_split():
    from dockingrl.stress import stress_table

    failures = {"timeout": 1, "missed_funnel": 0, "too_fast": 2}
    row = {"name": "L0", "description": "the paper's task", "success_rate": 70.0, "episodes": 10}
    strong = {"abs_oc_y": "strong", "range": [0.2, 0.3], "episodes": 4, "success_rate": 50.0}
    empty = {**strong, "episodes": 0, "success_rate": None}
    other = {"episodes": 3, "success_rate": 100.0, "range": [0.0, 0.1]}
    weaker = [{**other, "abs_oc_y": "weak"}, {**other, "abs_oc_y": "moderate"}]
    result = {"scenario": "noise", "episodes": 10, "seed": 0, "gate": None}
    levels = [
        {**row, "failures": failures},
        {**row, "name": "L1", "failures": failures, "by_current_y": [*weaker, strong]},
        {**row, "name": "L2", "failures": failures, "by_current_y": [*weaker, empty]},
    ]
    lines = stress_table({**result, "levels": levels}).splitlines()
    assert [x.rsplit("|", 2)[1].strip() for x in lines if x.startswith("| L")] == [
        "-",
        "50.0 (4)",
        "n/a (0)",
    ]


def test_get_and_set_state_carry_the_realism_state():
    from dockingrl.env.levels import level_config

    env = DockingEnv(4, config=level_config("L5"), seed=3)
    td = env.reset()
    action = torch.tensor([[0.6, 0.1]]).expand(4, 2)
    for _ in range(7):  # mid USBL period, ages and held readings away from their reset values
        td = env.step(td.set("action", action))["next"]
    state = env.get_state()
    assert set(state["realism"].keys()) >= {"scales", "held", "sensor_steps", "current_bias"}
    generators = env.rng.get_state(), env.realism_rng.get_state()

    def rollout():
        out = env.step(TensorDict({"action": action}, batch_size=[4]))["next"]
        return [out["observation"]] + [
            env.step(TensorDict({"action": action}, batch_size=[4]))["next"]["observation"]
            for _ in range(5)
        ]

    first = rollout()
    for _ in range(3):  # move every realism state on, then go back
        env.step(TensorDict({"action": -action}, batch_size=[4]))
    env.set_state(state)
    env.rng.set_state(generators[0])
    env.realism_rng.set_state(generators[1])
    second = rollout()
    for a, b in zip(first, second, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    # the realism state must come with it, and only to an env that has realism on
    with pytest.raises(KeyError, match="state lacks 'realism'"):
        env.set_state(state.exclude("realism"))
    with pytest.raises(ValueError, match="this env has no realism on"):
        DockingEnv(4, seed=0).set_state(state)
    bad = state.clone()
    bad["realism", "sensor_steps"] = bad["realism", "sensor_steps"] - 100
    with pytest.raises(ValueError, match=r"\['sensor_steps'\] must hold integers >= 0"):
        env.set_state(bad)
