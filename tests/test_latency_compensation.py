"""The EKF's compensation of a late USBL fix (``latency_steps``, ``compensate_latency``): off
or at latency 0 it is today's filter bit for bit; with a latency it takes a fix's innovation
against the estimate of the instant the fix describes, the same offline (run_filter), in the
env (EKFTransform) and per env across resets, and stays differentiable in Q and R."""

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from dockingrl.agents.managed_surge import ManagedSurgePolicy
from dockingrl.env import DockingConfig, DockingEnv
from dockingrl.filter_learning import record_rollouts, run_filter
from dockingrl.scenarios import make_filter
from dockingrl.transforms.ekf import (
    ekf_predict,
    ekf_step,
    measurement_function,
    motion_model,
    process_covariance,
)

#: a 1 Hz USBL 0.6 s (3 steps) late, short episodes so that envs reset mid-rollout
LATE = DockingConfig(usbl_period=1.0, usbl_latency=0.6, max_steps=40, noise=True)
K = 3


@pytest.fixture(scope="module")
def rollouts():
    return record_rollouts(8, 60, config=LATE, seed=5)


def _online(config, ekf, steps=60, seed=5):
    env = TransformedEnv(DockingEnv(8, config=config, seed=seed), ekf)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        return env.rollout(steps, ManagedSurgePolicy(), break_when_any_done=False)


def test_option_off_or_latency_zero_is_todays_filter_bit_for_bit():
    on_time = LATE.replace(usbl_latency=0.0)
    ekf = make_filter(on_time, compensate_latency=True)
    assert ekf.latency_steps == 0
    today = _online(on_time, make_filter(on_time), steps=30)
    compensated = _online(on_time, ekf, steps=30)
    assert "ekf_usbl_history" not in compensated.keys()
    assert torch.equal(today["next", "ekf_mean"], compensated["next", "ekf_mean"])
    assert torch.equal(today["next", "ekf_cov"], compensated["next", "ekf_cov"])
    assert make_filter(LATE).latency_steps == 0  # off unless asked
    assert make_filter(LATE, compensate_latency=True).latency_steps == K


def test_a_fix_predicted_as_the_prior_predicts_it_changes_nothing():
    """``usbl_prediction`` equal to h(prior) is the uncompensated update, exactly."""
    torch.manual_seed(0)
    mean = torch.tensor([[20.0, 3.0, 0.3, 1.0, 0.05], [-8.0, 12.0, -2.0, 0.5, -0.1]])
    cov, Q = 0.1 * torch.eye(5).expand(2, 5, 5), process_covariance()
    action, current = torch.tensor([[1.0, 0.1], [0.5, -0.2]]), torch.tensor([[0.2, -0.1]] * 2)
    z = measurement_function(mean, current) + 0.05 * torch.randn(2, 6)
    R = torch.full((6,), 1e-3)
    prior, _ = ekf_predict(mean, cov, action, current, Q, 0.2)
    plain = ekf_step(mean, cov, action, z, current, Q, R, 0.2, diagonal=True)
    same = ekf_step(
        mean,
        cov,
        action,
        z,
        current,
        Q,
        R,
        0.2,
        diagonal=True,
        usbl_prediction=measurement_function(prior, current)[..., :2],
    )
    for a, b in zip(plain, same, strict=True):
        assert torch.equal(a, b)
    moved = ekf_step(
        mean, cov, action, z, current, Q, R, 0.2, diagonal=True, usbl_prediction=z[..., :2]
    )
    assert (moved[0] - plain[0]).abs().max() > 1e-2  # it does take the fix against it


