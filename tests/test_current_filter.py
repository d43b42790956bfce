"""The EKF that estimates the current's error: the paper's filter when that error is pinned
at 0, a smaller position error where the believed current is biased, and the transform's
state and options."""

import json
from functools import partial

import pytest
import torch
from torch.autograd.functional import jacobian

from dockingrl import make_env
from dockingrl.env import DockingConfig
from dockingrl.env.levels import level_config
from dockingrl.filter_learning import filter_estimates, record_rollouts
from dockingrl.filter_learning.consistency import state_error
from dockingrl.scenarios import make_filter, mirror_signs
from dockingrl.stress import stress_ladder
from dockingrl.transforms import EKFTransform
from dockingrl.transforms.current_filter import (
    AUGMENTED_DIM,
    CurrentEstimatingEKF,
    augmented_measurement_jacobian,
    augmented_motion_jacobian,
    augmented_step,
)
from dockingrl.transforms.ekf import (
    ekf_step,
    measurement_function,
    motion_model,
    process_covariance,
)


def _batch(n=48, seed=0):
    g = torch.Generator().manual_seed(seed)
    f64 = dict(dtype=torch.float64)
    scale = torch.tensor([10.0, 5.0, 0.5, 0.5, 0.1], **f64)
    mean = torch.randn(n, 5, generator=g, **f64) * scale + torch.tensor([-20, 0, 0, 0.8, 0], **f64)
    a = torch.randn(n, 5, 5, generator=g, **f64) * 0.1
    cov = a @ a.transpose(-1, -2) + 0.01 * torch.eye(5, **f64)
    action = torch.randn(n, 2, generator=g, **f64) * 0.3
    current = torch.randn(n, 2, generator=g, **f64) * 0.2
    z = measurement_function(mean, current) + 0.05 * torch.randn(n, 6, generator=g, **f64)
    z[:7, :2] += 4.0  # a few outlying USBL fixes for the gate
    R = (torch.rand(n, 6, generator=g, **f64) + 0.5) * 0.01
    arrived = torch.rand(n, 6, generator=g) < 0.7
    late = measurement_function(mean, current)[..., :2] + 0.1
    return mean, cov, action, z, current, process_covariance(dtype=torch.float64), R, arrived, late


@pytest.mark.parametrize("gate", [None, 13.8])
@pytest.mark.parametrize("late", [False, True])
def test_with_the_error_pinned_at_zero_it_is_the_papers_filter(gate, late):
    mean, cov, action, z, current, Q, R, arrived, prediction = _batch()
    prediction = prediction if late else None
    kwargs = dict(arrived=arrived, gate=gate, usbl_prediction=prediction)
    m5, P5, f5 = ekf_step(mean, cov, action, z, current, Q, R, 0.2, diagonal=True, **kwargs)
    m7 = torch.cat((mean, torch.zeros_like(mean[..., :2])), -1)
    P7 = torch.zeros(*mean.shape[:-1], AUGMENTED_DIM, AUGMENTED_DIM, dtype=mean.dtype)
    P7[..., :5, :5] = cov
    m, P, f = augmented_step(m7, P7, action, z, current, Q, R, 0.2, current_error_std=0.0, **kwargs)
    torch.testing.assert_close(m[..., :5], m5, rtol=0, atol=1e-12)
    torch.testing.assert_close(P[..., :5, :5], P5, rtol=0, atol=1e-12)
    torch.testing.assert_close(f, f5, rtol=0, atol=1e-12)
    assert m[..., 5:].abs().max() == 0 and P[..., 5:, :].abs().max() == 0


def test_a_reading_that_did_not_arrive_leaves_the_estimate_as_predicted():
    mean, cov, action, z, current, Q, R, _, _ = _batch()
    m7 = torch.cat((mean, torch.full_like(mean[..., :2], 0.03)), -1)
    P7 = torch.zeros(*mean.shape[:-1], AUGMENTED_DIM, AUGMENTED_DIM, dtype=mean.dtype)
    P7[..., :5, :5] = cov
    P7[..., 5, 5] = P7[..., 6, 6] = 0.01
    none = torch.zeros(mean.shape[0], 6, dtype=torch.bool)
    held, held_cov, _ = augmented_step(m7, P7, action, z, current, Q, R, 0.2, arrived=none)
    other = z + 1.0  # other readings change nothing when none arrived
    again, again_cov, _ = augmented_step(m7, P7, action, other, current, Q, R, 0.2, arrived=none)
    assert torch.equal(held, again) and torch.equal(held_cov, again_cov)
    torch.testing.assert_close(held[..., 5:], m7[..., 5:], rtol=0, atol=0)


