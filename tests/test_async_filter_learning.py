"""The learned-Q/R tooling and the onboard policy with sensors at their own rates: the same
filter offline (run_filter on recorded rollouts), in the env (EKFTransform) and onboard."""

import pytest
import torch
from helpers import step_onboard, tiny_actor
from tensordict import TensorDict
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from dockingrl import make_env
from dockingrl.agents.managed_surge import ManagedSurgePolicy
from dockingrl.env import DockingConfig, DockingEnv
from dockingrl.filter_learning import (
    FilterFit,
    evaluate_filter,
    fit_filter,
    innovation_whiteness,
    record_rollouts,
    run_filter,
)
from dockingrl.onboard import OnboardPolicy
from dockingrl.scenarios import make_filter
from dockingrl.transforms.ekf import (
    MEASUREMENT_NOISE_STD,
    ekf_predict,
    innovation,
    innovation_covariance,
    measurement_jacobian,
)
from dockingrl.transforms.filtering import arrived_readings

#: a 1 Hz USBL with outliers (gated), short episodes so that envs reset mid-rollout
ASYNC = DockingConfig(
    usbl_period=1.0, usbl_outlier_probability=0.1, usbl_outlier_distance=5.0, max_steps=40
)


@pytest.fixture(scope="module")
def rollouts():
    return record_rollouts(8, 60, config=ASYNC, seed=5)


def test_rollouts_keep_the_sensor_ages_and_only_when_the_env_has_them(rollouts):
    assert rollouts["sensor_age"].shape == (60, 8, 3)
    usbl_new = rollouts["sensor_age"][..., 0] == 0
    assert 0.1 < usbl_new.double().mean() < 0.3  # one fix in five steps
    assert bool((rollouts["sensor_age"][..., 1:] == 0).all())  # DVL and IMU every step
    assert "sensor_age" not in record_rollouts(2, 3, seed=0).keys()