def _perfect_model_data(steps=60, delay=K, period=5):
    """Noise-free readings of a vehicle that moves exactly as the filter's model says (no
    process noise), turning: the DVL and IMU every step, the USBL every ``period`` steps,
    describing the vehicle ``delay`` steps ago (its start for the first steps, as the env
    fills its history); one episode per env."""
    dt = 0.2
    state = torch.tensor(
        [[15.0, -4.0, 2.6, 0.6, 0.0], [-10.0, 12.0, -0.8, 0.8, 0.0]], dtype=torch.float64
    )
    current = torch.tensor([[0.15, -0.1], [-0.05, 0.2]], dtype=torch.float64)
    states, actions = [], []
    for t in range(steps):
        states.append(state)
        turn = 0.25 * math.sin(0.15 * t)
        action = torch.tensor([[0.7, turn], [0.5, -turn]], dtype=torch.float64)
        actions.append(action)
        state = motion_model(state, action, current, dt)
    truth = torch.stack(states)
    clean = measurement_function(truth, current.expand(steps, 2, 2))
    late = torch.stack([clean[max(t - delay, 0), :, :2] for t in range(steps)])
    t = torch.arange(steps)
    usbl_age = dt * (t % period).to(torch.float64)
    sensor_age = torch.zeros(steps, 2, 3, dtype=torch.float64)
    sensor_age[..., 0] = usbl_age[:, None]
    step_count = t[:, None].expand(steps, 2)

    def data(usbl):
        return TensorDict(
            {
                "observation": torch.cat((usbl, clean[..., 2:]), -1),
                "action": torch.stack(actions),
                "ocean_current": current.expand(steps, 2, 2),
                "step_count": step_count,
                "sensor_age": sensor_age,
            },
            batch_size=[steps, 2],
        )

    return truth, data(late), data(clean[..., :2])


def _position_error(ekf, data, truth, start_error):
    with torch.no_grad():
        mean, cov = ekf.initial_estimate(data["observation"][0], data["ocean_current"][0])
        mean = mean.clone()
        mean[:, :2] += start_error
        state = (mean, cov, data["action"][0])
        if ekf.latency_steps:
            filtered = measurement_function(mean, data["ocean_current"][0])
            state += (ekf.initial_history(filtered),)
        means = run_filter(ekf, data[1:], state=state)[0]
    return (means[..., :2] - truth[1:, :, :2]).norm(dim=-1)


def test_compensated_late_fix_under_a_perfect_model_equals_the_on_time_fix():
    """Started on the truth, a filter whose model is exact stays on it with on-time fixes; with
    fixes 3 steps late it stays on it only when it compensates them (the innovation against
    the estimate of the instant the fix describes is then 0, an off-by-one step is not)."""
    truth, late, on_time = _perfect_model_data()
    config = LATE.replace(max_steps=1000)
    plain = make_filter(config).double()
    compensating = make_filter(config, compensate_latency=True).double()
    assert _position_error(plain, on_time, truth, 0.0).max() < 1e-6
    assert _position_error(compensating, late, truth, 0.0).max() < 1e-6
    assert _position_error(plain, late, truth, 0.0).max() > 0.05
    wrong_lag = make_filter(config, latency_steps=K - 1).double()
    assert _position_error(wrong_lag, late, truth, 0.0).max() > 0.02


def test_compensated_late_fix_corrects_a_wrong_start_nearly_as_an_on_time_fix():
    """From a 3 m error, the compensating filter with late fixes converges about as the
    filter with on-time fixes does (its gain acts on the current estimate, so not exactly),
    at half the uncompensated one's error."""
    truth, late, on_time = _perfect_model_data()
    config = LATE.replace(max_steps=1000)
    plain = make_filter(config).double()
    compensating = make_filter(config, compensate_latency=True).double()
    offset = torch.tensor([2.0, -2.2], dtype=torch.float64)
    ideal = _position_error(plain, on_time, truth, offset)[10:].mean()
    compensated = _position_error(compensating, late, truth, offset)[10:].mean()
    uncompensated = _position_error(plain, late, truth, offset)[10:].mean()
    assert ideal <= compensated < 1.1 * ideal
    assert compensated < 0.6 * uncompensated