def _position_rmse(ekf, data):
    keep = data["step_count"] >= 10
    error = state_error(filter_estimates(ekf, data)[..., :5], data["true_state"])[keep]
    return float(error[:, :2].pow(2).sum(-1).mean().sqrt())


def test_a_biased_current_costs_the_estimating_filter_less():
    config = DockingConfig(current_knowledge_bias=0.05)
    data = record_rollouts(48, 300, config=config, seed=1)
    with torch.no_grad():
        paper = _position_rmse(make_filter(config), data)
        estimating = _position_rmse(make_filter(config, estimate_current=True), data)
    assert estimating < 0.3 * paper, (paper, estimating)


def test_the_transform_keeps_a_seven_entry_state_through_resets():
    config = level_config("L5")
    env = make_env(
        "compound",
        4,
        seed=0,
        config=config,
        ekf_kwargs={"estimate_current": True, "compensate_latency": True},
    )
    assert isinstance(env.transform[0], CurrentEstimatingEKF)
    data = env.rollout(40, break_when_any_done=False)
    assert data["next", "ekf_mean"].shape == (4, 40, AUGMENTED_DIM)
    assert data["next", "ekf_cov"].shape == (4, 40, AUGMENTED_DIM, AUGMENTED_DIM)
    assert data["next", "observation"].shape == (4, 40, 12)
    assert torch.isfinite(data["next", "observation"]).all()
    assert env.observation_spec["ekf_mean"].shape == (4, AUGMENTED_DIM)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"current_error_std": -0.1}, "current_error_std"),
        ({"initial_current_error_std": float("nan")}, "initial_current_error_std"),
        ({"compile": True}, "compile"),
    ],
)
def test_bad_options_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        CurrentEstimatingEKF(**kwargs)


def test_the_stress_ladder_refuses_it_without_a_filter():
    with pytest.raises(ValueError, match="estimate_current applies to the filtered scenarios"):
        stress_ladder("managed_surge", "noise", episodes=1, estimate_current=True)


@pytest.mark.parametrize("observe_error", [False, True])
def test_onboard_policy_and_its_export_estimate_as_the_env_pipeline_does(tmp_path, observe_error):
    """The onboard policy and its exported program run the filter as the env pipeline does,
    and, with ``observe_current_error``, give the actor the current and the filter's estimate
    of its error as the pipeline's ``CurrentError`` does."""
    from helpers import drive_onboard_beside_env, tiny_actor

    from dockingrl.onboard import OnboardPolicy, export_onboard

    config = level_config("L5").replace(max_steps=40)
    options = {"compensate_latency": True, "estimate_current": True}
    observe = {"observe_current": True, "observe_current_error": True} if observe_error else {}
    actor = tiny_actor(16 if observe_error else 12, "sac")
    onboard = OnboardPolicy(actor, "compound", config=config, **options, **observe)
    program = torch.export.load(
        export_onboard(onboard, tmp_path / "onboard.pt2", batch=4, sensor_age=True)
    ).module()
    env = make_env("compound", 4, seed=3, config=config, ekf_kwargs=options, **observe)
    if observe_error:
        td = env.rollout(30)
        errors = td["next", "observation"][..., 14:16]
        torch.testing.assert_close(errors, td["next", "ekf_mean"][..., 5:7])
        assert errors.abs().max() > 1e-3  # the filter moved its estimate off zero
    assert onboard.initial_state(4)[0].shape == (4, AUGMENTED_DIM)
    resets, _ = drive_onboard_beside_env(env, actor, onboard, program)
    assert resets > 0