def test_run_filter_equals_the_env_transform_step_by_step(rollouts):
    """The same gated, asynchronous filter offline and online: run_filter on the recorded
    rollouts gives the estimates the env's EKFTransform kept, resets included."""
    config = ASYNC.replace(noise=True)
    ekf = make_filter(config, gate=13.8)
    env = TransformedEnv(DockingEnv(8, config=config, seed=5), make_filter(config, gate=13.8))
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        online = env.rollout(60, ManagedSurgePolicy(), break_when_any_done=False)
    online = online.transpose(0, 1)
    torch.testing.assert_close(online["observation"], rollouts["observation"])
    assert bool((rollouts["step_count"][1:] == 0).any())  # envs reset mid-way
    with torch.no_grad():
        means, covs, _, _ = run_filter(ekf, rollouts)
    torch.testing.assert_close(means, online["ekf_mean"], rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(covs, online["ekf_cov"], rtol=1e-4, atol=1e-7)
    # the held USBL readings did not update it: the filter that takes them as new differs
    with torch.no_grad():
        every_step, _, _, _ = run_filter(ekf, rollouts.exclude("sensor_age"))
    assert (every_step - means).abs().max() > 1e-2


def _hand_innovations(ekf, data, arrived_only):
    """The mean over steps (after the first) and envs of each innovation's negative
    log-likelihood, and each step's NIS ``(T - 1, N)`` (NaN at an episode's first step), over
    the readings that arrived (or over all six), from run_filter's estimates, env by env with
    an explicit sub-matrix of S."""
    with torch.no_grad():
        means, covs, _, _ = run_filter(ekf, data)
    z, current, fresh = data["observation"], data["ocean_current"], data["step_count"] == 0
    arrived = arrived_readings(data["sensor_age"])
    total, count = 0.0, 0
    nis = torch.full((z.shape[0] - 1, z.shape[1]), float("nan"), dtype=torch.float64)
    for t in range(1, z.shape[0]):
        applied = ekf._applied_action(data["action"][t - 1])
        Q, R = ekf.noise_covariances(means[t - 1], applied, z[t], data["step_count"][t] - 1)
        prior_mean, prior_cov = ekf_predict(
            means[t - 1], covs[t - 1], applied, current[t], Q, ekf.dt, k_v=ekf.k_v, k_w=ekf.k_w
        )
        H = measurement_jacobian(prior_mean, current[t])
        S = innovation_covariance(prior_cov, H, torch.diag_embed(R)).double()
        y = innovation(prior_mean, z[t], current[t]).double()
        for n in range(z.shape[1]):
            count += 1
            if fresh[t, n]:
                continue
            keep = arrived[t, n] if arrived_only else torch.ones(6, dtype=torch.bool)
            y_a, S_a = y[n][keep], S[n][keep][:, keep]
            nis[t - 1, n] = y_a @ torch.linalg.solve(S_a, y_a)
            total += 0.5 * float(nis[t - 1, n] + torch.logdet(S_a))
    return total / count, nis


def test_nll_and_nis_count_only_the_readings_that_arrived():
    data = record_rollouts(3, 12, config=ASYNC, seed=2)
    ekf = make_filter(ASYNC)
    nis: list[torch.Tensor] = []
    with torch.no_grad():
        loss = float(run_filter(ekf, data, objective="nll", nis=nis)[3])
    hand_loss, hand_nis = _hand_innovations(ekf, data, arrived_only=True)
    assert loss == pytest.approx(hand_loss, rel=1e-4, abs=1e-4)
    torch.testing.assert_close(
        torch.stack(nis).double(), hand_nis, rtol=1e-3, atol=1e-4, equal_nan=True
    )
    assert abs(loss - _hand_innovations(ekf, data, arrived_only=False)[0]) > 0.1


def test_nis_report_counts_the_readings_that_arrived(rollouts):
    report = evaluate_filter(make_filter(ASYNC), rollouts, skip=2)
    assert 4.0 < report["nis_dof_mean"] < 5.0  # DVL and IMU every step, the USBL one in five
    assert "nis_step_bounds_95" not in report
    assert 0.0 < report["nis_fraction_in_step_bounds"] < 1.0


def test_fitting_q_and_r_on_asynchronous_data_lowers_the_loss(rollouts):
    wrong = [3.0 * s for s in MEASUREMENT_NOISE_STD]  # a poor start, away from the fit
    ekf = make_filter(ASYNC, measurement_noise_std=wrong)
    with torch.no_grad():
        before = float(run_filter(ekf, rollouts, objective="nll")[3])
    fit = FilterFit(num_envs=8, steps=60, window=20, epochs=3, lr=0.1, whiteness=0.1, lags=5)
    history = fit_filter(ekf, fit, data=rollouts)
    with torch.no_grad():
        after = float(run_filter(ekf, rollouts, objective="nll")[3])
    assert len(history) == 9 and all(torch.isfinite(torch.tensor(history)))
    assert after < before - 0.1


def test_onboard_policy_with_sensor_ages_commands_what_the_env_pipeline_does():
    actor = tiny_actor(12, "sac")
    onboard = OnboardPolicy(actor, "compound", config=ASYNC)
    blind = OnboardPolicy(actor, "compound", config=ASYNC)  # takes every reading as new
    env = make_env("compound", 8, seed=3, config=ASYNC)
    td = env.reset()
    resets, differs = 0, False
    for _ in range(60):
        command = onboard.act(td["observation"][..., :6], td["ocean_current"], td["sensor_age"])
        differs |= bool(
            (blind.act(td["observation"][..., :6], td["ocean_current"]) - command).abs().max()
            > 1e-3
        )
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            obs = TensorDict({"observation": td["observation"]}, batch_size=[8])
            torch.testing.assert_close(command, actor(obs)["action"], rtol=1e-5, atol=1e-6)
        td, done = step_onboard(env, td, command, onboard, blind)
        resets += int(done.sum())
    assert resets > 0 and differs


def test_onboard_policy_refuses_bad_sensor_ages():
    onboard = OnboardPolicy(tiny_actor(12, "sac"), "compound", config=ASYNC)
    z, current = torch.tensor([20.0, 0.1, 0.2, 0.3, 0.0, 0.0]), torch.zeros(2)
    with pytest.raises(ValueError, match=r"sensor_age must be \(3,\) or \(vehicles, 3\)"):
        onboard.act(z, current, torch.zeros(2))
    with pytest.raises(ValueError, match="sensor_age must be >= 0 s"):
        onboard.act(z, current, torch.tensor([-0.2, 0.0, 0.0]))
    with pytest.raises(ValueError, match="one row of 3 ages per vehicle of z"):
        onboard.act(z, current, torch.zeros(2, 3))
    command = onboard.act(z, current, torch.tensor([0.0, 0.0, 0.0]))
    assert command.shape == (2,)


def test_exported_program_with_sensor_ages_commands_what_the_policy_does(tmp_path):
    from dockingrl.onboard import export_onboard

    policy = OnboardPolicy(tiny_actor(12, "sac"), "compound", config=ASYNC)
    program = torch.export.load(
        export_onboard(policy, tmp_path / "onboard.pt2", batch=2, sensor_age=True)
    ).module()
    env = make_env("compound", 2, seed=6, config=ASYNC)
    td = env.reset()
    state = policy.initial_state(2)
    for _ in range(12):
        z, current, ages = td["observation"][..., :6], td["ocean_current"], td["sensor_age"]
        command, *filter_state = program(z, current, *state, ages)
        torch.testing.assert_close(command, policy.act(z, current, ages), rtol=1e-5, atol=1e-6)
        state = (filter_state[0], filter_state[1], command, filter_state[2])
        td["action"] = command
        td = env.step_and_maybe_reset(td)[1]
    torch.testing.assert_close(state[0], policy._state[0], rtol=1e-5, atol=1e-6)


def test_whiteness_averages_each_entry_pair_over_the_steps_where_both_arrived():
    torch.manual_seed(0)
    arrived = torch.rand(30, 4, 2) < 0.5
    white = torch.where(arrived, torch.randn(30, 4, 2), torch.zeros(30, 4, 2))
    valid = torch.ones(30, 4, dtype=torch.bool)
    expected = 0.0
    for k in (1, 2):
        for i in range(2):
            for j in range(2):
                both = arrived[k:, :, i] & arrived[:-k, :, j]
                products = (white[k:, :, i] * white[:-k, :, j])[both]
                expected += float(products.mean()) ** 2
    penalty = innovation_whiteness(white, valid, 2, arrived)
    assert float(penalty) == pytest.approx(expected, rel=1e-5)
    assert float(innovation_whiteness(white, valid, 2)) < 0.5 * expected  # diluted by the zeros