def test_run_filter_equals_the_env_transform_with_latency_and_resets(rollouts):
    """The compensating filter offline and online give the same estimates, resets included:
    the history is kept and restarted per env as the env's transform does."""
    ekf = make_filter(LATE, compensate_latency=True, gate=13.8)
    online = _online(LATE, make_filter(LATE, compensate_latency=True, gate=13.8))
    online = online.transpose(0, 1)
    torch.testing.assert_close(online["observation"], rollouts["observation"])
    assert bool((rollouts["step_count"][1:] == 0).any())  # envs reset mid-way
    with torch.no_grad():
        means, covs, _, _ = run_filter(ekf, rollouts)
        uncompensated, _, _, _ = run_filter(make_filter(LATE, gate=13.8), rollouts)
    torch.testing.assert_close(means, online["ekf_mean"], rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(covs, online["ekf_cov"], rtol=1e-4, atol=1e-7)
    assert (uncompensated - means).abs().max() > 1e-2
    # after step t the history holds the range and bearing of estimates t-K+1..t, oldest first
    history = online["ekf_usbl_history"]
    filtered = online["filtered_observation"][..., :2]
    keep = online["step_count"].squeeze(-1)[K:] >= K
    for lag in range(K):
        torch.testing.assert_close(
            history[K:, :, K - 1 - lag][keep], filtered[K - lag : filtered.shape[0] - lag][keep]
        )


def test_history_restarts_only_in_the_envs_that_reset():
    ekf = make_filter(LATE, compensate_latency=True)
    env = TransformedEnv(DockingEnv(3, config=LATE, seed=1), ekf)
    td = env.reset()
    history = td["ekf_usbl_history"]
    assert history.shape == (3, K, 2)
    torch.testing.assert_close(history, td["filtered_observation"][:, None, :2].expand(3, K, 2))
    for _ in range(6):
        td["action"] = torch.tensor([[1.0, 0.3]] * 3)
        td = env.step(td)["next"]
    before = td["ekf_usbl_history"].clone()
    assert (before[:, 0] - before[:, -1]).abs().max() > 1e-3  # it moved
    td["_reset"] = torch.tensor([[True], [False], [False]])
    td = env.reset(td)
    after = td["ekf_usbl_history"]
    torch.testing.assert_close(after[0], td["filtered_observation"][0, None, :2].expand(K, 2))
    assert torch.equal(after[1:], before[1:])


def test_gradients_flow_to_q_and_r_through_the_compensation(rollouts):
    ekf = make_filter(LATE, compensate_latency=True, gate=13.8, learnable=True)
    loss = run_filter(ekf, rollouts[:30], objective="nll")[3]
    loss.backward()
    grads = [p.grad for p in ekf.noise_parameters()]
    assert all(g is not None and bool(torch.isfinite(g).all()) for g in grads)
    assert all(float(g.abs().sum()) > 0 for g in grads)
    # and the compensated objective is not the uncompensated one
    plain = make_filter(LATE, gate=13.8)
    with torch.no_grad():
        other = float(run_filter(plain, rollouts[:30], objective="nll")[3])
    assert abs(float(loss.detach()) - other) > 1e-3


def test_bad_latency_steps_are_refused():
    with pytest.raises(ValueError, match="latency_steps must be a whole number of steps >= 0"):
        make_filter(LATE, latency_steps=-1)
    with pytest.raises(ValueError, match="latency_steps must be a whole number of steps >= 0"):
        make_filter(LATE, latency_steps=1.5)


def test_onboard_policy_and_its_export_compensate_as_the_env_pipeline_does(tmp_path):
    from helpers import drive_onboard_beside_env, tiny_actor

    from dockingrl import make_env
    from dockingrl.onboard import OnboardPolicy, export_onboard

    actor = tiny_actor(12, "sac")
    onboard = OnboardPolicy(actor, "compound", config=LATE, compensate_latency=True)
    plain = OnboardPolicy(actor, "compound", config=LATE)
    program = torch.export.load(
        export_onboard(onboard, tmp_path / "onboard.pt2", batch=4, sensor_age=True)
    ).module()
    env = make_env("compound", 4, seed=3, config=LATE, ekf_kwargs={"compensate_latency": True})
    resets, differs = drive_onboard_beside_env(env, actor, onboard, program, plain=plain)
    assert resets > 0 and differs
    with pytest.raises(ValueError, match="needs sensor_age=True"):
        export_onboard(onboard, tmp_path / "no_ages.pt2")