def test_the_estimated_error_is_observed_only_from_the_filter_that_estimates_it():
    from helpers import tiny_actor

    from dockingrl.onboard import OnboardPolicy, OnboardStep

    with pytest.raises(ValueError, match="needs the filter that estimates the current's error"):
        make_env("filtered", 2, seed=0, observe_current_error=True)
    with pytest.raises(ValueError, match="needs a scenario with the EKF"):
        make_env("noise", 2, seed=0, observe_current_error=True)
    with pytest.raises(ValueError, match="needs the filter that estimates the current's error"):
        OnboardPolicy(tiny_actor(8, "sac"), "filtered", observe_current_error=True)
    with pytest.raises(ValueError, match="needs a scenario with the EKF"):
        OnboardPolicy(tiny_actor(8, "sac"), "noise", observe_current_error=True)
    with pytest.raises(ValueError, match="needs the filter that estimates the current's error"):
        OnboardStep(
            tiny_actor(8, "sac"),
            "filtered",
            make_filter(DockingConfig()),
            observe_current_error=True,
        )
    signs = mirror_signs("filtered", observe_current=True, observe_current_error=True)
    assert signs[-4:].tolist() == [1.0, -1.0, 1.0, -1.0]  # oc_y and b_y flip with the mirror


def _augmented(mean, cov, action, z, current, R, std=0.05, seed=1):
    """``mean`` and ``cov`` with a nonzero current error ``b`` and uncertainty in it."""
    g = torch.Generator().manual_seed(seed)
    error = 0.05 * torch.randn(mean.shape[0], 2, generator=g, dtype=mean.dtype)
    m7 = torch.cat((mean, error), -1)
    a = torch.randn(mean.shape[0], AUGMENTED_DIM, AUGMENTED_DIM, generator=g, dtype=mean.dtype)
    P7 = 0.05 * a @ a.transpose(-1, -2) + 1e-3 * torch.eye(AUGMENTED_DIM, dtype=mean.dtype)
    P7[..., :5, :5] += cov
    return m7, P7


def _f7(m7, action, current, dt=0.2):
    state = motion_model(m7[:5], action, current + m7[5:], dt)
    return torch.cat((state, m7[5:]))


def _h7(m7, current):
    return measurement_function(m7[:5], current + m7[5:])


def test_the_jacobians_are_the_derivatives_of_the_augmented_models():
    mean, cov, action, z, current, Q, R, _, _ = _batch(8)
    m7, _ = _augmented(mean, cov, action, z, current, R)
    F = augmented_motion_jacobian(m7[..., :5], 0.2)
    H = augmented_measurement_jacobian(m7[..., :5], current + m7[..., 5:])
    for n in range(8):
        f = torch.autograd.functional.jacobian(
            partial(_f7, action=action[n], current=current[n]), m7[n]
        )
        h = jacobian(partial(_h7, current=current[n]), m7[n])
        torch.testing.assert_close(F[n], f, rtol=0, atol=1e-12)
        torch.testing.assert_close(H[n], h, rtol=0, atol=1e-12)


def test_the_update_is_the_joint_ekf_update_with_an_uncertain_current_error():
    """Against a dense textbook EKF over the 7 entries: predict, one joint update with
    ``S^-1``, Joseph form; every reading arrived, no gate, no latency."""
    mean, cov, action, z, current, Q, R, _, _ = _batch(16)
    m7, P7 = _augmented(mean, cov, action, z, current, R)
    std = 0.05
    m, P, filtered = augmented_step(m7, P7, action, z, current, Q, R, 0.2, current_error_std=std)
    Q7 = torch.zeros(AUGMENTED_DIM, AUGMENTED_DIM, dtype=Q.dtype)
    Q7[:5, :5], Q7[5, 5], Q7[6, 6] = Q, std**2, std**2
    I7 = torch.eye(AUGMENTED_DIM, dtype=Q.dtype)
    for n in range(16):
        F = torch.autograd.functional.jacobian(
            partial(_f7, action=action[n], current=current[n]), m7[n]
        )
        prior = _f7(m7[n], action[n], current[n])
        Pp = F @ P7[n] @ F.T + Q7
        H = jacobian(partial(_h7, current=current[n]), prior)
        y = z[n] - _h7(prior, current[n])
        y[1:3] = torch.remainder(y[1:3] + torch.pi, 2 * torch.pi) - torch.pi
        Rn = torch.diag(R[n])
        K = Pp @ H.T @ torch.linalg.inv(H @ Pp @ H.T + Rn)
        x = prior + K @ y
        x[2] = torch.remainder(x[2] + torch.pi, 2 * torch.pi) - torch.pi
        Pj = (I7 - K @ H) @ Pp @ (I7 - K @ H).T + K @ Rn @ K.T
        torch.testing.assert_close(m[n], x, rtol=0, atol=1e-10)
        torch.testing.assert_close(P[n], Pj, rtol=0, atol=1e-10)
    torch.testing.assert_close(filtered, measurement_function(m[..., :5], current + m[..., 5:]))


def test_the_start_holds_the_surges_share_of_the_current_error():
    ekf = CurrentEstimatingEKF(initial_current_error_std=0.1).double()
    mean, cov, action, z, current, Q, R, _, _ = _batch(4)
    m0, P0 = ekf.initial_estimate(z, current)
    paper_m, paper_P = EKFTransform().double().initial_estimate(z, current)
    torch.testing.assert_close(m0[..., :5], paper_m)
    assert m0[..., 5:].abs().max() == 0
    heading = torch.stack((torch.cos(m0[..., 2]), torch.sin(m0[..., 2])), -1)
    torch.testing.assert_close(P0[..., 3, 5:], -0.01 * heading)
    torch.testing.assert_close(P0[..., 3, 3], paper_P[..., 3, 3] + 0.01)
    torch.testing.assert_close(P0[..., 5:, 5:], 0.01 * torch.eye(2, dtype=P0.dtype).expand(4, 2, 2))
    assert bool((torch.linalg.eigvalsh(P0) > 0).all())


def test_learned_filter_parameters_and_the_paper_filters_tools_refuse_it():
    from dockingrl.filter_learning import run_filter

    ekf = CurrentEstimatingEKF()
    with pytest.raises(ValueError, match="do not apply to the filter that estimates the current"):
        ekf.load_filter_params("unused.pt")
    data = record_rollouts(4, 20, config=DockingConfig(), seed=0)
    with pytest.raises(ValueError, match="run_filter runs the paper's 5-state EKF"):
        run_filter(ekf, data)


def test_a_run_trained_with_it_carries_it_to_evaluation_and_the_onboard_policy(tmp_path):
    from helpers import smoke_config

    from dockingrl.agents.layout import pipeline_options
    from dockingrl.onboard import OnboardPolicy
    from dockingrl.training import train

    cfg = smoke_config(
        "sac",
        "filtered",
        tmp_path,
        "estimating",
        total_steps=128,
        start_steps=64,
        frames_per_batch=64,
        eval_every=128,
        final_eval_episodes=2,
        train_level="L5",
        compensate_latency=True,
        estimate_current=True,
        mirror_augment=True,
    )
    train(cfg, progress=False)
    saved = json.loads((tmp_path / "estimating" / "config.json").read_text())
    assert pipeline_options(saved)["ekf_kwargs"] == {
        "compensate_latency": True,
        "estimate_current": True,
    }
    onboard = OnboardPolicy.from_file(tmp_path / "estimating" / "policy.pt")
    assert isinstance(onboard.step.ekf, CurrentEstimatingEKF)
    assert onboard.initial_state(2)[0].shape == (2, AUGMENTED_DIM)


def test_a_scenario_without_a_filter_refuses_it():
    from dockingrl.agents.config import make_config

    with pytest.raises(ValueError, match="estimate_current.*has no filter"):
        make_config("sac", "paper", scenario="noise", estimate_current=True)


def test_a_run_observes_the_estimated_error_only_with_the_filter_that_estimates_it():
    from dockingrl import load_recipe

    recipe = load_recipe("sac-robust")
    with pytest.raises(ValueError, match="observe_current_error: needs estimate_current"):
        recipe.make_config(estimate_current=False, observe_current_error=True)
    with pytest.raises(ValueError, match="observe_current_error: scenario 'noise' has no filter"):
        load_recipe("sac").make_config(scenario="noise", observe_current_error=True)
    cfg = recipe.make_config(observe_current_error=True)
    assert cfg.observe_current_error and cfg.estimate_current
    with pytest.raises(ValueError, match="compile: not with estimate_current"):
        recipe.make_config(compile=True)  # refused before its env is built
